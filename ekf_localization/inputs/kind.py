"""What an input kind is: its ROS message, how a message becomes a record, and how it is fused.

An input kind (``odom``, ``pose``, ``twist``, ``imu``, ``joint``, ``landmark``) is one module of
this package that defines ``KIND``, and one line of the registry (``inputs/__init__.py``).
From it, with no other edit: ekf_node subscribes to ``<kind>N`` topics with ``message_type``,
bag_replay reads them, the parameter schema takes ``<kind>N_...`` settings, and the Localizer
fuses them.

Two ways to be fused:

* **Parts** (robot_localization's kinds): the record has parts of RL's 15 fields (``parts``:
  name, first field, length) and ``<kind>N_config`` picks the fields; the Localizer checks
  and fuses them as linear measurements of the state.
* **Own fusion** (``fusion`` set): the kind's parameters build a :class:`Fusion`, which gives
  one measurement model and turns each record into (z, R) or a rejection reason.

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
from ekf_localization.core.units import stamp_to_ns


class Fusion(Protocol):
    """An input's own measurement: ``part`` names it (its NIS key, its rejection threshold)."""

    part: str

    def measurement_model(self, field_to_state: Mapping[int, int], n: int) -> tuple[Any, tuple[int, ...]]:
        """(a measurement model for the engine (``m``, ``z_is_angle``, ``h``, ``jacobian``), the
        components whose residual is an angle) on a state whose RL fields are ``field_to_state``."""

    def fuse(self, record: Any, base_frame: str) -> tuple[np.ndarray, np.ndarray] | str:
        """(z, R) of a record, or the REJECT_* reason it cannot be fused."""


@dataclass(frozen=True)
class ParameterSpec:
    """One ``<kind>N_<name>`` parameter of a kind with its own fusion (ros.ekf_parameters makes
    the schema entry): type "float" | "floats" | "bool" | "str", default, unit, one line of doc,
    and a check with the form it expects."""

    name: str
    type: str
    default: Any
    unit: str
    doc: str
    check: Callable[[Any], bool] | None = None
    form: str = ""
    required: bool = False  # no default: the parameter must be given


@dataclass(frozen=True)
class InputKind:
    """An input kind: see the module docstring."""

    name: str  # the parameter prefix: <name>0, <name>1, ...
    message_type: str  # e.g. "nav_msgs/msg/Odometry"
    read: Callable[[Any], Any]  # message -> record (raises AttributeError/TypeError/ValueError)
    parts: tuple[tuple[str, int, int], ...] = ()  # (part, first RL field, length)
    thresholds: Mapping[str, str] = field(default_factory=dict)  # parameter suffix -> the part it gates
    parameters: tuple[ParameterSpec, ...] = ()  # an own-fusion kind's settings
    fusion: Callable[[Mapping[str, Any]], Fusion] | None = None  # its parameters' values -> Fusion

    @property
    def fields(self) -> frozenset[int]:
        """The RL fields a message of this kind can carry."""
        return frozenset(f for _, first, length in self.parts for f in range(first, first + length))


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
