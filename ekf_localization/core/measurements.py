"""Timestamped measurement records and their validation (no ROS imports).

Every record carries its header stamp in integer nanoseconds and the frame its data is
expressed in. Fields follow robot_localization's 15-field order
``x y z roll pitch yaw vx vy vz vroll vpitch vyaw ax ay az``: a record is split into
*parts* (pose, twist, orientation, angular velocity, linear acceleration), each covering a
contiguous run of those fields with its own covariance block, frame and rejection threshold.

Validation looks only at the fields a source fuses: a NaN in a field nobody fuses is not an
error. A part is rejected when a fused value or covariance entry is non-finite, the fused
covariance block is not symmetric or not positive definite (a zero variance included: the
update would collapse the state covariance), or its frame is not the expected one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

import numpy as np

from ekf_localization.core.linalg import (
    is_positive_definite,
    is_symmetric,
    rows_positive_definite,
    rows_symmetric,
)

FIELD_NAMES: tuple[str, ...] = ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz",
                                "vroll", "vpitch", "vyaw", "ax", "ay", "az")
N_FIELDS = 15

# Rejection reasons (diagnostics count them per source).
REJECT_NONFINITE = "nonfinite"
REJECT_COVARIANCE = "bad_covariance"
REJECT_FRAME = "wrong_frame"
REJECT_NO_TRANSFORM = "no_transform"
REJECT_STALE = "stale_stamp"
REJECT_FUTURE = "future_stamp"
REJECT_TOO_OLD = "older_than_history"
REJECT_GATED = "mahalanobis_gate"
REJECT_FILTER = "filter_update_failed"
REJECT_NOT_PROVIDED = "field_not_provided"
REJECT_LIMITS = "beyond_limits"  # a command beyond control_velocity_limits
REJECT_WHEEL_COUNT = "wrong_wheel_count"  # a wheel command without one speed per wheel
# sensor_msgs/JointState (dead-wheel encoders, ekf_localization.core.joint_states)
REJECT_ARRAY_LENGTHS = "unequal_array_lengths"
REJECT_DUPLICATE_NAMES = "duplicate_joint_names"
REJECT_JOINT_MISSING = "joint_missing"
REJECT_STAMP_NOT_INCREASING = "stamp_not_increasing"
REJECT_ENCODER_JUMP = "encoder_jump"  # a position step faster than max_speed: reset or wrap
REJECT_TILT_RANGE = "tilt_out_of_range"  # IMU roll or pitch beyond core.tilt.MAX_TILT_RAD
REJECT_IMPLAUSIBLE = "implausible_value"  # beyond the max_plausible_* limits (EkfConfig.plausible_bounds)
REJECT_ZERO_STAMP = "zero_stamp"  # stamped 0 while no clock is known: no time to put it at
REJECT_UNREADABLE = "unreadable_message"  # bytes or fields that do not read as the input's type
REJECT_NO_FRAME = "no_frame"  # an empty header.frame_id and no <input>_default_frame_id to take
REJECT_DUPLICATE = "duplicate"  # same input, stamp and content as a recent message (core.duplicates)
REJECT_SLIP = "slip"  # wheel speeds while the wheels slip (inputs.slip)
REJECT_OVERLOADED = "overloaded"  # lagged so far that its rewind would exceed timeline.MAX_REPLAY_ENTRIES
REJECT_REASONS = (REJECT_NONFINITE, REJECT_COVARIANCE, REJECT_FRAME, REJECT_NO_TRANSFORM, REJECT_STALE,
                  REJECT_FUTURE, REJECT_TOO_OLD, REJECT_GATED, REJECT_FILTER, REJECT_NOT_PROVIDED,
                  REJECT_ARRAY_LENGTHS, REJECT_DUPLICATE_NAMES, REJECT_JOINT_MISSING,
                  REJECT_STAMP_NOT_INCREASING, REJECT_ENCODER_JUMP, REJECT_TILT_RANGE,
                  REJECT_LIMITS, REJECT_IMPLAUSIBLE, REJECT_ZERO_STAMP,
                  REJECT_WHEEL_COUNT, REJECT_UNREADABLE, REJECT_DUPLICATE, REJECT_NO_FRAME,
                  REJECT_OVERLOADED, REJECT_SLIP)


@dataclass(frozen=True, eq=False)
class MeasurementPart:
    """A contiguous run of fields ``first_field .. first_field + len(values) - 1``."""

    name: str  # "pose", "twist", "orientation", "angular_velocity", "linear_acceleration"
    first_field: int
    frame_id: str
    values: np.ndarray
    covariance: np.ndarray
    provided: bool = True  # False: the message says it has no such data (sensor_msgs/Imu: cov[0] = -1)
    child_frame_id: str = ""  # a pose part of an odometry message: the frame whose pose it is


class PartLayout(NamedTuple):
    """Where one part of a message record lives: the attributes its data is read from."""

    name: str
    first_field: int
    values: str  # attribute holding the values
    covariance: str  # attribute holding the covariance block
    frame: str  # attribute holding the frame the values are in
    child_frame: str = ""  # attribute naming the frame whose pose it is (odometry's pose part)
    flags_not_provided: bool = False  # covariance[0, 0] == -1 means "no such data" (sensor_msgs/Imu)


def parts_of(record, layout: tuple[PartLayout, ...]) -> tuple[MeasurementPart, ...]:
    """The record's parts as its class's ``LAYOUT`` describes them."""
    out = []
    for lay in layout:
        cov = getattr(record, lay.covariance)
        child = getattr(record, lay.child_frame) if lay.child_frame else ""
        out.append(MeasurementPart(lay.name, lay.first_field, getattr(record, lay.frame),
                                   getattr(record, lay.values), cov,
                                   provided=not (lay.flags_not_provided and cov[0, 0] == -1.0),
                                   child_frame_id=child))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class PoseMeasurement:
    """geometry_msgs/PoseWithCovarianceStamped: [x y z roll pitch yaw] in ``frame_id``."""

    LAYOUT: ClassVar[tuple[PartLayout, ...]] = (PartLayout("pose", 0, "pose", "covariance", "frame_id"),)
    stamp_ns: int
    frame_id: str
    pose: np.ndarray  # (6,)
    covariance: np.ndarray  # (6, 6), x y z rotX rotY rotZ

    def parts(self) -> tuple[MeasurementPart, ...]:
        return parts_of(self, self.LAYOUT)


@dataclass(frozen=True, eq=False)
class TwistMeasurement:
    """geometry_msgs/TwistWithCovarianceStamped: body twist [vx vy vz wx wy wz] in ``frame_id``."""

    LAYOUT: ClassVar[tuple[PartLayout, ...]] = (PartLayout("twist", 6, "twist", "covariance", "frame_id"),)
    stamp_ns: int
    frame_id: str
    twist: np.ndarray  # (6,)
    covariance: np.ndarray  # (6, 6)

    def parts(self) -> tuple[MeasurementPart, ...]:
        return parts_of(self, self.LAYOUT)


@dataclass(frozen=True, eq=False)
class OdometryMeasurement:
    """nav_msgs/Odometry: pose in ``frame_id``, twist in ``child_frame_id``."""

    LAYOUT: ClassVar[tuple[PartLayout, ...]] = (
        PartLayout("pose", 0, "pose", "pose_covariance", "frame_id", child_frame="child_frame_id"),
        PartLayout("twist", 6, "twist", "twist_covariance", "child_frame_id"))
    stamp_ns: int
    frame_id: str
    child_frame_id: str
    pose: np.ndarray  # (6,)
    pose_covariance: np.ndarray  # (6, 6)
    twist: np.ndarray  # (6,)
    twist_covariance: np.ndarray  # (6, 6)

    def parts(self) -> tuple[MeasurementPart, ...]:
        return parts_of(self, self.LAYOUT)


@dataclass(frozen=True, eq=False)
class ImuMeasurement:
    """sensor_msgs/Imu in ``frame_id``; a covariance whose first entry is -1 means "not provided"."""

    LAYOUT: ClassVar[tuple[PartLayout, ...]] = tuple(
        PartLayout(name, first, name, f"{name}_covariance", "frame_id", flags_not_provided=True)
        for name, first in (("orientation", 3), ("angular_velocity", 9), ("linear_acceleration", 12)))
    stamp_ns: int
    frame_id: str
    orientation: np.ndarray  # (3,) roll pitch yaw
    orientation_covariance: np.ndarray  # (3, 3)
    angular_velocity: np.ndarray  # (3,)
    angular_velocity_covariance: np.ndarray  # (3, 3)
    linear_acceleration: np.ndarray  # (3,)
    linear_acceleration_covariance: np.ndarray  # (3, 3)

    def parts(self) -> tuple[MeasurementPart, ...]:
        return parts_of(self, self.LAYOUT)


@dataclass(frozen=True, eq=False)
class ControlCommand:
    """geometry_msgs/Twist on cmd_vel: commanded body twist [vx vy vz wx wy wz], stamped on receipt."""

    stamp_ns: int
    twist: np.ndarray = field(default_factory=lambda: np.zeros(6))


@dataclass(frozen=True, eq=False)
class JointStateMeasurement:
    """sensor_msgs/JointState: per joint a name, position (rad) and optionally velocity (rad/s).

    ``velocities`` (and ``efforts``) are empty when the message has none; validation is
    :class:`ekf_localization.core.joint_states.EncoderSpeeds`.
    """

    stamp_ns: int
    names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray = field(default_factory=lambda: np.zeros(0))
    efforts: np.ndarray = field(default_factory=lambda: np.zeros(0))


Measurement = (PoseMeasurement | TwistMeasurement | OdometryMeasurement | ImuMeasurement
               | JointStateMeasurement)


def _block_problem(values: np.ndarray, cov: np.ndarray, idx: np.ndarray) -> str | None:
    """None when values[idx] and the block cov[idx, idx] are finite and the block is symmetric
    positive definite (a Cholesky factor exists), else the REJECT_* reason."""
    block = cov[idx[:, None], idx]
    if not (np.isfinite(values[idx]).all() and np.isfinite(block).all()):
        return REJECT_NONFINITE
    if not is_symmetric(block) or not is_positive_definite(block):
        return REJECT_COVARIANCE
    return None


def fused_values(part: MeasurementPart, fused: np.ndarray, block: tuple[np.ndarray, np.ndarray],
                 expected_frame: str) -> tuple[np.ndarray, np.ndarray] | str:
    """(z, R): the fused values ``part.values[fused]`` and their covariance ``part.covariance[block]``
    (``block`` = np.ix_(fused, fused)), or why they cannot be fused, in :func:`check_part`'s order."""
    if not part.provided:
        return REJECT_NOT_PROVIDED
    z = np.asarray(part.values, dtype=float)[fused]
    R = np.asarray(part.covariance, dtype=float)[block]
    rows = R.tolist()  # (Python's sums and tests cost less than numpy's calls at these sizes)
    # (a finite sum is the usual case)
    if not math.isfinite(sum(z.tolist()) + sum(map(sum, rows))) and not (
            np.isfinite(z).all() and np.isfinite(R).all()):
        return REJECT_NONFINITE
    if part.frame_id.lstrip("/") != expected_frame:
        return REJECT_FRAME
    if not rows_symmetric(rows):
        return REJECT_COVARIANCE
    return (z, R) if rows_positive_definite(R, rows) else REJECT_COVARIANCE


