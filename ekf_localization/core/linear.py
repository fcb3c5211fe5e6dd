"""Linear models run by the EKF engine: a measurement z = H x and a process x' = x + Δt·B u."""

from __future__ import annotations

import numpy as np


class LinearMeasurement:
    """z = H x with constant H; ``z_is_angle`` marks components whose residual is wrapped."""

    linear = True

    def __init__(self, H: np.ndarray, z_is_angle: np.ndarray | None = None) -> None:
        self.H = np.ascontiguousarray(np.asarray(H, dtype=float))
        if self.H.ndim != 2 or not np.all(np.isfinite(self.H)):
            raise ValueError(f"H must be a finite (m, n) matrix, got shape {self.H.shape}")
        self.m, self.n = self.H.shape
        self.z_is_angle = (np.zeros(self.m, dtype=np.bool_) if z_is_angle is None
                           else np.asarray(z_is_angle, dtype=np.bool_))
        if self.z_is_angle.shape != (self.m,):
            raise ValueError(f"z_is_angle must have {self.m} entries, got shape {self.z_is_angle.shape}")
        self._HT = np.ascontiguousarray(self.H.T)
        self._H1 = self.H[None]
        # H = e_jᵀ (one row, a single 1): the state component j it reads (core.ekf's one-component update)
        ones = np.flatnonzero(self.H[0]).tolist() if self.m == 1 else []
        self.unit_row: int | None = ones[0] if len(ones) == 1 and self.H[0, ones[0]] == 1.0 else None

    def h(self, X: np.ndarray) -> np.ndarray:
        return X @ self._HT

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        """(1, m, n): the same H for every trial (the kernels broadcast a leading 1)."""
        return self._H1


def select_rows(n: int, rows: list[int], angle_rows: tuple[int, ...] = ()) -> LinearMeasurement:
    """A measurement that observes state components ``rows`` directly."""
    H = np.zeros((len(rows), n))
    for i, r in enumerate(rows):
        H[i, r] = 1.0
    return LinearMeasurement(H, np.array([r in angle_rows for r in rows], dtype=np.bool_))


def stack_measurements(*parts: LinearMeasurement) -> LinearMeasurement:
    """Several linear measurements of one state fused as one (e.g. seed 000 eq. 31 = 28 over 30)."""
    if not parts:
        raise ValueError("stack_measurements needs at least one measurement")
    return LinearMeasurement(np.vstack([p.H for p in parts]), np.concatenate([p.z_is_angle for p in parts]))


class LinearProcessModel:
    """x' = x + Δt·B u with constant B, Jacobian I, Q = diag(variance_per_step + variance_rate·Δt).

    A linear model run through the EKF engine is exactly the Kalman filter (seed 000 eq.
    7-12, Joseph form). B is (n, k): the state's rate of change per unit of control; with
    U = None the state is held. Variances are per state component: ``variance_per_step``
    is added at every prediction whatever its Δt, ``variance_rate`` grows with Δt.
    """

    def __init__(self, B: np.ndarray, variance_per_step=0.0, variance_rate=0.0,
                 x_is_angle: np.ndarray | None = None) -> None:
        self.B = np.ascontiguousarray(np.asarray(B, dtype=float))
        if self.B.ndim != 2 or not np.all(np.isfinite(self.B)):
            raise ValueError(f"B must be a finite (n, k) matrix, got shape {self.B.shape}")
        self.n, self.control_dim = self.B.shape
        self.variance_per_step = nonnegative_variances("variance_per_step", variance_per_step, self.n)
        self.variance_rate = nonnegative_variances("variance_rate", variance_rate, self.n)
        self.x_is_angle = (np.zeros(self.n, dtype=np.bool_) if x_is_angle is None
                           else np.asarray(x_is_angle, dtype=np.bool_))
        self._F = np.eye(self.n)[None]
        self._BT = np.ascontiguousarray(self.B.T)
        self._q_cache: tuple[float, np.ndarray] | None = None

    def f(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        if U is None:
            return X.copy()
        return X + dt * (np.asarray(U, dtype=float) @ self._BT)

    def jacobian(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        """(1, n, n) identity, shared by every trial."""
        return self._F

    def noise(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        c = self._q_cache
        if c is not None and c[0] == dt:
            return c[1]
        Q = np.diag(self.variance_per_step + self.variance_rate * dt)[None]
        self._q_cache = (dt, Q)
        return Q


def nonnegative_variances(name: str, value, n: int) -> np.ndarray:
    """``value`` (a scalar or n values) as n finite non-negative variances, else ValueError."""
    v = np.asarray(value, dtype=float)
    if v.shape == ():
        v = np.full(n, float(v))
    if v.shape != (n,) or not np.all(np.isfinite(v)) or np.any(v < 0.0):
        raise ValueError(f"{name} must be {n} finite non-negative variances, got {value!r}")
    return v
