"""Angle helpers: wrapping to (-pi, pi], quaternion <-> yaw / roll-pitch-yaw and quaternion /
roll-pitch-yaw <-> rotation matrix (REP-103: fixed axes, R = Rz(yaw)·Ry(pitch)·Rx(roll), yaw CCW;
quaternions (x, y, z, w) as in geometry_msgs).

The one module for angles and quaternions: the message conversions, the frames, the models
and the simulator all call these; no other module writes a quaternion formula
(``test/test_one_of_each.py``).
"""

from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * math.pi


def wrap_angle(a: float) -> float:
    """Wrap a scalar angle to (-pi, pi] (nan for a non-finite angle)."""
    w = a + math.pi
    if not 0.0 < w < TWO_PI:  # inside, % would return w itself: skip its fmod (5x the rest)
        w %= TWO_PI  # [0, 2pi], exact
        if w <= 0.0:
            w += TWO_PI
    return w - math.pi


def wrap_angles(a: np.ndarray) -> np.ndarray:
    """Vectorised wrap to (-pi, pi]."""
    w = np.mod(np.asarray(a, dtype=float) + np.pi, TWO_PI)
    w = np.where(w <= 0.0, w + TWO_PI, w)
    return w - np.pi


def yaw_to_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation about +z by ``yaw``."""
    return 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)


def rpy_to_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of fixed-axis roll, pitch, yaw (R = Rz(yaw)·Ry(pitch)·Rx(roll), REP-103)."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def _scaled_quaternion(x: float, y: float, z: float, w: float) -> tuple[float, float, float, float]:
    """The quaternion divided by its largest component (so squares neither overflow nor underflow:
    1e200 or 1e-200 times a unit quaternion is fine); all nan when it has no orientation (all
    zero or not finite)."""
    m = max(abs(x), abs(y), abs(z), abs(w))
    if not (math.isfinite(m) and m > 0.0) or not (math.isfinite(x) and math.isfinite(y)
                                                  and math.isfinite(z) and math.isfinite(w)):
        return math.nan, math.nan, math.nan, math.nan
    return x / m, y / m, z / m, w / m


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    """Yaw (rotation about +z, ZYX convention) of a quaternion, in (-pi, pi].

    The quaternion need not be normalised (any finite scale); a zero or non-finite one has no
    orientation and gives nan (which the filter rejects as a non-finite measurement).
    """
    x, y, z, w = _scaled_quaternion(x, y, z, w)
    if math.isnan(w):
        return math.nan
    norm2 = x * x + y * y + z * z + w * w
    return wrap_angle(math.atan2(2.0 * (w * z + x * y), norm2 - 2.0 * (y * y + z * z)))


def quaternion_to_rpy(x: float, y: float, z: float, w: float) -> tuple[float, float, float]:
    """Roll, pitch, yaw (fixed axes X, Y, Z) of a quaternion (need not be normalised; all nan
    when it has no orientation, as in :func:`quaternion_to_yaw`)."""
    x, y, z, w = _scaled_quaternion(x, y, z, w)
    if math.isnan(w):
        return math.nan, math.nan, math.nan
    yaw = quaternion_to_yaw(x, y, z, w)
    s = 2.0 / (x * x + y * y + z * z + w * w)
    roll = math.atan2(s * (w * x + y * z), 1.0 - s * (x * x + y * y))
    sp = s * (w * y - z * x)
    pitch = math.copysign(math.pi / 2.0, sp) if abs(sp) >= 1.0 else math.asin(sp)
    return roll, pitch, yaw


def quaternion_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """(3, 3) rotation of a quaternion (normalised here)."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0.0 or not math.isfinite(n):
        return np.full((3, 3), math.nan)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def rpy_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw)·Ry(pitch)·Rx(roll) (REP-103 fixed axes)."""
    return quaternion_to_matrix(*rpy_to_quaternion(roll, pitch, yaw))


def matrix_to_rpy(R: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of a rotation matrix, the inverse of :func:`rpy_to_matrix`."""
    pitch = math.asin(max(-1.0, min(1.0, -float(R[2, 0]))))
    return np.array([math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])])
