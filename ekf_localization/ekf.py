"""Generic extended Kalman filter: one trial or N independent trials at once.

Time enters as integer nanoseconds (ROS stamps) and becomes seconds only inside the
step. Residual angles are wrapped to (-pi, pi], the covariance update is Joseph form,
P stays symmetric positive definite, and non-finite inputs are rejected with a reason.

Process and measurement models work on batches, states shaped (N, n):

* process model: ``n``, ``x_is_angle`` (n,), ``f(X, U, dt)`` -> (N, n),
  optionally ``f_and_jacobian(X, U, dt)`` -> both at once (faster),
  ``jacobian(X, U, dt)`` -> (N, n, n), ``noise(X, U, dt)`` -> (N, n, n), (1, n, n) or (n, n).
* measurement model: ``m``, ``z_is_angle`` (m,), ``h(X)`` -> (N, m),
  ``jacobian(X)`` -> (N, m, n) or (1, m, n) when it is the same for every trial;
  ``linear = True`` declares h(X) = H X (the kernel then evaluates it itself).
"""

from __future__ import annotations

import math
from typing import NamedTuple, Protocol

import numpy as np

from ekf_localization import kernels
from ekf_localization.kernels import STATUS_OK, STATUS_TEXT

NS_PER_S = 1_000_000_000
_NO_ZHAT = np.empty((0, 0))


