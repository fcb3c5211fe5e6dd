"""Symmetric positive definite matrices: one symmetry tolerance, one PD test, one symmetrise."""

from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dpotrf

SYMMETRY_RTOL = 1e-9
SYMMETRY_ATOL = 1e-12
SMALL = 8  # is_symmetric compares a matrix up to this size entry by entry in Python


def is_symmetric(M: np.ndarray) -> bool:
    """True when every (..., n, n) matrix of M equals its transpose within the tolerance:
    |M_ij - M_ji| <= SYMMETRY_ATOL + SYMMETRY_RTOL·|M_ji| for every entry."""
    M = np.asarray(M, dtype=float)
    if M.ndim == 2 and M.shape[0] == M.shape[1] <= SMALL:  # Python floats: cheaper than numpy's calls
        return rows_symmetric(M.tolist())
    MT = np.swapaxes(M, -1, -2)
    if (M == MT).all():  # the usual case: exactly symmetric
        return True
    return bool((np.abs(M - MT) <= SYMMETRY_ATOL + SYMMETRY_RTOL * np.abs(MT)).all())


def rows_symmetric(rows: list[list[float]]) -> bool:
    """:func:`is_symmetric` of a small square matrix given as its rows of Python floats."""
    for i, row in enumerate(rows):
        for j in range(i):
            a, b = row[j], rows[j][i]
            if a != b and not (abs(a - b) <= SYMMETRY_ATOL + SYMMETRY_RTOL * abs(b)
                               and abs(b - a) <= SYMMETRY_ATOL + SYMMETRY_RTOL * abs(a)):
                return False
    return True


def rows_positive_definite(A: np.ndarray, rows: list[list[float]]) -> bool:
    """:func:`has_cholesky` of the finite symmetric A, whose rows of Python floats are ``rows``: a
    diagonal A (the usual covariance) is positive definite exactly when its diagonal is > 0
    (the factorisation's pivots are then its square roots), read without LAPACK."""
    if all(v == 0.0 for i, row in enumerate(rows) for j, v in enumerate(row) if i != j):
        return all(row[i] > 0.0 for i, row in enumerate(rows))
    return has_cholesky(A)


def symmetrise(M: np.ndarray) -> np.ndarray:
    """(M + Mᵀ) / 2 of every (..., n, n) matrix of M."""
    M = np.asarray(M, dtype=float)
    return 0.5 * (M + np.swapaxes(M, -1, -2))


def has_cholesky(A: np.ndarray) -> bool:
    """True when the finite symmetric (n, n) matrix A has a Cholesky factor, i.e. is positive
    definite (LAPACK's potrf, lower and not cleaned: options by position, which f2py parses
    faster than keywords; it passes nan and inf through: check finiteness first)."""
    return dpotrf(A, 1, 0)[1] == 0


def is_positive_definite(M: np.ndarray) -> bool:
    """True when every (..., n, n) matrix of M is finite and positive definite (Cholesky of
    its lower triangle succeeds; symmetry is :func:`is_symmetric`'s job)."""
    M = np.asarray(M, dtype=float)
    if M.ndim < 2 or M.shape[-1] != M.shape[-2]:
        raise ValueError(f"expected square matrices, got shape {M.shape}")
    if not np.isfinite(M).all():
        return False
    if M.ndim == 2:
        return has_cholesky(M)
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return False
    return True

