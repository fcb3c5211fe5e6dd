"""N independent extended Kalman filters stepped together, for the seed papers' Monte-Carlo tables.

The equations are :class:`~ekf_localization.core.ekf.ExtendedKalmanFilter`'s (seed 000
section III, eq. 7-12) on stacks over trials: states (N, n), covariances (N, n, n), one status
per trial. A process model works on such stacks already (``f(X, U, dt)`` -> (N, n),
``jacobian`` -> (1|N, n, n), ``noise`` -> (1|N, n, n) or (n, n), optional ``f_and_jacobian``
and ``control_dim``); so does a measurement model (``h(X)`` -> (N, m), ``jacobian(X)`` ->
(1|N, m, n)).

After every step P is symmetrised and, where a rounding error left it indefinite, its diagonal
is lifted by ``min_variance`` (tenfold per try). A trial with non-finite or inconsistent input
is refused with a status and keeps its state; the other trials go on.
``test/test_batched_ekf.py`` checks the results against N single filters.
"""

from __future__ import annotations

import math

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.ekf import (
    STATUS_BAD_R,
    STATUS_GATED,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_P_NOT_PD,
    STATUS_S_NOT_PD,
    STATUS_SKIPPED,
    MeasurementModel,
    ProcessModel,
    dt_seconds,
    gate_squared,
)
from ekf_localization.core.linalg import SYMMETRY_ATOL, SYMMETRY_RTOL, is_positive_definite, is_symmetric

_MAX_LIFTS = 40  # diagonal lifts of min_variance · 10^k tried before P counts as unusable


