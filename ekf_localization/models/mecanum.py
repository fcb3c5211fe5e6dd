"""Mecanum-drive process model (seed 000, eq. 19-27).

State ``[x y θ ẋ ẏ θ̇]``: field-frame pose, body-frame velocities (REP-103: x forward,
y left, θ CCW). Control: either a body twist ``[ẋ ẏ θ̇]`` or the four wheel speeds
``[m1 m2 m3 m4]`` (rad/s), converted with eq. 23-24.

Wheel numbering follows the signs of eq. 24 (positive wheel speed drives the robot
forward): m1 and m3 are on the left (they slow down for a CCW turn), m2 and m4 on the
right; strafing left (+ẏ) spins m1 and m4 forward and m2, m3 backward, so with the
usual X roller pattern (seen from above) m1 = rear-left, m2 = rear-right,
m3 = front-left, m4 = front-right. L and l are the half wheelbase and half track (eq. 23).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ekf_localization.kernels import njit

N_STATE = 6
X, Y, THETA, VX, VY, VTH = range(N_STATE)


@dataclass(frozen=True)
class MecanumKinematics:
    """Wheel radius r, half wheelbase L and half track l (eq. 23), metres (or inches, consistently)."""

    wheel_radius: float
    half_length: float
    half_width: float

    def __post_init__(self) -> None:
        for name in ("wheel_radius", "half_length", "half_width"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name} must be a positive finite number, got {v!r}")

    @property
    def forward_matrix(self) -> np.ndarray:
        """(3, 4) wheels -> body twist, eq. 23."""
        k = 1.0 / (self.half_length + self.half_width)
        return (self.wheel_radius / 4.0) * np.array(
            [[1.0, 1.0, 1.0, 1.0], [1.0, -1.0, -1.0, 1.0], [-k, k, -k, k]])

    @property
    def inverse_matrix(self) -> np.ndarray:
        """(4, 3) body twist -> wheels, the exact inverse of eq. 23 on its range."""
        k = self.half_length + self.half_width
        return (1.0 / self.wheel_radius) * np.array(
            [[1.0, 1.0, -k], [1.0, -1.0, k], [1.0, -1.0, -k], [1.0, 1.0, k]])

    def wheels_to_twist(self, wheels: np.ndarray) -> np.ndarray:
        """Eq. 24: (..., 4) wheel speeds -> (..., 3) body twist."""
        return np.asarray(wheels, dtype=float) @ self.forward_matrix.T

    def twist_to_wheels(self, twist: np.ndarray) -> np.ndarray:
        """(..., 3) body twist -> (..., 4) wheel speeds."""
        return np.asarray(twist, dtype=float) @ self.inverse_matrix.T


@njit(cache=True)
def _f(Xs: np.ndarray, V: np.ndarray, dt: float, has_control: bool) -> np.ndarray:
    N = Xs.shape[0]
    out = np.empty((N, 6))
    for b in range(N):
        th = Xs[b, 2]
        c = math.cos(th)
        s = math.sin(th)
        vx = Xs[b, 3]
        vy = Xs[b, 4]
        out[b, 0] = Xs[b, 0] + dt * (vx * c - vy * s)  # eq. 22
        out[b, 1] = Xs[b, 1] + dt * (vx * s + vy * c)
        out[b, 2] = th + dt * Xs[b, 5]
        if has_control:  # eq. 24-25: velocities from the command
            out[b, 3] = V[b, 0]
            out[b, 4] = V[b, 1]
            out[b, 5] = V[b, 2]
        else:  # no command: constant body velocity
            out[b, 3] = vx
            out[b, 4] = vy
            out[b, 5] = Xs[b, 5]
    return out


@njit(cache=True)
def _jacobian(Xs: np.ndarray, dt: float, has_control: bool) -> np.ndarray:
    F = np.zeros((Xs.shape[0], 6, 6))
    _fill_jacobian(Xs, dt, has_control, F)
    return F


@njit(cache=True)
def _f_and_jacobian(Xs: np.ndarray, V: np.ndarray, dt: float,
                    has_control: bool) -> tuple[np.ndarray, np.ndarray]:
    F = np.zeros((Xs.shape[0], 6, 6))
    _fill_jacobian(Xs, dt, has_control, F)
    return _f(Xs, V, dt, has_control), F


@njit(cache=True)
def _fill_jacobian(Xs: np.ndarray, dt: float, has_control: bool, F: np.ndarray) -> None:
    for b in range(Xs.shape[0]):
        th = Xs[b, 2]
        c = math.cos(th)
        s = math.sin(th)
        vx = Xs[b, 3]
        vy = Xs[b, 4]
        F[b, 0, 0] = 1.0  # eq. 27
        F[b, 0, 2] = dt * (-vx * s - vy * c)
        F[b, 0, 3] = dt * c
        F[b, 0, 4] = -dt * s
        F[b, 1, 1] = 1.0
        F[b, 1, 2] = dt * (vx * c - vy * s)
        F[b, 1, 3] = dt * s
        F[b, 1, 4] = dt * c
        F[b, 2, 2] = 1.0
        F[b, 2, 5] = dt
        if not has_control:
            F[b, 3, 3] = 1.0
            F[b, 4, 4] = 1.0
            F[b, 5, 5] = 1.0


@dataclass
class MecanumModel:
    """Process model of eq. 22-27 with a parameterised Q (eq. 26).

    Q = diag(pose_variance_rate · dt, velocity_variance_per_step + velocity_variance_rate · dt).
    Seed 000 uses pose_variance_rate = 0.002 in²/s (per component) and
    velocity_variance_per_step = 0.45 (in/s)² with velocity_variance_rate = 0.
    ``control`` is "twist" (U is (N, 3)) or "wheels" (U is (N, 4), needs ``kinematics``).
    With U = None the body velocity is held constant (a random walk driven by Q).
    """

    pose_variance_rate: np.ndarray = field(default_factory=lambda: np.full(3, 0.002))
    velocity_variance_per_step: np.ndarray = field(default_factory=lambda: np.full(3, 0.45))
    velocity_variance_rate: np.ndarray = field(default_factory=lambda: np.zeros(3))
    control: str = "twist"
    kinematics: MecanumKinematics | None = None
    n: int = N_STATE
    x_is_angle: np.ndarray = field(default_factory=lambda: np.array([0, 0, 1, 0, 0, 0], dtype=np.bool_))

    def __post_init__(self) -> None:
        for name in ("pose_variance_rate", "velocity_variance_per_step", "velocity_variance_rate"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape == ():
                v = np.full(3, float(v))
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v < 0.0):
                raise ValueError(f"{name} must be 3 finite non-negative variances, got {v!r}")
            setattr(self, name, v)
        if self.control not in ("twist", "wheels"):
            raise ValueError(f"control must be 'twist' or 'wheels', got {self.control!r}")
        if self.control == "wheels" and self.kinematics is None:
            raise ValueError("control='wheels' needs kinematics")
        self._q_cache: tuple[float, bool, np.ndarray] | None = None

    def _twist(self, U: np.ndarray | None, N: int) -> np.ndarray:
        if U is None:
            return np.zeros((N, 3))
        U = np.asarray(U, dtype=float)
        if self.control == "wheels":
            return self.kinematics.wheels_to_twist(U)  # type: ignore[union-attr]
        return U

    def f(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        return _f(X, self._twist(U, X.shape[0]), dt, U is not None)

    def jacobian(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        return _jacobian(X, dt, U is not None)

    def f_and_jacobian(self, X: np.ndarray, U: np.ndarray | None,
                       dt: float) -> tuple[np.ndarray, np.ndarray]:
        return _f_and_jacobian(X, self._twist(U, X.shape[0]), dt, U is not None)

    def noise(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        has_u = U is not None
        c = self._q_cache
        if c is not None and c[0] == dt and c[1] == has_u:
            return c[2]
        vel = self.velocity_variance_rate * dt + (self.velocity_variance_per_step if has_u else 0.0)
        Q = np.diag(np.concatenate([self.pose_variance_rate * dt, vel]))
        self._q_cache = (dt, has_u, Q)
        return Q
