"""What an input kind is: its ROS message, how a message becomes a record, its settings, and
the handler that fuses it.

An input kind (``odom``, ``pose``, ``twist``, ``imu``, ``joint``, ``landmark``,
``tag_corners``) is one module of this package that defines ``KIND``, and one line of the
registry (``inputs/__init__.py``). From it, with no other edit: ekf_node subscribes to
``<kind>N`` topics with ``message_type``, bag_replay reads them, the parameter schema takes
``<kind>N_...`` settings (``common`` and ``parameters``), ``configure`` turns their values into
the input's settings, and the Localizer fuses its messages through ``handler``
(core.fusion_context.Handler). Nothing outside this package branches on a kind's name.

Handlers come in three shapes here: robot_localization's parts (inputs/parts.py: odom, pose,
twist, imu), encoder speeds (inputs/joint.py), and a kind with its own measurement model
(:class:`FusionHandler`: landmark, tag_corners).

Readers are duck-typed on field names (``msg.header.stamp.sec`` ...), so the same function
reads an rclpy message live and a rosbags message from a bag. No ROS imports here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ekf_localization.core.angles import quaternion_to_rpy
from ekf_localization.core.config import InputConfig
from ekf_localization.core.fusion_context import Fused, FusionContext, Handler
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.part_plans import PartPlan
from ekf_localization.core.units import stamp_to_ns


@dataclass(frozen=True)
class ParameterSpec:
    """One ``<kind>N_<name>`` parameter (ros.input_parameters makes the schema entry): type
    "float" | "float_list" | "bool" | "bool_list" | "str" | "str_list", default, unit, one line
    of doc, and a check with the form it expects."""

    name: str
    type: str
    default: Any
    unit: str
    doc: str
    check: Callable[[Any], bool] | None = None
    form: str = ""
    required: bool = False  # no default: the parameter must be given


@dataclass
class Report:
    """What ``configure`` found: (parameter, expected form, the value given) problems, and notes
    for the log."""

    problems: list[tuple[str, str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def problem(self, parameter: str, form: str, got: Any = None) -> None:
        self.problems.append((parameter, form, got))

    def warn(self, text: str) -> None:
        self.notes.append(text)


Configure = Callable[[Mapping[str, Any], str, MotionModelSpec, Report], Any]


@dataclass(frozen=True)
class InputKind:
    """An input kind: see the module docstring."""

    name: str  # the parameter prefix: <name>0, <name>1, ...
    message_type: str  # e.g. "nav_msgs/msg/Odometry"
    read: Callable[[Any], Any]  # message -> record (raises AttributeError/TypeError/ValueError)
    configure: Configure  # (parsed values with "topic", input name, model, report) -> settings
    handler: Callable[[InputConfig, FusionContext], Handler]
    parts: tuple[tuple[str, int, int], ...] = ()  # (part, first RL field, length) of a parts kind
    thresholds: Mapping[str, str] = field(default_factory=dict)  # parameter suffix -> the part it gates
    common: tuple[ParameterSpec, ...] = ()  # settings shared with kinds of its shape (documented once)
    parameters: tuple[ParameterSpec, ...] = ()  # its own settings
    absolute_pose: bool = False  # its records are fixes of the robot's pose in the world (a camera's)

    @property
    def fields(self) -> frozenset[int]:
        """The RL fields a message of this kind can carry."""
        return frozenset(f for _, first, length in self.parts for f in range(first, first + length))


# --- a kind with its own measurement model ---------------------------------------------------------

class Fusion(Protocol):
    """An input's own measurement: ``part`` names it (its NIS key, its rejection threshold)."""

    part: str

    def measurement_model(self, field_to_state: Mapping[int, int], n: int) -> tuple[Any, tuple[int, ...]]:
        """(a measurement model for the engine (``m``, ``z_is_angle``, ``h``, ``jacobian``), the
        components whose residual is an angle) on a state whose RL fields are ``field_to_state``."""

    def fuse(self, record: Any, base_frame: str) -> tuple[np.ndarray, np.ndarray] | str:
        """(z, R) of a record, or the REJECT_* reason it cannot be fused. A fusion with
        ``uses_estimate`` true also gets the filter's estimate at the stamp (or None); one with
        ``widen_above`` has the residual check's NIS bound (core.ekf update)."""


