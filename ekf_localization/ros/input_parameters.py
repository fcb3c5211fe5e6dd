"""ekf_node's per-input parameters (``odom0``, ``odom0_config``, ``landmark0_position``, ...): the
schemas of each input kind (ekf_localization.inputs) and their parsing into an
:class:`InputConfig` (no rclpy). Names follow robot_localization where the concept is the same.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

from ekf_localization.core.config import TILT_FIELDS, InputConfig
from ekf_localization.core.joint_states import EncoderInputConfig, validate_encoder_config
from ekf_localization.core.measurements import FIELD_NAMES, N_FIELDS
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.inputs import KINDS
from ekf_localization.ros.parameters import (
    REQUIRED,
    Check,
    Entry,
    Problem,
    Schema,
    at_least,
    expected,
    positive,
)

NODE_NAME = "ekf_node"
DOC = "docs/ekf_node.md"
_FIELDS_TEXT = " ".join(FIELD_NAMES)
INPUT_KINDS = tuple(KINDS)  # ekf_localization.inputs: one module per kind
# Fields each message type can carry.
KIND_FIELDS: dict[str, frozenset[int]] = {name: kind.fields for name, kind in KINDS.items()}
# Rejection-threshold parameter suffix -> the message part it gates, per kind (RL names).
THRESHOLD_SUFFIXES: dict[str, dict[str, str]] = {name: dict(kind.thresholds) for name, kind in KINDS.items()}
_PART_DOC = {"range_bearing": "the range and bearing", "encoders": "the encoder speeds", "pose": "the pose",
             "twist": "the twist",
             "orientation": "the orientation",
             "angular_velocity": "the angular velocity",
             "linear_acceleration": "the acceleration (differential model: a process input, not gated)"}


RL_INPUT_IGNORED = ("nodelay", "remove_gravitational_acceleration")


_QUEUE = Entry("queue_size", "int", InputConfig.__dataclass_fields__["queue_size"].default, "messages",
               "subscription depth", at_least(1, "an integer >= 1"))
# Settings of one input, ``<input>_<name>`` (the input itself, ``odom0``, is its topic);
# a jointN input has only the queue size of these.
INPUT_PARAMETERS = Schema(NODE_NAME, DOC, (
    Entry("config", "bool_list", REQUIRED, "",
          "15 booleans: which fields to fuse; a field the message or the model lacks is ignored with a "
          "warning (not jointN)",
          Check(lambda v: len(v) == N_FIELDS, f"a list of 15 booleans ({_FIELDS_TEXT})")),
    _QUEUE,
    Entry("differential", "bool", False, "",
          "robot_localization's differential mode: successive poses become a body velocity (pose data "
          "of odom, pose, imu inputs)"),
    Entry("relative", "bool", False, "",
          "robot_localization's relative mode: poses relative to the first one (ignored with differential)"),
    Entry("variance_scale", "float", InputConfig.__dataclass_fields__["variance_scale"].default, "",
          "every message covariance is multiplied by this (ekf_tune fits it)",
          positive("a finite factor > 0 on the message covariances")),
    Entry("default_frame_id", "str", "", "",
          "the frame of a message whose header.frame_id is empty ('' = such a message is rejected as "
          "no_frame: no frame is guessed)"),
), ints_as_floats=True)
_JOINT_COMMON = Schema(NODE_NAME, DOC, (_QUEUE,))

_THRESHOLD = Check(lambda v: v > 0.0, "a Mahalanobis distance in sigmas > 0")
_TILT = Entry("tilt_compensation", "bool", False, "",
              "project the fused body twist onto the horizontal plane with the IMU's roll and pitch")
_POSE_FRAME = Entry("pose_frame", "str", "", "",
                    "the frame whose pose the pose part gives ('' = base_link_frame), via TF")
_CHILD_FRAME = Entry("pose_use_child_frame", "bool", False, "",
                     "the pose is of the message's child_frame_id (RL)")
_E = EncoderInputConfig(names=("left", "right", "lateral"))
_JOINT = (
    Entry("names", "str_list", REQUIRED, "",
          "joint names [left, right, lateral] (mecanum) or [left, right] (differential; a third is ignored "
          "with a warning)"),
    Entry("wheel_radius", "float", _E.wheel_radius, "m", "dead-wheel radius: joint position rad -> distance "
          "along the surface"),
    Entry("half_spacing", "float", _E.half_spacing, "m",
          "W: the parallel wheels sit at ±W from the centre line (seed 000 eq. 29-30)"),
    Entry("lateral_offset", "float", _E.lateral_offset, "m",
          "D: the lateral wheel sits this far behind the centre (negative: in front), E_a = vy - D·vyaw "
          "(eq. 30)"),
    Entry("speed_variance_coeff", "float", _E.speed_variance_coeff, "",
          "a of the per-wheel speed variance a·E² + b (eq. 32)"),
    Entry("speed_variance_floor", "float", _E.speed_variance_floor, "(m/s)²", "b of a·E² + b"),
    Entry("use_velocities", "bool", _E.use_velocities, "",
          "use the message's velocity array (rad/s) when it has one; false: speeds from position "
          "differences"),
    Entry("max_speed", "float", _E.max_speed, "m/s",
          "a position step implying a faster wheel is an encoder reset or wrap: rejected (encoder_jump)"),
    Entry("tilt_compensation", "bool", _E.tilt_compensation, "",
          "fuse the speeds against the horizontal velocity with the IMU's roll and pitch"),
)


def _thresholds(kind: str) -> tuple[Entry, ...]:
    alias = " (alias of the twist threshold)"
    return tuple(Entry(suffix[1:], "float", math.inf, "σ",
                       f"Mahalanobis gate on {_PART_DOC.get(part, 'the ' + part.replace('_', ' '))}"
                       + (alias if suffix.startswith("_angular") else ""), _THRESHOLD)
                 for suffix, part in THRESHOLD_SUFFIXES[kind].items())


def _own_entries(kind: str) -> tuple[Entry, ...]:
    """The settings of a kind with its own fusion (inputs.kind.ParameterSpec) as schema entries."""
    return tuple(Entry(p.name, p.type, REQUIRED if p.required else p.default, p.unit, p.doc,
                       Check(p.check, p.form) if p.check is not None else None)
                 for p in KINDS[kind].parameters)


# Per kind: its own settings, ``<kindN>_<name>``.
KIND_PARAMETERS: dict[str, Schema] = {
    kind: Schema(NODE_NAME, DOC, (_JOINT if kind == "joint" else ()) + _thresholds(kind) + _own_entries(kind)
                 + ((_TILT,) if kind in ("odom", "twist") else ())
                 + ((_POSE_FRAME,) if kind in ("odom", "pose") else ())
                 + ((_CHILD_FRAME,) if kind == "odom" else ()), ints_as_floats=True)
    for kind in INPUT_KINDS}
_FUSION_COMMON = Schema(NODE_NAME, DOC, (_QUEUE, INPUT_PARAMETERS["variance_scale"]), ints_as_floats=True)

INPUT_RE = re.compile(rf"^({'|'.join(INPUT_KINDS)})(\d+)(.*)$")


def parse_input(values: Mapping[str, Any], kind: str, name: str, state_fields: set[int],
                 spec: MotionModelSpec, problems: list[Problem], warnings: list[str],
                 claimed: set[str]) -> InputConfig | None:
    model = spec.name
    prefix = name + "_"
    claimed.add(name)
    topic = values[name]
    n_problems = len(problems)
    if not isinstance(topic, str) or not topic.strip():
        problems.append(expected(name, "a topic name", topic))
    own_fusion = KINDS[kind].fusion is not None
    common_schema = _JOINT_COMMON if kind == "joint" else _FUSION_COMMON if own_fusion else INPUT_PARAMETERS
    common = common_schema.parse(values, prefix)
    own = KIND_PARAMETERS[kind].parse(values, prefix)
    problems += common.problems + own.problems
    for schema in (common_schema, KIND_PARAMETERS[kind]):
        claimed.update(prefix + e for e in schema)
    if common_schema is INPUT_PARAMETERS:
        for suffix in RL_INPUT_IGNORED:
            if prefix + suffix in values:
                claimed.add(prefix + suffix)
                warnings.append(f"parameter '{prefix + suffix}' (robot_localization) is not supported; "
                                "ignored")
    thresholds = []
    seen_parts: dict[str, str] = {}
    for suffix, part in THRESHOLD_SUFFIXES[kind].items():
        if suffix[1:] not in own.given:
            continue
        pname = name + suffix
        if part in seen_parts:
            problems.append(expected(pname, f"only one of {seen_parts[part]} and {pname}", values[pname]))
            continue
        seen_parts[part] = pname
        thresholds.append((part, own.values[suffix[1:]]))
    if kind == "joint":
        encoders = _encoders(values, name, own.values, spec, problems, warnings)
        if len(problems) > n_problems:
            return None
        return InputConfig(name=name, kind=kind, topic=topic, config=(False,) * N_FIELDS,
                           queue_size=common.values["queue_size"], rejection_thresholds=tuple(thresholds),
                           encoders=encoders)
    if own_fusion:
        for p in KINDS[kind].parameters:
            if p.required and own.values[p.name] is REQUIRED and prefix + p.name not in values:
                problems.append(expected(prefix + p.name, KIND_PARAMETERS[kind][p.name].form + " (required)"))
        if len(problems) > n_problems:
            return None
        try:
            fusion = KINDS[kind].fusion(own.values)
            fusion.measurement_model({f: i for i, f in enumerate(spec.state_fields)}, len(spec.state_fields))
        except ValueError as exc:
            problems.append(expected(name, f"an input model '{model}' can fuse ({exc})", topic))
            return None
        return InputConfig(name=name, kind=kind, topic=topic, config=(False,) * N_FIELDS,
                           queue_size=common.values["queue_size"], rejection_thresholds=tuple(thresholds),
                           variance_scale=common.values["variance_scale"], fusion=fusion)
    config = common.values["config"]
    if config is REQUIRED and prefix + "config" not in values:
        problems.append(expected(prefix + "config", INPUT_PARAMETERS["config"].form + " (required)"))
    if len(problems) > n_problems or config is REQUIRED:
        return None
    differential, relative = common.values["differential"], common.values["relative"]
    if kind not in ("odom", "pose", "imu") and (differential or relative):
        warnings.append(f"{name}: _differential and _relative apply to pose data only; ignored")
        differential = relative = False
    if differential and relative:
        warnings.append(f"{name}_relative: ignored, {name}_differential is true (as in robot_localization)")
        relative = False
    fused = {i for i, f in enumerate(config) if f}
    if kind == "imu" and all(config[f] for f in TILT_FIELDS):
        state_fields = state_fields | set(TILT_FIELDS)  # the tilt source: used, not estimated
    not_in_msg = sorted(fused - KIND_FIELDS[kind])
    if not_in_msg:
        warnings.append(f"{name}_config: a {kind} message has no "
                        + ", ".join(FIELD_NAMES[i] for i in not_in_msg) + "; ignored")
    not_in_model = sorted((fused & KIND_FIELDS[kind]) - state_fields)
    if not_in_model:
        warnings.append(f"{name}_config: model '{model}' does not estimate "
                        + ", ".join(FIELD_NAMES[i] for i in not_in_model) + "; ignored")
    if not ((fused & KIND_FIELDS[kind]) & state_fields):
        warnings.append(f"{name} ({topic}) fuses no field the '{model}' model estimates")
    return InputConfig(name=name, kind=kind, topic=topic, config=tuple(config), parts=KINDS[kind].parts,
                       queue_size=common.values["queue_size"], rejection_thresholds=tuple(thresholds),
                       tilt_compensation=own.values.get("tilt_compensation", False),
                       variance_scale=common.values["variance_scale"],
                       default_frame_id=common.values.get("default_frame_id", "").strip("/ "),
                       pose_frame=own.values.get("pose_frame", "").strip("/ "),
                       pose_use_child_frame=own.values.get("pose_use_child_frame", False),
                       differential=differential, relative=relative)


def _encoders(values: Mapping[str, Any], name: str, v: Mapping[str, Any], spec: MotionModelSpec,
              problems: list[Problem], warnings: list[str]) -> EncoderInputConfig | None:
    """A jointN input's dead-wheel settings (``v``: its parsed KIND_PARAMETERS['joint'] values)."""
    key = name + "_names"
    model = spec.name
    want = spec.dead_wheel_count
    if want == 0:
        problems.append(expected(name, f"no jointN input: model '{model}' has no dead-wheel encoder "
                                 "measurement", values[name]))
        return None
    what = (f"a list of {want} joint names [left, right{', lateral' if want == 3 else ''}]"
            + (" (a lateral third name is ignored)" if want == 2 else ""))
    names = v["names"]
    if names is REQUIRED:
        if key not in values:
            problems.append(expected(key, what + " (required)"))
        return None
    if len(names) not in (want, 3) or not all(names):
        problems.append(expected(key, what, values[key]))
        return None
    if len(names) > want:
        warnings.append(f"{key}: model '{model}' has no lateral velocity; '{names[2]}' is not used")
        names = names[:want]
    cfg = EncoderInputConfig(names=tuple(names), **{e.name: v[e.name] for e in _JOINT[1:]})
    problem = validate_encoder_config(cfg)
    if problem is not None:
        field_name, form = problem.split(": ", 1)
        problems.append(expected(f"{name}_{field_name}", form,
                                 values.get(f"{name}_{field_name}", getattr(cfg, field_name))))
        return None
    return cfg