def _transpose(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(A, -1, -2)


def _as_spd(P: np.ndarray, name: str) -> np.ndarray:
    """P (..., n, n) checked finite, symmetric and positive definite; returned symmetrised."""
    P = np.array(P, dtype=float)
    if not np.all(np.isfinite(P)):
        raise ValueError(f"{name} must be finite")
    if not is_symmetric(P):
        raise ValueError(f"{name} must be symmetric")
    if not is_positive_definite(P):
        raise ValueError(f"{name} must be positive definite")
    return 0.5 * (P + _transpose(P))


def _is_pd(A: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        return False
    return True


def _pd_rows(A: np.ndarray) -> np.ndarray:
    """(N,) bool: which symmetric matrices of the finite stack A (N, k, k) are positive definite."""
    if _is_pd(A):
        return np.ones(A.shape[0], dtype=bool)
    return np.array([_is_pd(a) for a in A], dtype=bool)


def make_spd(A: np.ndarray, min_variance: float) -> np.ndarray:
    """Symmetrise every matrix of the stack A (N, n, n) in place and lift the diagonal of any
    that is not positive definite (min_variance, then tenfold per try) until it is.

    Returns (N,) bool: False where a matrix is not finite or no lift made it PD."""
    A[:] = 0.5 * (A + _transpose(A))  # exactly symmetric: a + b == b + a
    ok = np.isfinite(A).all(axis=(1, 2))
    if ok.all() and _is_pd(A):
        return ok
    diagonal = np.eye(A.shape[1], dtype=bool)
    for b in np.flatnonzero(ok):
        lift = min_variance
        for _ in range(_MAX_LIFTS + 1):
            if _is_pd(A[b]):
                break
            A[b][diagonal] += lift
            lift *= 10.0
        else:
            ok[b] = False
    return ok


def _nearly_symmetric(R: np.ndarray) -> np.ndarray:
    """(N,) bool: every R[b] equals its transpose within core.linalg's tolerance."""
    RT = _transpose(R)
    return (np.abs(R - RT) <= SYMMETRY_ATOL + SYMMETRY_RTOL * np.abs(RT)).all(axis=(1, 2))


class BatchedEKF:
    """N independent EKFs sharing one process model, stepped together."""

    def __init__(self, model: ProcessModel, X0: np.ndarray, P0: np.ndarray,
                 min_variance: float = 1e-12) -> None:
        n = int(model.n)
        X0 = np.array(X0, dtype=float)
        if X0.ndim != 2 or X0.shape[1] != n:
            raise ValueError(f"initial state must be shaped (N, {n}), got {X0.shape}")
        if not np.all(np.isfinite(X0)):
            raise ValueError("initial state must be finite")
        N = X0.shape[0]
        P0 = np.array(P0, dtype=float)
        if P0.shape == (n, n):
            P0 = np.broadcast_to(P0, (N, n, n))
        if P0.shape != (N, n, n):
            raise ValueError(f"initial covariance must be shaped ({n}, {n}) or ({N}, {n}, {n}), "
                             f"got {P0.shape}")
        min_variance = float(min_variance)
        if not (min_variance > 0.0 and math.isfinite(min_variance)):
            raise ValueError(f"min_variance must be finite and > 0, got {min_variance!r}")
        x_is_angle = np.asarray(model.x_is_angle, dtype=bool)
        if x_is_angle.shape != (n,):
            raise ValueError(f"model.x_is_angle must have {n} entries, got shape {x_is_angle.shape}")
        k = getattr(model, "control_dim", None)
        self.model = model
        self._n = n
        self._min_variance = min_variance
        self._x_is_angle = x_is_angle
        self._angles = bool(x_is_angle.any())
        self._control_dim = None if k is None else int(k)
        self._X = self._wrapped(X0)
        self._P = _as_spd(P0, "initial covariance")
        self._eye = np.eye(n)

    @property
    def N(self) -> int:  # noqa: N802 - the usual symbol
        return self._X.shape[0]

    @property
    def X(self) -> np.ndarray:  # noqa: N802 - the usual symbol
        """States (N, n), the filter's own array: copy it before keeping it."""
        return self._X

    @property
    def P(self) -> np.ndarray:  # noqa: N802 - the usual symbol
        """Covariances (N, n, n), the filter's own array: copy it before keeping it."""
        return self._P

    @property
    def min_variance(self) -> float:
        """Smallest diagonal lift used to keep P positive definite (fixed at construction)."""
        return self._min_variance

    def set_state(self, X: np.ndarray, P: np.ndarray) -> None:
        """Replace every trial's state (N, n) and covariance ((n, n) or (N, n, n))."""
        X = np.asarray(X, dtype=float)
        if X.shape != self._X.shape or not np.all(np.isfinite(X)):
            raise ValueError(f"states must be {self._X.shape} finite values")
        P = np.asarray(P, dtype=float)
        if P.shape == self._P.shape[1:]:
            P = np.broadcast_to(P, self._P.shape)
        if P.shape != self._P.shape:
            raise ValueError(f"covariances must be shaped {self._P.shape[1:]} or {self._P.shape}")
        self._X[:] = self._wrapped(X)
        self._P[:] = _as_spd(P, "P")

    def predict(self, dt_ns: int, U: np.ndarray | None = None, steps: int = 1) -> np.ndarray:
        """Propagate every trial ``steps`` times by dt_ns nanoseconds with controls U (N, k) or None.

        Returns (N,) bool: False for a trial with a prediction that was not finite (that step
        kept it as it was)."""
        dt = dt_seconds(dt_ns)
        if U is not None:
            U = self._check_control(U)
        if type(steps) is not int or steps < 1:
            raise ValueError(f"steps must be an int >= 1, got {steps!r}")
        ok = np.ones(self.N, dtype=bool)
        if dt > 0.0:
            for _ in range(steps):
                ok &= self._predict(dt, U)
        return ok

    def update(self, model: MeasurementModel, Z: np.ndarray, R: np.ndarray,
               mask: np.ndarray | None = None,
               gate_sigmas: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """Fuse one measurement per trial. Returns (status (N,), squared Mahalanobis (N,)).

        R is (m, m) shared or (N, m, m); mask is (m,) shared or (N, m), True = fuse."""
        m, N = int(model.m), self.N
        Z = np.asarray(Z, dtype=float)
        if Z.shape != (N, m):
            raise ValueError(f"Z must be shaped ({N}, {m}), got {Z.shape}")
        R = np.asarray(R, dtype=float)
        if R.ndim == 2:
            R = R[None]
        if R.ndim != 3 or R.shape[1:] != (m, m) or R.shape[0] not in (1, N):
            raise ValueError(f"R must be shaped ({m}, {m}) or ({N}, {m}, {m}), got {R.shape}")
        return self._update(model, Z, np.broadcast_to(R, (N, m, m)), self._mask(mask, m),
                            gate_squared(gate_sigmas))

    def _wrapped(self, X: np.ndarray) -> np.ndarray:
        if self._angles:
            X = X.copy()
            X[:, self._x_is_angle] = wrap_angles(X[:, self._x_is_angle])
        return X

    def _check_control(self, U: np.ndarray) -> np.ndarray:
        U = np.asarray(U, dtype=float)
        k = self._control_dim
        if U.ndim != 2 or U.shape[0] != self._X.shape[0] or (k is not None and U.shape[1] != k):
            raise ValueError(f"control must be shaped ({self._X.shape[0]}, {k}), got {U.shape}")
        return U

    def _mask(self, mask: np.ndarray | None, m: int) -> np.ndarray | None:
        if mask is None:
            return None
        mask = np.asarray(mask, dtype=bool)
        if mask.ndim == 1:
            mask = mask[None]
        N = self._X.shape[0]
        if mask.ndim != 2 or mask.shape[1] != m or mask.shape[0] not in (1, N):
            raise ValueError(f"mask must be shaped ({m},) or ({N}, {m}), got {mask.shape}")
        return None if mask.all() else mask

    def _predict(self, dt: float, U: np.ndarray | None) -> np.ndarray:
        """One step of eq. 8-9 for every trial (dt > 0 seconds). Returns (N,) bool: False for a
        trial whose prediction is not finite (kept as it was)."""
        X, P, model = self._X, self._P, self.model
        both = getattr(model, "f_and_jacobian", None)
        Xn, F = both(X, U, dt) if both is not None else (model.f(X, U, dt), model.jacobian(X, U, dt))
        Q = np.asarray(model.noise(X, U, dt), dtype=float)
        n = self._n
        if Xn.shape != X.shape or F.shape[1:] != (n, n) or Q.shape[-2:] != (n, n):
            raise ValueError(f"process model returned f {Xn.shape}, F {F.shape}, Q {Q.shape} for X {X.shape}")
        Pn = F @ P @ _transpose(F) + Q  # eq. 9 (make_spd symmetrises Q's part too)
        ok = np.isfinite(Xn).all(axis=1) & make_spd(Pn, self._min_variance)
        if ok.all():
            X[:] = self._wrapped(Xn)
            P[:] = Pn
        else:
            X[ok] = self._wrapped(Xn[ok])
            P[ok] = Pn[ok]
        return ok

    def _update(self, model: MeasurementModel, Z: np.ndarray, R: np.ndarray, mask: np.ndarray | None,
                gate_sq: float) -> tuple[np.ndarray, np.ndarray]:
        """Eq. 10-12 for every trial, in place. Returns (status (N,), squared Mahalanobis (N,)).

        A component left out by ``mask`` (N|1, m) is neutralised: its row of H, its residual
        and its covariances with the others are 0, its variance 1. That is exactly the update
        with the reduced measurement."""
        X, P = self._X, self._P
        N, m = X.shape[0], int(model.m)
        with np.errstate(all="ignore"):  # a singular h gives nan: refused below
            Zhat = np.asarray(model.h(X), dtype=float)
            H = np.broadcast_to(np.asarray(model.jacobian(X), dtype=float), (N, m, self._n))
        if Zhat.shape != (N, m):
            raise ValueError(f"h(X) must be shaped ({N}, {m}), got {Zhat.shape}")
        y = Z - Zhat  # eq. 10's residual, angles wrapped
        z_is_angle = np.asarray(model.z_is_angle, dtype=bool)
        if z_is_angle.any():
            y[:, z_is_angle] = wrap_angles(y[:, z_is_angle])
        status = np.full(N, STATUS_OK)
        if mask is not None:
            mask = np.broadcast_to(mask, (N, m))
            status[~mask.any(axis=1)] = STATUS_SKIPPED
            pair = mask[:, :, None] & mask[:, None, :]
            H = np.where(mask[:, :, None], H, 0.0)
            y = np.where(mask, y, 0.0)
            R = np.where(pair, R, 0.0) + np.where(mask, 0.0, 1.0)[:, :, None] * np.eye(m)
        finite = (np.isfinite(y).all(axis=1) & np.isfinite(H).all(axis=(1, 2))
                  & np.isfinite(R).all(axis=(1, 2)))
        status[(status == STATUS_OK) & ~finite] = STATUS_NONFINITE
        # R must be symmetric positive semi-definite: a tiny jitter lets a PSD R pass Cholesky
        diag = np.diagonal(R, axis1=1, axis2=2)
        bad_r = ~_nearly_symmetric(R) | (diag < 0.0).any(axis=1)
        check = (status == STATUS_OK) & ~bad_r
        if check.any() and np.count_nonzero(R[check] * (1.0 - np.eye(m))):
            Rj = 0.5 * (R[check] + _transpose(R[check]))
            Rj += (1e-12 * diag[check].max(axis=1) + 1e-300)[:, None, None] * np.eye(m)
            bad_r[np.flatnonzero(check)] = ~_pd_rows(Rj)
        status[(status == STATUS_OK) & bad_r] = STATUS_BAD_R
        d2 = np.full(N, math.nan)
        live = np.flatnonzero(status == STATUS_OK)
        if live.size == 0:
            return status, d2
        every = live.size == N
        x, Pl, Hl, yl = (X, P, H, y) if every else (X[live], P[live], H[live], y[live])
        Rl = 0.5 * (R + _transpose(R))
        if not every and Rl.shape[0] == N:
            Rl = Rl[live]
        HP = Hl @ Pl
        S = HP @ _transpose(Hl) + Rl  # eq. 10's innovation covariance
        s_pd = _pd_rows(S)
        if not s_pd.all():
            status[live[~s_pd]] = STATUS_S_NOT_PD
            S[~s_pd] = np.eye(m)  # kept out of the solves below, which need a regular S
        Kt = np.linalg.solve(S, np.concatenate([HP, yl[:, :, None]], axis=2))  # S⁻¹ [H P | y]
        Kt, Sy = Kt[:, :, :-1], Kt[:, :, -1]
        d2l = np.einsum("bi,bi->b", yl, Sy)
        d2[live] = np.where(s_pd, d2l, math.nan)
        gated = s_pd & ~(d2l <= gate_sq)
        status[live[gated]] = STATUS_GATED
        K = _transpose(Kt)  # eq. 10: K = P Hᵀ S⁻¹
        A = self._eye - K @ Hl
        Pn = A @ Pl @ _transpose(A) + K @ Rl @ Kt  # eq. 12, Joseph form
        xn = x + np.einsum("bij,bj->bi", K, yl)  # eq. 11
        go = s_pd & ~gated
        finite = np.isfinite(xn).all(axis=1) & np.isfinite(Pn).all(axis=(1, 2))
        status[live[go & ~finite]] = STATUS_NONFINITE
        go &= finite
        spd = np.zeros_like(go)
        if go.any():
            Pgo = Pn[go]
            spd[go] = make_spd(Pgo, self._min_variance)
            Pn[go] = Pgo
        status[live[go & ~spd]] = STATUS_P_NOT_PD
        go &= spd
        if go.all() and every:
            X[:] = self._wrapped(xn)
            P[:] = Pn
        elif go.any():
            X[live[go]] = self._wrapped(xn[go])
            P[live[go]] = Pn[go]
        return status, d2
