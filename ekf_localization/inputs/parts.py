"""robot_localization's input kinds (odomN, poseN, twistN, imuN): messages whose parts are runs of
its 15 state fields, fused as linear measurements of the state (z = x[rows]).

``<input>_config`` (15 booleans) picks the fields. Each fused part gets a :class:`PartPlan`
(which fields, which state rows, the frame they must be in, the Mahalanobis gate). A message
goes through :class:`PartsHandler`:

1. with ``<input>_twist_covariance`` (odom, twist; ours, not robot_localization's), the
   message's twist covariance replaced by it, in the twist's own frame (a driver whose
   covariance is a placeholder or absent);
2. its frame (an empty frame_id takes ``<input>_default_frame_id``, or the message is
   rejected as ``no_frame``), then its parts in the filter's frames (core.input_frames: TF,
   ``_differential`` and ``_relative`` poses);
3. the kind's extras (the IMU's tilt and process input, inputs/imu.py);
4. each fused part checked (provided, finite, frame, covariance symmetric PD, plausible), a
   zero fused variance raised to ``zero_variance_floor`` first (as robot_localization does:
   diff_drive_controller publishes all-zero covariances by default); a twist projected onto
   the horizontal plane with ``tilt_compensation``; R scaled by ``variance_scale``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ekf_localization.core.config import InputConfig
from ekf_localization.core.ekf import symmetric_psd
from ekf_localization.core.fusion_context import Fused, FusionContext
from ekf_localization.core.linear import select_rows
from ekf_localization.core.measurements import (
    FIELD_NAMES,
    N_FIELDS,
    REJECT_IMPLAUSIBLE,
    REJECT_NO_FRAME,
    MeasurementPart,
    fused_values,
)
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.part_plans import RATE_PARTS, SOURCE_PART, PartPlan, floor_zero_variances
from ekf_localization.inputs.kind import ParameterSpec, Report

_NO_FRAME = (("message", REJECT_NO_FRAME),)


@dataclass(frozen=True)
class PartsSettings:
    """A parts input's own settings (its ``<input>_...`` parameters)."""

    config: tuple[bool, ...]  # 15 flags: which fields to fuse
    parts: tuple[tuple[str, int, int], ...]  # its kind's message parts: (name, first RL field, length)
    differential: bool = False  # successive poses become a body velocity (RL's _differential)
    relative: bool = False  # poses relative to the first one (RL's _relative)
    default_frame_id: str = ""  # the frame of a message whose frame_id is empty ("": rejected, no_frame)
    pose_frame: str = ""  # the frame whose pose a pose part gives ("": base_link_frame)
    pose_use_child_frame: bool = False  # odometry: the pose is of its child_frame_id (RL)
    tilt_compensation: bool = False  # odom/twist: project the twist with an IMU's roll/pitch
    twist_covariance: tuple[float, ...] = ()  # 36 values, row-major: replaces the message's ((): kept)


def _is_scale(v: float) -> bool:
    return math.isfinite(v) and v > 0.0


VARIANCE_SCALE = ParameterSpec("variance_scale", "float", 1.0, "",
                               "every message covariance is multiplied by this (ekf_tune fits it)",
                               _is_scale, "a finite factor > 0 on the message covariances")
# Every parts kind's settings, ``<input>_<name>`` (robot_localization's names).
COMMON = (
    ParameterSpec("config", "bool_list", None, "",
                  "15 booleans: which fields to fuse; a field the message or the model lacks is ignored "
                  "with a warning (not jointN)",
                  lambda v: len(v) == N_FIELDS, f"a list of 15 booleans ({' '.join(FIELD_NAMES)})",
                  required=True),
    ParameterSpec("differential", "bool", False, "",
                  "robot_localization's differential mode: successive poses become a body velocity (pose "
                  "data of odom, pose, imu inputs)"),
    ParameterSpec("relative", "bool", False, "",
                  "robot_localization's relative mode: poses relative to the first one (ignored with "
                  "differential)"),
    VARIANCE_SCALE,
    ParameterSpec("default_frame_id", "str", "", "",
                  "the frame of a message whose header.frame_id is empty ('' = such a message is rejected "
                  "as no_frame: no frame is guessed)"),
)
TILT_COMPENSATION = ParameterSpec("tilt_compensation", "bool", False, "",
                                  "project the fused body twist onto the horizontal plane with the IMU's "
                                  "roll and pitch")
POSE_FRAME = ParameterSpec("pose_frame", "str", "", "",
                           "the frame whose pose the pose part gives ('' = base_link_frame), via TF")


def twist_covariance_matrix(values: list[float] | tuple[float, ...]) -> np.ndarray | None:
    """``<input>_twist_covariance`` as a 6 x 6 matrix: 6 variances (the diagonal) or 36 values
    (row-major); None when it is not finite, a variance is negative, or the matrix is not
    symmetric positive semi-definite."""
    a = np.asarray(values, dtype=float)
    if a.size not in (6, 36) or not np.isfinite(a).all():
        return None
    C = np.diag(a) if a.size == 6 else a.reshape(6, 6)
    return symmetric_psd(C)