class FusionHandler:
    """An input whose settings are a :class:`Fusion`: one update per message, (z, R) from the
    fusion, R scaled by ``variance_scale``."""

    def __init__(self, inp: InputConfig, ctx: FusionContext) -> None:
        fusion: Fusion = inp.settings
        model, angle_local = fusion.measurement_model(ctx.field_to_state, len(ctx.x_is_angle))
        local = np.arange(model.m, dtype=np.intp)
        self._plan = PartPlan(fusion.part, local, np.ix_(local, local), model, inp.threshold(fusion.part),
                              ctx.config.base_link_frame, angle_local=tuple(angle_local),
                              nis_key=f"{inp.name}/{fusion.part}",
                              widen_above=getattr(fusion, "widen_above", math.inf))
        self.plans = (self._plan,)
        self._fusion = fusion
        self._scale = inp.variance_scale
        self._base_frame = ctx.config.base_link_frame
        self._estimate_at = ctx.estimate_at if getattr(fusion, "uses_estimate", False) else None

    def reset(self) -> None:
        """Nothing kept between messages."""

    def fuse(self, record: Any, stamp: int) -> Fused:
        if self._estimate_at is None:
            zR = self._fusion.fuse(record, self._base_frame)
        else:
            zR = self._fusion.fuse(record, self._base_frame, self._estimate_at(stamp))
        if isinstance(zR, str):
            return Fused(stamp, (), rejected=((self._plan.name, zR),))
        return Fused(stamp, ((self._plan, zR[0], zR[1] * self._scale),))


def fusion_kind(name: str, message_type: str, read: Callable[[Any], Any], part: str,
                make: Callable[[Mapping[str, Any]], Fusion], parameters: tuple[ParameterSpec, ...],
                common: tuple[ParameterSpec, ...]) -> InputKind:
    """A kind fused by its own :class:`Fusion` (``make``: its parameters' values -> the fusion,
    whose measurement is named ``part``), gated by ``<kind>N_rejection_threshold``."""

    def configure(values: Mapping[str, Any], input_name: str, spec: MotionModelSpec, report: Report) -> Any:
        fusion = make(values)
        try:
            fusion.measurement_model({f: i for i, f in enumerate(spec.state_fields)}, len(spec.state_fields))
        except ValueError as exc:
            report.problem(input_name, f"an input model '{spec.name}' can fuse ({exc})", values["topic"])
            return None
        return fusion

    return InputKind(name, message_type, read, configure, FusionHandler,
                     thresholds={"_rejection_threshold": part}, common=common, parameters=parameters)


# --- message fields shared by the readers ---------------------------------------------------------

def covariance(c, size: int) -> np.ndarray:
    """A row-major covariance array as (size, size); NaNs when it has the wrong length (the
    Localizer rejects it as non-finite). A copy: a bag's arrays are read-only views."""
    a = np.array(c, dtype=float)
    if a.size != size * size:
        return np.full((size, size), math.nan)
    return a.reshape(size, size)


def pose6(p) -> np.ndarray:
    """geometry_msgs/Pose -> [x y z roll pitch yaw]."""
    q = p.orientation
    roll, pitch, yaw = quaternion_to_rpy(q.x, q.y, q.z, q.w)
    return np.array([p.position.x, p.position.y, p.position.z, roll, pitch, yaw], dtype=float)


def twist6(t) -> np.ndarray:
    """geometry_msgs/Twist -> [vx vy vz wx wy wz]."""
    return np.array([t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z], dtype=float)


def header_of(msg) -> tuple[int, str]:
    """(stamp in integer ns, frame_id) of a message's header."""
    return stamp_to_ns(msg.header.stamp), str(msg.header.frame_id)
