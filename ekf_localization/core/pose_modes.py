"""robot_localization's ``<input>_differential`` and ``<input>_relative`` modes of pose data (no ROS).

* **Differential**: successive poses (of base_link, in the sensor's own world-fixed frame)
  become a body velocity: with the previous pose ``(R₀, p₀)`` and the new one ``(R₁, p₁)``
  ``dt`` apart, ``v = R₀ᵀ·(p₁ − p₀)/dt`` and ``ω = log(R₀ᵀ·R₁)/dt`` in the body axes of the
  previous pose. The two poses' fixed-axis covariances are rotated into those axes and
  added, over ``dt²`` (treating the two poses as independent errors; an integrated
  odometry pose's correlated errors make this conservative). A constant offset between
  the sensor's frame and the world (an odometry pose in ``odom``, an IMU's yaw zeroed at
  power-on, a Pinpoint/OTOS origin) cancels. The first message gives no velocity.
* **Relative**: poses relative to the first one, ``T₀⁻¹·T``, fused as poses in the world
  frame (the robot starts at the world origin; its covariance is rotated by ``R₀ᵀ``).
"""

from __future__ import annotations

import numpy as np

from ekf_localization.core.angles import matrix_to_rpy, rpy_to_matrix
from ekf_localization.core.frames import masked_matmul
from ekf_localization.core.units import ns_to_seconds


def _block_rotate(R: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """C -> B·C·Bᵀ with B = blockdiag(R, R, ...) matching C's size (3 or 6)."""
    B = np.kron(np.eye(cov.shape[0] // 3), R)
    return masked_matmul(masked_matmul(B, cov), B.T)


class PoseDifferentiator:
    """Successive poses [x y z roll pitch yaw] (or orientations [roll pitch yaw]) -> body rates."""

    def __init__(self) -> None:
        self._prev: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None

    def reset(self) -> None:
        self._prev = None

    def update(self, stamp_ns: int, values: np.ndarray,
               cov: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None | str:
        """(rates, covariance) for this message; None for the first; "not_increasing" for an old stamp."""
        values = np.asarray(values, dtype=float)
        cov = np.asarray(cov, dtype=float)
        R = rpy_to_matrix(*values[-3:])
        prev = self._prev
        if prev is not None and stamp_ns <= prev[0]:
            return "not_increasing"
        self._prev = (int(stamp_ns), values, cov, R)
        if prev is None:
            return None
        t0, v0, c0, R0 = prev
        from scipy.spatial.transform import Rotation  # only differential inputs pay its import (0.35 s)

        dt = ns_to_seconds(stamp_ns - t0)
        w = Rotation.from_matrix(R0.T @ R).as_rotvec() / dt
        rates = w if values.size == 3 else np.concatenate([R0.T @ (values[:3] - v0[:3]) / dt, w])
        return rates, (_block_rotate(R0.T, c0) + _block_rotate(R0.T, cov)) / (dt * dt)


class PoseRelative:
    """Poses relative to the first one received: T₀⁻¹·T (orientations: R₀ᵀ·R)."""

    def __init__(self) -> None:
        self._first: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self) -> None:
        self._first = None

    def update(self, values: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        values = np.asarray(values, dtype=float)
        R = rpy_to_matrix(*values[-3:])
        if self._first is None:
            self._first = (values.copy(), R)
        v0, R0 = self._first
        rpy = matrix_to_rpy(R0.T @ R)
        out = rpy if values.size == 3 else np.concatenate([R0.T @ (values[:3] - v0[:3]), rpy])
        return out, _block_rotate(R0.T, np.asarray(cov, dtype=float))