TWIST_COVARIANCE = ParameterSpec(
    "twist_covariance", "float_list", [], "(m/s)², (rad/s)²",
    "replaces the covariance of each message's twist, in the twist's frame: 6 variances (vx vy vz vroll "
    "vpitch vyaw) or a 6x6 matrix (36 values, row-major); for a driver whose covariance is a placeholder "
    "(mecanum_drive_controller's fixed 0.1) or zeros (diff_drive_controller), or that has none; "
    "[] = the message's. zero_variance_floor and variance_scale apply after it (not in RL)",
    lambda v: len(v) == 0 or twist_covariance_matrix(v) is not None,
    "[] or 6 finite variances >= 0, or 36 values of a symmetric positive semi-definite matrix")
POSE_USE_CHILD_FRAME = ParameterSpec("pose_use_child_frame", "bool", False, "",
                                     "the pose is of the message's child_frame_id (RL)")


def configure_parts(values: Mapping[str, Any], name: str, spec: MotionModelSpec, report: Report, kind: str,
              parts: tuple[tuple[str, int, int], ...], poses: bool = True,
              extra_fields: frozenset[int] = frozenset()) -> PartsSettings:
    """The settings of a parts input of ``kind`` from its parsed ``values``; warnings for fields
    that the message or the model lacks. ``poses``: the kind has pose data (``_differential``
    and ``_relative`` apply); ``extra_fields``: fields it uses though the model does not
    estimate them."""
    differential, relative = values["differential"], values["relative"]
    if not poses and (differential or relative):
        report.warn(f"{name}: _differential and _relative apply to pose data only; ignored")
        differential = relative = False
    if differential and relative:
        report.warn(f"{name}_relative: ignored, {name}_differential is true (as in robot_localization)")
        relative = False
    config = tuple(values["config"])
    fused = {i for i, f in enumerate(config) if f}
    carried = {f for _, first, length in parts for f in range(first, first + length)}
    state_fields = set(spec.state_fields) | set(spec.input_fields) | extra_fields
    not_in_msg = sorted(fused - carried)
    if not_in_msg:
        report.warn(f"{name}_config: a {kind} message has no "
                    + ", ".join(FIELD_NAMES[i] for i in not_in_msg) + "; ignored")
    not_in_model = sorted((fused & carried) - state_fields)
    if not_in_model:
        report.warn(f"{name}_config: model '{spec.name}' does not estimate "
                    + ", ".join(FIELD_NAMES[i] for i in not_in_model) + "; ignored")
    if not ((fused & carried) & state_fields):
        report.warn(f"{name} ({values['topic']}) fuses no field the '{spec.name}' model estimates")
    twist_cov = _twist_covariance(values.get("twist_covariance", []), config, name, report)
    return PartsSettings(config, parts, differential, relative,
                         values["default_frame_id"].strip("/ "), values.get("pose_frame", "").strip("/ "),
                         values.get("pose_use_child_frame", False), values.get("tilt_compensation", False),
                         twist_cov)


def _twist_covariance(values: list[float], config: tuple[bool, ...], name: str,
                      report: Report) -> tuple[float, ...]:
    """The checked ``<input>_twist_covariance`` (36 values, () when not given). The block of the
    fused twist fields must be positive definite once its zero variances are raised to
    ``zero_variance_floor``: a zero variance (with its row, PSD) is floored, anything else
    singular would refuse every message."""
    if not values:
        return ()
    C = twist_covariance_matrix(values)
    fused = [j for j in range(6) if config[6 + j]]
    zero = [j for j in fused if C[j, j] == 0.0]
    rest = [j for j in fused if C[j, j] > 0.0]
    if rest and np.linalg.eigvalsh(C[np.ix_(rest, rest)]).min() <= 0.0:
        report.problem(f"{name}_twist_covariance", "a matrix positive definite on the fused twist fields "
                       f"({', '.join(FIELD_NAMES[6 + j] for j in rest)})", values)
    if zero:
        report.warn(f"{name}_twist_covariance: zero variance on fused "
                    + ", ".join(FIELD_NAMES[6 + j] for j in zero) + "; zero_variance_floor is used")
    return tuple(float(c) for c in C.ravel())


def make_plans(inp: InputConfig, ctx: FusionContext) -> tuple[PartPlan, ...]:
    """The plans of every part ``inp`` fuses (a part whose fields the state has not is left out)."""
    s: PartsSettings = inp.settings
    field_to_state, x_is_angle = ctx.field_to_state, ctx.x_is_angle
    plans = []
    for name, first, length in s.parts:
        target = first  # the fields a part measures: a differential pose measures their rates
        if s.differential and name in RATE_PARTS:
            name, target = RATE_PARTS[name], first + 6
        local = [j for j in range(length) if s.config[first + j] and (target + j) in field_to_state]
        if not local:
            continue
        rows = [field_to_state[target + j] for j in local]
        angle_rows = tuple(r for r in rows if x_is_angle[r])
        idx = np.array(local, dtype=np.intp)
        plans.append(PartPlan(name, idx, np.ix_(idx, idx), select_rows(len(x_is_angle), rows, angle_rows),
                              inp.threshold(SOURCE_PART.get(name, name)),
                              ctx.config.world_frame if name == "pose" else ctx.config.base_link_frame,
                              np.array(rows, dtype=np.intp),
                              tuple(i for i, r in enumerate(rows) if r in angle_rows), f"{inp.name}/{name}",
                              r_checked=True))
    return tuple(plans)


