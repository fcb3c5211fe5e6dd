"""Symmetric positive definite matrices: one symmetry tolerance, one PD test, one symmetrise.

``nearly_symmetric_pair`` is plain Python arithmetic, so the compiled kernels use the same
function (:mod:`ekf_localization.core.kernels` compiles it) and the same tolerance.
"""

from __future__ import annotations

import numpy as np

SYMMETRY_RTOL = 1e-9
SYMMETRY_ATOL = 1e-12


def nearly_symmetric_pair(a: float, b: float) -> bool:
    """True when the mirrored entries a = M[i, j] and b = M[j, i] agree within the tolerance."""
    return abs(a - b) <= SYMMETRY_ATOL + SYMMETRY_RTOL * abs(b)


def is_symmetric(M: np.ndarray) -> bool:
    """True when every (..., n, n) matrix of M equals its transpose within the tolerance."""
    M = np.asarray(M, dtype=float)
    return bool(np.allclose(M, np.swapaxes(M, -1, -2), rtol=SYMMETRY_RTOL, atol=SYMMETRY_ATOL))


def symmetrise(M: np.ndarray) -> np.ndarray:
    """(M + Mᵀ) / 2 of every (..., n, n) matrix of M."""
    M = np.asarray(M, dtype=float)
    return 0.5 * (M + np.swapaxes(M, -1, -2))


def is_positive_definite(M: np.ndarray) -> bool:
    """True when every (..., n, n) matrix of M is finite and positive definite (Cholesky of
    its lower triangle succeeds; symmetry is :func:`is_symmetric`'s job)."""
    M = np.asarray(M, dtype=float)
    if M.ndim < 2 or M.shape[-1] != M.shape[-2]:
        raise ValueError(f"expected square matrices, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        return False
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return False
    return True

