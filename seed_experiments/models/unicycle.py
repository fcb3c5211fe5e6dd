"""Unicycle with wheel angles (seed 002): dead reckoning, linear KF with a fixed heading, EKF.

State ``[φ x y θ_L θ_R]`` (heading rad CCW, position m, cumulative wheel angles rad),
control ``u = [u_L u_R]`` wheel speeds (rad/s). Seed 002 eq. 3, as corrected in the seeds
README (the printed matrix has four rows for five states)::

    φ̇ = r/(2d)·(u_R − u_L)    ẋ = r/2·(u_L + u_R)·cos φ    ẏ = r/2·(u_L + u_R)·sin φ
    θ̇_L = u_L                 θ̇_R = u_R

r is the wheel radius and d half the distance between the wheels. Discretised with
Euler's rule x' = x + f(x, u)·Δt (eq. 1): the same step is dead reckoning (no updates),
and with its Jacobian (eq. 11) the EKF prediction.

The linear KF of seed 002 (eq. 6-10) drops φ from the state and fixes it, which makes
the model linear; the seed's "φ = 1/4" is π/4 (see the seeds README).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ekf_localization.core.linear import (
    LinearMeasurement,
    LinearProcessModel,
    nonnegative_variances,
    select_rows,
)

N_STATE = 5
PHI, POS_X, POS_Y, THETA_L, THETA_R = range(N_STATE)


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a positive length in metres, got {value!r}")
    return value


@dataclass
class UnicycleModel:
    """Euler-discretised unicycle of eq. 1-3; Q = diag(state_variance_rate)·Δt.

    state_variance_rate (5,) is in rad²/s, m²/s, m²/s, rad²/s, rad²/s. With U = None the
    wheels are taken as stopped.
    """

    wheel_radius: float
    half_axle: float  # d: half the distance between the wheels
    state_variance_rate: np.ndarray = field(default_factory=lambda: np.full(N_STATE, 1e-3))
    n: int = N_STATE
    x_is_angle: np.ndarray = field(default_factory=lambda: np.array([1, 0, 0, 0, 0], dtype=np.bool_))
    control_dim: int = 2

    def __post_init__(self) -> None:
        self.wheel_radius = _positive("wheel_radius", self.wheel_radius)
        self.half_axle = _positive("half_axle", self.half_axle)
        self.state_variance_rate = nonnegative_variances("state_variance_rate", self.state_variance_rate,
                                                         N_STATE)
        self._q_cache: tuple[float, np.ndarray] | None = None

    def _wheels(self, U: np.ndarray | None, N: int) -> tuple[np.ndarray, np.ndarray]:
        if U is None:
            return np.zeros(N), np.zeros(N)
        U = np.asarray(U, dtype=float)
        if U.shape != (N, 2):
            raise ValueError(f"control must be shaped ({N}, 2) wheel speeds [u_L, u_R], got {U.shape}")
        return U[:, 0], U[:, 1]

    def rates(self, X: np.ndarray, U: np.ndarray | None) -> np.ndarray:
        """ẋ = f(x, u) of eq. 3 (corrected), batched: (N, 5)."""
        X = np.asarray(X, dtype=float)
        uL, uR = self._wheels(U, X.shape[0])
        r, d = self.wheel_radius, self.half_axle
        speed = 0.5 * r * (uL + uR)
        return np.stack([r / (2.0 * d) * (uR - uL), speed * np.cos(X[:, PHI]), speed * np.sin(X[:, PHI]),
                         uL, uR], axis=1)

    def f(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        """Euler step, eq. 1: x + f(x, u)·Δt."""
        return np.asarray(X, dtype=float) + dt * self.rates(X, U)

    def jacobian(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        """∂(x + f Δt)/∂x = I + Δt ∂f/∂x (used in eq. 11): only the φ column is not trivial."""
        X = np.asarray(X, dtype=float)
        uL, uR = self._wheels(U, X.shape[0])
        speed = 0.5 * self.wheel_radius * (uL + uR)
        F = np.broadcast_to(np.eye(N_STATE), (X.shape[0], N_STATE, N_STATE)).copy()
        F[:, POS_X, PHI] = -dt * speed * np.sin(X[:, PHI])
        F[:, POS_Y, PHI] = dt * speed * np.cos(X[:, PHI])
        return F

    def noise(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        c = self._q_cache
        if c is not None and c[0] == dt:
            return c[1]
        Q = np.diag(self.state_variance_rate * dt)[None]
        self._q_cache = (dt, Q)
        return Q


def fixed_heading_model(wheel_radius: float, heading: float = math.pi / 4,
                        state_variance_rate: float | np.ndarray = 1e-3) -> LinearProcessModel:
    """Seed 002's linear KF model (eq. 6-8): state [x y θ_L θ_R], A = I, φ fixed (default π/4).

    B = [[r/2 cos φ, r/2 cos φ], [r/2 sin φ, r/2 sin φ], [1, 0], [0, 1]] (per second, times Δt).
    """
    r = _positive("wheel_radius", wheel_radius)
    if not math.isfinite(heading):
        raise ValueError(f"heading must be finite (rad), got {heading!r}")
    c, s = math.cos(heading), math.sin(heading)
    B = np.array([[0.5 * r * c, 0.5 * r * c], [0.5 * r * s, 0.5 * r * s], [1.0, 0.0], [0.0, 1.0]])
    return LinearProcessModel(B, variance_rate=state_variance_rate)


def position_measurement() -> LinearMeasurement:
    """[x, y] of the unicycle state (eq. 10 on the full state)."""
    return select_rows(N_STATE, [POS_X, POS_Y])


def pose_measurement() -> LinearMeasurement:
    """[φ, x, y] (the TurtleBot odom pose of seed 002 sec. I C, eq. 12), φ residual wrapped."""
    return select_rows(N_STATE, [PHI, POS_X, POS_Y], angle_rows=(PHI,))


def fixed_heading_position_measurement() -> LinearMeasurement:
    """y = C x with C = [[1, 0, 0, 0], [0, 1, 0, 0]] on the fixed-heading state (eq. 10)."""
    return select_rows(4, [0, 1])
