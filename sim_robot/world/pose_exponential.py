"""Constant-curvature (pose exponential) integration of a body twist, with its Jacobians.

This is how FTC dead-wheel localizers integrate encoder deltas: over an interval T
the robot is assumed to move with a constant body twist ``ξ = [vx vy wz]``, i.e. along a
circular arc. With ``a = vx·T``, ``b = vy·T``, ``φ = wz·T``, ``A = sin φ / φ`` and
``B = (1 − cos φ) / φ`` the body-frame increment is

    δ = [A·a − B·b,  B·a + A·b,  φ]

and the new field pose is ``[x, y] + R(θ)·δ[:2]``, ``θ + φ``. Near φ = 0 the series of
A, B and their derivatives are used (no 0/0).

Covariance: ``P' = J_p P J_pᵀ + J_ξ Σ_ξ J_ξᵀ`` with the exact Jacobians of the step
with respect to the previous pose (J_p) and to the twist (J_ξ), treating the twist
noise of successive intervals as independent.
"""

from __future__ import annotations

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.linalg import symmetrise

_SERIES_LIMIT = 1e-2  # |φ| below which A, B, A', B' come from their Taylor series


def _curvature_terms(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A, B and their derivatives dA/dφ, dB/dφ, elementwise."""
    small = np.abs(phi) < _SERIES_LIMIT
    p = np.where(small, 1.0, phi)  # safe divisor where the series is used
    s, c = np.sin(p), np.cos(p)
    A = s / p
    B = (1.0 - c) / p
    dA = (p * c - s) / (p * p)
    dB = (p * s - (1.0 - c)) / (p * p)
    q = phi * phi
    A_s = 1.0 - q / 6.0 + q * q / 120.0 - q * q * q / 5040.0
    B_s = phi * (0.5 - q / 24.0 + q * q / 720.0)
    dA_s = phi * (-1.0 / 3.0 + q / 30.0 - q * q / 840.0)
    dB_s = 0.5 - q / 8.0 + q * q / 144.0 - q * q * q / 5760.0
    return (np.where(small, A_s, A), np.where(small, B_s, B),
            np.where(small, dA_s, dA), np.where(small, dB_s, dB))


def _increment_and_jacobian(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b, phi = xi[..., 0], xi[..., 1], xi[..., 2]
    A, B, dA, dB = _curvature_terms(phi)
    d = np.stack([A * a - B * b, B * a + A * b, phi], axis=-1)
    J = np.zeros(xi.shape[:-1] + (3, 3))
    J[..., 0, 0] = A
    J[..., 0, 1] = -B
    J[..., 0, 2] = dA * a - dB * b
    J[..., 1, 0] = B
    J[..., 1, 1] = A
    J[..., 1, 2] = dB * a + dA * b
    J[..., 2, 2] = 1.0
    return d, J


def body_increment(xi: np.ndarray) -> np.ndarray:
    """(N, 3) twist·T = [a b φ] -> (N, 3) body-frame pose increment δ."""
    return _increment_and_jacobian(np.asarray(xi, dtype=float))[0]


def body_increment_jacobian(xi: np.ndarray) -> np.ndarray:
    """(N, 3, 3) ∂δ/∂[a b φ]."""
    return _increment_and_jacobian(np.asarray(xi, dtype=float))[1]


def integrate(pose: np.ndarray, twist: np.ndarray, dt_s: float) -> np.ndarray:
    """Pose after moving for ``dt_s`` seconds with a constant body twist; θ wrapped."""
    pose = np.asarray(pose, dtype=float)
    d = body_increment(np.asarray(twist, dtype=float) * dt_s)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    return np.stack([pose[..., 0] + c * d[..., 0] - s * d[..., 1],
                     pose[..., 1] + s * d[..., 0] + c * d[..., 1],
                     wrap_angles(pose[..., 2] + d[..., 2])], axis=-1)


def integrate_with_covariance(pose: np.ndarray, pose_cov: np.ndarray, twist: np.ndarray,
                              twist_cov: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``integrate`` plus the first-order covariance of the new pose (module docstring)."""
    pose = np.asarray(pose, dtype=float)
    twist = np.asarray(twist, dtype=float)
    d, J_body = _increment_and_jacobian(twist * dt_s)
    th = pose[..., 2]
    c, s = np.cos(th), np.sin(th)
    dx = c * d[..., 0] - s * d[..., 1]
    dy = s * d[..., 0] + c * d[..., 1]
    new_pose = np.stack([pose[..., 0] + dx, pose[..., 1] + dy, wrap_angles(th + d[..., 2])], axis=-1)
    N = pose.shape[:-1]
    Jp = np.broadcast_to(np.eye(3), N + (3, 3)).copy()
    Jp[..., 0, 2] = -dy
    Jp[..., 1, 2] = dx
    R = np.zeros(N + (3, 3))
    R[..., 0, 0] = c
    R[..., 0, 1] = -s
    R[..., 1, 0] = s
    R[..., 1, 1] = c
    R[..., 2, 2] = 1.0
    Jxi = R @ J_body * dt_s
    P = Jp @ pose_cov @ np.swapaxes(Jp, -1, -2) + Jxi @ twist_cov @ np.swapaxes(Jxi, -1, -2)
    return new_pose, symmetrise(P)