class ProcessModel(Protocol):
    n: int
    x_is_angle: np.ndarray

    def f(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray: ...

    def jacobian(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray: ...

    def noise(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray: ...


class MeasurementModel(Protocol):
    m: int
    z_is_angle: np.ndarray

    def h(self, X: np.ndarray) -> np.ndarray: ...

    def jacobian(self, X: np.ndarray) -> np.ndarray: ...


class UpdateResult(NamedTuple):
    """Outcome of one single-trial update."""

    status: int
    mahalanobis: float  # sqrt of the squared Mahalanobis distance of the innovation (nan if not reached)

    @property
    def accepted(self) -> bool:
        return self.status == STATUS_OK

    @property
    def reason(self) -> str:
        return STATUS_TEXT[self.status]


def _as_spd(P: np.ndarray, name: str) -> np.ndarray:
    P = np.array(P, dtype=float)
    if not np.all(np.isfinite(P)):
        raise ValueError(f"{name} must be finite")
    if not np.allclose(P, np.swapaxes(P, -1, -2), rtol=1e-9, atol=1e-12):
        raise ValueError(f"{name} must be symmetric")
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError as exc:
        raise ValueError(f"{name} must be positive definite") from exc
    return P


def _c3(a: np.ndarray, ndim: int) -> np.ndarray:
    """C-contiguous float64 array of the given ndim (the kernels' fixed argument types)."""
    a = np.ascontiguousarray(a, dtype=float)
    if a.ndim != ndim:
        raise ValueError(f"expected a {ndim}-d array, got shape {a.shape}")
    return a


def dt_seconds(dt_ns: int) -> float:
    """Integer nanoseconds -> float seconds, refusing negative or non-integer input."""
    if isinstance(dt_ns, bool) or not isinstance(dt_ns, (int, np.integer)):
        raise TypeError(f"dt must be integer nanoseconds, got {type(dt_ns).__name__}")
    if dt_ns < 0:
        raise ValueError(f"dt must not be negative, got {dt_ns} ns")
    return int(dt_ns) / NS_PER_S


class BatchedEKF:
    """N independent EKFs sharing one process model, stepped together."""

    def __init__(self, model: ProcessModel, X0: np.ndarray, P0: np.ndarray,
                 min_variance: float = 1e-12) -> None:
        X0 = np.array(X0, dtype=float)
        if X0.ndim != 2 or X0.shape[1] != model.n:
            raise ValueError(f"X0 must be shaped (N, {model.n}), got {X0.shape}")
        if not np.all(np.isfinite(X0)):
            raise ValueError("X0 must be finite")
        P0 = np.array(P0, dtype=float)
        if P0.shape == (model.n, model.n):
            P0 = np.broadcast_to(P0, (X0.shape[0], model.n, model.n))
        if P0.shape != (X0.shape[0], model.n, model.n):
            raise ValueError(f"P0 must be shaped ({model.n}, {model.n}) or (N, n, n), got {P0.shape}")
        self.model = model
        self.X = np.ascontiguousarray(X0)
        self.P = np.ascontiguousarray(_as_spd(P0, "P0"))
        self.min_variance = float(min_variance)
        if not (self.min_variance > 0.0):
            raise ValueError("min_variance must be > 0")
        self._x_is_angle = np.asarray(model.x_is_angle, dtype=np.bool_)
        self._ok = np.ones(self.N, dtype=np.bool_)
        self._status = np.zeros(self.N, dtype=np.int64)
        self._d2 = np.zeros(self.N)
        self._masks: dict[int, np.ndarray] = {}  # all-true (1, m) masks
        self._predict_kernel = kernels.FastCall(kernels.predict)
        self._update_kernel = kernels.FastCall(kernels.update)

    @property
    def N(self) -> int:
        return self.X.shape[0]

    def predict(self, dt_ns: int, U: np.ndarray | None = None) -> np.ndarray:
        """Propagate every trial by dt_ns nanoseconds. Returns a bool (N,) of trials updated."""
        dt = dt_seconds(dt_ns)
        self._ok[:] = True
        if dt == 0.0:
            return self._ok
        model = self.model
        fj = getattr(model, "f_and_jacobian", None)
        if fj is not None:
            Xn, F = fj(self.X, U, dt)
        else:
            Xn = model.f(self.X, U, dt)
            F = model.jacobian(self.X, U, dt)
        Q = model.noise(self.X, U, dt)
        if Q.ndim == 2:
            Q = Q[None]
        self._predict_kernel(self.X, self.P, _c3(Xn, 2), _c3(F, 3), _c3(Q, 3), self._x_is_angle,
                             self.min_variance, self._ok)
        return self._ok

    def update(self, model: MeasurementModel, Z: np.ndarray, R: np.ndarray,
               mask: np.ndarray | None = None,
               gate_sigmas: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """Fuse one measurement per trial. Returns (status (N,), squared Mahalanobis (N,))."""
        Z = np.ascontiguousarray(Z, dtype=float)
        if Z.shape != (self.N, model.m):
            raise ValueError(f"Z must be shaped ({self.N}, {model.m}), got {Z.shape}")
        R = np.asarray(R, dtype=float)
        if R.ndim == 2:
            R = R[None]
        if mask is None:
            mask = self._masks.get(model.m)
            if mask is None:
                mask = self._masks[model.m] = np.ones((1, model.m), dtype=np.bool_)
        else:
            mask = np.asarray(mask, dtype=np.bool_)
            if mask.ndim == 1:
                mask = mask[None]
        gate_sq = float(gate_sigmas * gate_sigmas) if gate_sigmas > 0 else math.inf
        Zhat = _NO_ZHAT if getattr(model, "linear", False) else _c3(model.h(self.X), 2)
        self._update_kernel(self.X, self.P, Z, Zhat, _c3(model.jacobian(self.X), 3), _c3(R, 3),
                            np.ascontiguousarray(mask), np.ascontiguousarray(model.z_is_angle, np.bool_),
                            self._x_is_angle, gate_sq, self._status, self._d2)
        return self._status, self._d2


class ExtendedKalmanFilter:
    """A single EKF (the N = 1 case of :class:`BatchedEKF`, with friendlier shapes)."""

    def __init__(self, model: ProcessModel, x0: np.ndarray, P0: np.ndarray,
                 min_variance: float = 1e-12) -> None:
        self._batch = BatchedEKF(model, np.asarray(x0, dtype=float)[None, :],
                                 np.asarray(P0, dtype=float)[None, :, :], min_variance)

    @property
    def model(self) -> ProcessModel:
        return self._batch.model

    @property
    def x(self) -> np.ndarray:
        """State (n,), a view: copy it before keeping it."""
        return self._batch.X[0]

    @property
    def P(self) -> np.ndarray:
        """Covariance (n, n), a view: copy it before keeping it."""
        return self._batch.P[0]

    def set_state(self, x: np.ndarray, P: np.ndarray) -> None:
        x = np.asarray(x, dtype=float)
        if x.shape != (self.model.n,) or not np.all(np.isfinite(x)):
            raise ValueError(f"state must be {self.model.n} finite values")
        self._batch.X[0] = x
        self._batch.P[0] = _as_spd(P, "P")

    def predict(self, dt_ns: int, u: np.ndarray | None = None) -> bool:
        """Propagate by dt_ns nanoseconds with control u (or None). False if rejected."""
        U = None if u is None else np.asarray(u, dtype=float).reshape(1, -1)
        return bool(self._batch.predict(dt_ns, U)[0])

    def update(self, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               mask: np.ndarray | None = None, gate_sigmas: float = math.inf) -> UpdateResult:
        """Fuse measurement z with covariance R; mask selects components (partial update)."""
        status, d2 = self._batch.update(model, np.asarray(z, dtype=float)[None],
                                        np.asarray(R, dtype=float)[None], mask, gate_sigmas)
        d = float(d2[0])
        return UpdateResult(int(status[0]), math.sqrt(d) if d >= 0.0 else math.nan)
