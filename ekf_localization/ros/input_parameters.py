"""ekf_node's per-input parameters (``odom0``, ``odom0_config``, ``landmark0_position``, ...): the
schemas of each input kind (ekf_localization.inputs) and their parsing into an
:class:`InputConfig` (no rclpy). Names follow robot_localization where the concept is the same.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

from ekf_localization.core.config import InputConfig
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.inputs import KINDS
from ekf_localization.inputs.kind import InputKind, ParameterSpec, Report
from ekf_localization.ros.parameters import (
    REQUIRED,
    Check,
    Entry,
    Problem,
    Schema,
    at_least,
    expected,
)

NODE_NAME = "ekf_node"
DOC = "docs/ekf_node.md"
INPUT_KINDS = tuple(KINDS)  # ekf_localization.inputs: one module per kind
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
_THRESHOLD = Check(lambda v: v > 0.0, "a Mahalanobis distance in sigmas > 0")


def _entry(p: ParameterSpec) -> Entry:
    """An input kind's parameter (inputs.kind.ParameterSpec) as a schema entry."""
    return Entry(p.name, p.type, REQUIRED if p.required else p.default, p.unit, p.doc,
                 Check(p.check, p.form) if p.check is not None else None)


def _thresholds(kind: str) -> tuple[Entry, ...]:
    alias = " (alias of the twist threshold)"
    return tuple(Entry(suffix[1:], "float", math.inf, "σ",
                       f"Mahalanobis gate on {_PART_DOC.get(part, 'the ' + part.replace('_', ' '))}"
                       + (alias if suffix.startswith("_angular") else ""), _THRESHOLD)
                 for suffix, part in THRESHOLD_SUFFIXES[kind].items())


def _common(kind: InputKind) -> Schema:
    """The queue size and the settings a kind shares with kinds of its shape (``config`` first)."""
    entries = [_entry(p) for p in kind.common]
    return Schema(NODE_NAME, DOC, tuple(entries[:1] + [_QUEUE] + entries[1:]), ints_as_floats=True)


# Settings of one input, ``<input>_<name>`` (the input itself, ``odom0``, is its topic): the common
# ones per kind, documented once for robot_localization's kinds, and each kind's own.
COMMON_PARAMETERS: dict[str, Schema] = {name: _common(kind) for name, kind in KINDS.items()}
INPUT_PARAMETERS = _common(KINDS["odom"])
KIND_PARAMETERS: dict[str, Schema] = {
    name: Schema(NODE_NAME, DOC, _thresholds(name) + tuple(_entry(p) for p in kind.parameters),
                 ints_as_floats=True)
    for name, kind in KINDS.items()}

INPUT_RE = re.compile(rf"^({'|'.join(INPUT_KINDS)})(\d+)(.*)$")


def parse_input(values: Mapping[str, Any], kind: str, name: str, spec: MotionModelSpec,
                problems: list[Problem], warnings: list[str], claimed: set[str]) -> InputConfig | None:
    """Input ``name`` of ``kind``: its settings parsed and checked, its kind's ``configure`` run."""
    prefix = name + "_"
    claimed.add(name)
    topic = values[name]
    n_problems = len(problems)
    if not isinstance(topic, str) or not topic.strip():
        problems.append(expected(name, "a topic name", topic))
    schemas = (COMMON_PARAMETERS[kind], KIND_PARAMETERS[kind])
    parsed = [schema.parse(values, prefix) for schema in schemas]
    for schema, result in zip(schemas, parsed, strict=True):
        problems += result.problems
        claimed.update(prefix + e for e in schema)
        for e in schema.values():
            if result.values[e.name] is REQUIRED and prefix + e.name not in values:
                problems.append(expected(prefix + e.name, e.form + " (required)"))
    if "config" in schemas[0]:  # robot_localization's kinds
        for suffix in RL_INPUT_IGNORED:
            if prefix + suffix in values:
                claimed.add(prefix + suffix)
                warnings.append(f"parameter '{prefix + suffix}' (robot_localization) is not supported; "
                                "ignored")
    common, own = parsed
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
    if len(problems) > n_problems or any(v is REQUIRED for r in parsed for v in r.values.values()):
        return None
    report = Report()
    settings = KINDS[kind].configure({**common.values, **own.values, "topic": topic}, name, spec, report)
    warnings += report.notes
    problems += [expected(p, form) if got is None else expected(p, form, got)
                 for p, form, got in report.problems]
    if settings is None or report.problems:
        return None
    return InputConfig(name=name, kind=kind, topic=topic, settings=settings, handler=KINDS[kind].handler,
                       queue_size=common.values["queue_size"], rejection_thresholds=tuple(thresholds),
                       variance_scale=common.values.get("variance_scale", 1.0))