def check_part(part: MeasurementPart, fused: np.ndarray, expected_frame: str) -> str | None:
    """Why ``part`` cannot be fused (a REJECT_* reason), or None if it is fine.

    ``fused`` are the indices (intp array), within the part, of the fields to fuse. The order
    of the reasons: not provided, non-finite, wrong frame, bad covariance."""
    fused = np.asarray(fused, dtype=np.intp)
    checked = fused_values(part, fused, np.ix_(fused, fused), expected_frame)
    return checked if isinstance(checked, str) else None


def covariance_problem(C: np.ndarray) -> str | None:
    """None if C is finite, symmetric and positive definite, else the REJECT_* reason."""
    C = np.asarray(C, dtype=float)
    return _block_problem(np.zeros(C.shape[0]), C, np.arange(C.shape[0], dtype=np.intp))


def implausible(values: np.ndarray, first_field: int, fused: np.ndarray, bounds: np.ndarray) -> str | None:
    """REJECT_IMPLAUSIBLE when a fused value (``values[fused]``, fields ``first_field + fused``)
    is larger in magnitude than its field's bound (``bounds``: (15,), RL field order), else None."""
    idx = np.asarray(fused, dtype=np.intp)
    values = np.asarray(values, dtype=float)
    return REJECT_IMPLAUSIBLE if (np.abs(values[idx]) > bounds[first_field + idx]).any() else None


def check_stamp(stamp_ns: int, now_ns: int | None, max_age_ns: int, future_tolerance_ns: int) -> str | None:
    """REJECT_STALE / REJECT_FUTURE against the receiver's clock ``now_ns`` (None: no clock yet)."""
    if now_ns is None:
        return None
    if stamp_ns < now_ns - max_age_ns:
        return REJECT_STALE
    if stamp_ns > now_ns + future_tolerance_ns:
        return REJECT_FUTURE
    return None
