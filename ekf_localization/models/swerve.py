"""Swerve-drive kinematics: N steered modules at (xᵢ, yᵢ) on a holonomic body (no ROS imports).

A module's wheel points along its steer angle φᵢ and rolls at speed sᵢ (m/s along the wheel), so
its contact point moves with the velocity vector uᵢ = sᵢ (cos φᵢ, sin φᵢ). A rigid body with the
twist v = [vx vy ω] moves the point (xᵢ, yᵢ) with

    uᵢ = A_i v,   A_i = [[1, 0, −yᵢ], [0, 1, xᵢ]]        (module velocity: vx − ω yᵢ, vy + ω xᵢ)

and the 2N rows A = [A_1; ...; A_N] are the measurement the ``joint`` input fuses on the state's
body twist (docs/models.md, "Swerve modules"). A module turned by π with its speed negated
moves its contact point alike: (sᵢ, φᵢ) and (−sᵢ, φᵢ + π) are the same state.

The speed is measured along the wheel with variance σ_s², the angle with variance σ_φ², so the
vector's covariance is R_i = Rot(φᵢ) diag(σ_s², sᵢ² σ_φ² + b) Rot(φᵢ)ᵀ (b: a floor, so a standing
module's across-wheel component is not certain). The weighted least-squares twist of all
modules, v̂ = (Aᵀ R⁻¹ A)⁻¹ Aᵀ R⁻¹ u with covariance (Aᵀ R⁻¹ A)⁻¹ (:func:`wls_twist`), is what fusing
the 2N rows gives in information form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.angles import wrap_angles


def layout_problem(positions) -> str | None:
    """Why ``positions`` (N, 2) cannot hold a swerve's body twist, or None: at least two modules,
    not all at one point (then A has rank 3)."""
    p = np.asarray(positions, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or not np.all(np.isfinite(p)):
        return "finite [x, y] pairs, one per module"
    if p.shape[0] < 2:
        return f"at least two modules (got {p.shape[0]}): one module cannot tell a turn from a translation"
    if np.max(np.ptp(p, axis=0)) <= 1e-6:
        return "modules at two or more distinct points (at one point a turn looks like a translation)"
    return None


@dataclass(frozen=True, eq=False)
class SwerveKinematics:
    """Module positions (N, 2) in the body frame, m."""

    positions: np.ndarray

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SwerveKinematics) and np.array_equal(self.positions, other.positions)

    def __hash__(self) -> int:
        return hash(self.positions.tobytes())

    def __post_init__(self) -> None:
        p = np.array(self.positions, dtype=float)
        if p.ndim == 1 and p.size % 2 == 0:  # a flat [x0, y0, x1, y1, ...] list
            p = p.reshape(-1, 2)
        problem = layout_problem(p)
        if problem is not None:
            raise ValueError(f"swerve module positions: {problem}, got {self.positions!r}")
        p.setflags(write=False)
        object.__setattr__(self, "positions", p)

    @property
    def n_modules(self) -> int:
        return int(self.positions.shape[0])

    @property
    def module_rows(self) -> np.ndarray:
        """(2N, 3) A: body twist [vx vy ω] -> module velocity vectors [u_1x u_1y u_2x ...]."""
        A = np.zeros((2 * self.n_modules, 3))
        A[0::2, 0] = 1.0
        A[1::2, 1] = 1.0
        A[0::2, 2] = -self.positions[:, 1]
        A[1::2, 2] = self.positions[:, 0]
        return A

    def twist_to_vectors(self, twist) -> np.ndarray:
        """(..., 3) twist -> (..., N, 2) module velocity vectors."""
        u = np.asarray(twist, dtype=float) @ self.module_rows.T
        return u.reshape(*u.shape[:-1], self.n_modules, 2)

    def twist_to_modules(self, twist, current_angles=None) -> tuple[np.ndarray, np.ndarray]:
        """(..., 3) twist -> (speeds, angles), each (..., N). With ``current_angles`` each module takes
        the one of (s, φ) and (−s, φ + π) nearer its current angle (it turns at most π/2); a standing
        module keeps its angle."""
        u = self.twist_to_vectors(twist)
        speeds = np.hypot(u[..., 0], u[..., 1])
        angles = np.arctan2(u[..., 1], u[..., 0])
        if current_angles is None:
            return speeds, angles
        cur = np.broadcast_to(np.asarray(current_angles, dtype=float), angles.shape)
        angles = np.where(speeds > 0.0, angles, cur)
        flip = np.abs(wrap_angles(angles - cur)) > 0.5 * math.pi
        return np.where(flip, -speeds, speeds), wrap_angles(np.where(flip, angles + math.pi, angles))


def module_vectors(speeds, angles) -> np.ndarray:
    """(..., N) speeds along the wheel and steer angles -> (..., 2N) [s cos φ, s sin φ] per module."""
    s = np.asarray(speeds, dtype=float)
    a = np.asarray(angles, dtype=float)
    u = np.stack([s * np.cos(a), s * np.sin(a)], axis=-1)
    return u.reshape(*u.shape[:-2], -1)


def module_covariance(angles, along_variance, across_variance) -> np.ndarray:
    """(2N, 2N) block diagonal: per module Rot(φ) diag(along, across) Rot(φ)ᵀ."""
    a = np.asarray(angles, dtype=float)
    c, s = np.cos(a), np.sin(a)
    va = np.asarray(along_variance, dtype=float) * np.ones_like(a)
    vc = np.asarray(across_variance, dtype=float) * np.ones_like(a)
    n = a.size
    R = np.zeros((2 * n, 2 * n))
    i = np.arange(n)
    R[2 * i, 2 * i] = c * c * va + s * s * vc
    R[2 * i + 1, 2 * i + 1] = s * s * va + c * c * vc
    R[2 * i, 2 * i + 1] = R[2 * i + 1, 2 * i] = c * s * (va - vc)
    return R


def wls_twist(A: np.ndarray, u: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The weighted least-squares body twist of the module vectors u (2N,) with covariance R:
    (v̂, C) with C = (Aᵀ R⁻¹ A)⁻¹ and v̂ = C Aᵀ R⁻¹ u."""
    W = np.linalg.solve(R, A)  # R⁻¹ A
    info = A.T @ W
    C = np.linalg.inv(info)
    return C @ (W.T @ u), 0.5 * (C + C.T)