class PartsHandler:
    """One parts input's path from record to updates (the module docstring)."""

    def __init__(self, inp: InputConfig, ctx: FusionContext, extra_parts: set[str] | None = None) -> None:
        self.name = inp.name
        self.settings: PartsSettings = inp.settings
        self.plans = make_plans(inp, ctx)
        self._ctx = ctx
        self._stats = ctx.stats[inp.name]
        self._scale = inp.variance_scale
        self._plausible = bounds = ctx.config.plausible_bounds
        first = {name: first for name, first, _ in self.settings.parts}
        # per plan: the largest plausible |value| of each fused field (a rate part: 6 fields on)
        self._bounds = {plan: bounds[plan.local + first[SOURCE_PART.get(plan.name, plan.name)]
                                     + (6 if plan.name in SOURCE_PART else 0)].tolist()
                        for plan in self.plans}
        self._tilt_twist = self.settings.tilt_compensation
        self._warned_floor = False
        self._twist_cov: np.ndarray | None = None
        if self.settings.twist_covariance:
            self._twist_cov = np.array(self.settings.twist_covariance, dtype=float).reshape(6, 6)
            self._twist_cov.setflags(write=False)
        used = {SOURCE_PART.get(plan.name, plan.name) for plan in self.plans} | (extra_parts or set())
        ctx.frames.register(inp.name, self.settings, used)

    def reset(self) -> None:
        """Nothing of its own: the pose modes live in core.input_frames."""

    def fuse(self, record: Any, stamp: int) -> Fused:
        frames = self._ctx.frames
        if self._twist_cov is not None:
            record = self._with_twist_covariance(record)
        measurement = frames.with_frame(self.name, record)
        if measurement is None:  # an empty frame_id: no frame is guessed
            return Fused(stamp, (), rejected=_NO_FRAME)
        parts, no_transform = frames.parts(self.name, measurement, stamp)
        applied, rejected = self.extras(parts, no_transform, stamp)
        updates = []
        for plan in self.plans:
            if plan.name not in parts and plan.name not in no_transform:
                continue  # a differential input's first pose: no velocity yet
            update = self._checked(plan, parts.get(plan.name), stamp, no_transform.get(plan.name))
            if isinstance(update, str):
                rejected.append((plan.name, update))
            else:
                updates.append(update)
        return Fused(stamp, tuple(updates), applied, tuple(rejected))

    def extras(self, parts: dict[str, MeasurementPart], no_transform: dict[str, str],
               stamp: int) -> tuple[tuple[str, ...], list[tuple[str, str]]]:
        """What a kind takes from a message besides its updates: (applied parts, rejected pairs)."""
        return (), []

    def _with_twist_covariance(self, record: Any) -> Any:
        """``record`` with ``<input>_twist_covariance`` as its twist's covariance (its LAYOUT
        names the attribute)."""
        for lay in record.LAYOUT:
            if lay.name == "twist":
                return replace(record, **{lay.covariance: self._twist_cov})
        return record

    def _checked(self, plan: PartPlan, part: MeasurementPart | None, stamp: int,
                 reason: str | None) -> tuple[PartPlan, np.ndarray, np.ndarray] | str:
        """(plan, z, R) of a part that passes every check, or the reason it does not."""
        if reason is not None:
            return reason
        zR = fused_values(part, plan.local, plan.block, plan.expected_frame)
        if isinstance(zR, str):  # a zero fused variance fails the checks: try the floor
            zR = fused_values(self._floor_zero_variances(part, plan.local), plan.local, plan.block,
                              plan.expected_frame)
            if isinstance(zR, str):
                return zR
        z, R = zR
        for value, bound in zip(z.tolist(), self._bounds[plan], strict=True):  # (a few values: Python's loop)
            if abs(value) > bound:
                return REJECT_IMPLAUSIBLE
        if self._tilt_twist and plan.name == "twist":
            z, R = self._ctx.tilt.project_twist(plan.local, z, R, stamp)
        return plan, z, (R if self._scale == 1.0 else R * self._scale)  # (R is the part's own copy)

    def _floor_zero_variances(self, part: MeasurementPart, fused: np.ndarray) -> MeasurementPart:
        """A zero variance on a fused field becomes ``zero_variance_floor``: counted, warned once."""
        floor = self._ctx.config.zero_variance_floor
        floored = floor_zero_variances(part, fused, floor)
        if floored is not part:
            self._stats.zero_variances_floored += 1
            if not self._warned_floor:
                self._warned_floor = True
                self._ctx.warn(f"{self.name}: zero variance on a fused field ({part.name}); using "
                               f"zero_variance_floor = {floor:g}")
        return floored


def parts_handler(inp: InputConfig, ctx: FusionContext) -> PartsHandler:
    return PartsHandler(inp, ctx)
