"""The extended Kalman filter in plain numpy: one state, its covariance, two steps.

The equations (docs/models.md, "The EKF"; seed 000 section III, eq. 7-12), for a state x (n,)
and its covariance P:

* predict (eq. 7, 9; the EKF form eq. 15):   x' = f(x, u, Δt),   P' = F P Fᵀ + Q,   F = ∂f/∂x
* update (eq. 10-12):  y = z - h(x) (angles wrapped),  S = H P Hᵀ + R,  K = P Hᵀ S⁻¹,
  x' = x + K y,  P' = (I - K H) P (I - K H)ᵀ + K R Kᵀ   (Joseph form: symmetric PD for any K)

Time enters as integer nanoseconds (ROS stamps) and becomes seconds once, in
:func:`dt_seconds`. After every step P is made exactly symmetric and tested finite and positive
definite by one Cholesky factorisation (:func:`make_spd`); if rounding left it indefinite, its
diagonal is lifted by ``min_variance`` (tenfold per try). Non-finite or inconsistent input is
refused with a status, never fused. Each step is a fixed handful of numpy calls on (n, n)
arrays: per call, numpy's overhead is most of the cost at these sizes. Products are
``ndarray.dot`` (the same BLAS call and result as ``@`` on 1-d and 2-d arrays, with about half
its per-call overhead: ``@`` dispatches as a ufunc). LAPACK's ``dpotrf(A, 1, 0)`` (lower, not
cleaned) and ``dpotrs(L, b, 1)`` (lower) take their options by position: f2py parses keywords
at a cost comparable to the factorisation of a 6 x 6 matrix.

Models work on stacks of states so that the research tables (seed_experiments) can run many
trials at once; here the stack holds one state:

* process model: ``n``, ``x_is_angle`` (n,), ``f(X, U, dt)`` -> (1, n), ``jacobian(X, U, dt)``
  -> (1, n, n) (or ``f_and_jacobian`` for both), ``noise(X, U, dt)`` -> (1, n, n) or (n, n);
  optionally ``control_dim``.
* measurement model: ``m``, ``z_is_angle`` (m,), ``h(X)`` -> (1, m), ``jacobian(X)`` -> (1, m, n);
  or ``linear = True`` with a constant ``H`` (m, n) (z = H x).
"""

from __future__ import annotations

import contextlib
import math
from functools import lru_cache
from typing import NamedTuple, Protocol

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotrs

from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.linalg import has_cholesky, is_positive_definite, is_symmetric
from ekf_localization.core.units import NS_PER_S, ns_to_seconds

# Update status.
STATUS_OK = 0
STATUS_SKIPPED = 1  # no component selected by the mask
STATUS_GATED = 2  # Mahalanobis distance above the gate
STATUS_NONFINITE = 3  # z, h(x), H or R not finite in a selected component, or a non-finite result
STATUS_BAD_R = 4  # R not symmetric, or not positive semi-definite (e.g. a negative variance)
STATUS_S_NOT_PD = 5  # innovation covariance not positive definite
STATUS_P_NOT_PD = 6  # updated P could not be made positive definite: reverted

STATUS_TEXT = {
    STATUS_OK: "ok",
    STATUS_SKIPPED: "no valid component",
    STATUS_GATED: "rejected by Mahalanobis gate",
    STATUS_NONFINITE: "non-finite measurement, prediction, Jacobian or covariance",
    STATUS_BAD_R: "measurement covariance not symmetric or not positive semi-definite",
    STATUS_S_NOT_PD: "innovation covariance not positive definite",
    STATUS_P_NOT_PD: "update would break positive definiteness of P (reverted)",
}

MAX_LIFTS = 40  # diagonal lifts of min_variance · 10^k tried before P counts as unusable


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
    """Outcome of one update; y and S once the update got that far (None before)."""

    status: int
    mahalanobis: float  # sqrt of the innovation's squared Mahalanobis distance (nan if not reached)
    y: np.ndarray | None = None  # the innovation z - h(x), angles wrapped (selected components)
    S: np.ndarray | None = None  # its covariance H P Hᵀ + R

    @property
    def accepted(self) -> bool:
        return self.status == STATUS_OK

    @property
    def reason(self) -> str:
        return STATUS_TEXT[self.status]


def dt_seconds(dt_ns: int) -> float:
    """Integer nanoseconds -> float seconds, refusing negative or non-integer input."""
    if isinstance(dt_ns, bool) or not isinstance(dt_ns, int | np.integer):
        raise TypeError(f"dt must be integer nanoseconds, got {type(dt_ns).__name__}")
    if dt_ns < 0:
        raise ValueError(f"dt must not be negative, got {dt_ns} ns")
    return ns_to_seconds(int(dt_ns))


@lru_cache(maxsize=64)
def gate_squared(gate_sigmas: float) -> float:
    """The squared Mahalanobis gate of ``gate_sigmas`` (math.inf: no gate)."""
    g = float(gate_sigmas)
    if g == math.inf:
        return math.inf
    if not g > 0.0:
        raise ValueError(f"gate_sigmas must be > 0 (math.inf disables the gate), got {gate_sigmas!r}")
    return g * g


def make_spd(P: np.ndarray, min_variance: float) -> bool:
    """Make P (n, n) exactly symmetric, in place, and positive definite: lift its diagonal by
    min_variance, then tenfold per try, until the Cholesky test passes. False when P is not
    finite or no lift made it positive definite.

    One factorisation is both tests. (a + b) and (b + a) are the same float, so P's triangles
    are then equal, and in a Cholesky factorisation every entry of the lower triangle reaches a
    pivot: a nan makes a pivot nan, an infinity makes one infinite or the factorisation fail.
    So the factorisation succeeds with a finite diagonal exactly when P is finite and positive
    definite. (Some LAPACKs pass nan through instead of failing: hence the look at the pivots.)
    """
    P += P.T.copy()  # (numpy's in-place add of an overlapping view copies it more slowly)
    P *= 0.5
    L, info = dpotrf(P, 1, 0)
    if info == 0:
        return math.isfinite(sum(L.diagonal().tolist()))  # (an overflowing sum: not finite)
    if not np.isfinite(P).all():
        return False
    diagonal = np.eye(P.shape[0], dtype=bool)
    lift = min_variance
    for _ in range(MAX_LIFTS):
        P[diagonal] += lift
        if has_cholesky(P):
            return True
        lift *= 10.0
    return False


class ExtendedKalmanFilter:
    """One EKF: the equations of the module docstring, on x (n,) and P (n, n)."""

    def __init__(self, model: ProcessModel, x0: np.ndarray, P0: np.ndarray,
                 min_variance: float = 1e-12) -> None:
        n = int(model.n)
        x0 = np.asarray(x0, dtype=float)
        P0 = np.asarray(P0, dtype=float)
        if x0.shape != (n,) or P0.shape != (n, n):
            raise ValueError(f"x0 must be ({n},) and P0 ({n}, {n}), got {x0.shape} and {P0.shape}")
        min_variance = float(min_variance)
        if not (min_variance > 0.0 and math.isfinite(min_variance)):
            raise ValueError(f"min_variance must be finite and > 0, got {min_variance!r}")
        x_is_angle = np.asarray(model.x_is_angle, dtype=bool)
        if x_is_angle.shape != (n,):
            raise ValueError(f"model.x_is_angle must have {n} entries, got shape {x_is_angle.shape}")
        self.model = model
        self.min_variance = min_variance
        self._n = n
        self._k = getattr(model, "control_dim", None)
        self._angle_rows = np.flatnonzero(x_is_angle).tolist()
        self._eye = np.eye(n)
        self.last_widening = 1.0  # R's factor in the last update (the residual check)
        self._X = np.zeros((1, n))  # the models' stack of one state; x is its row
        self._x = self._X[0]
        self._P = np.eye(n)
        self._f_and_jacobian = getattr(model, "f_and_jacobian", None)
        self._u_shape = (self._k,)  # the shapes checked on every step, built once
        self._stack_shape = (1, n)
        self._nn = (n, n)
        self.set_state(x0, P0)

    @property
    def x(self) -> np.ndarray:
        """State (n,), the filter's own array: copy it before keeping it."""
        return self._x

    @property
    def P(self) -> np.ndarray:  # noqa: N802 - the usual symbol
        """Covariance (n, n), the filter's own array: copy it before keeping it."""
        return self._P

    def set_state(self, x: np.ndarray, P: np.ndarray) -> None:
        """Replace the state (n,) and covariance (n, n), checked finite and symmetric PD."""
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        if x.shape != (self._n,) or not np.isfinite(x).all():
            raise ValueError(f"state must be {self._n} finite values")
        if P.shape != (self._n, self._n):
            raise ValueError(f"P must be shaped ({self._n}, {self._n}), got {P.shape}")
        if not np.isfinite(P).all():
            raise ValueError("P must be finite")
        if not is_symmetric(P):
            raise ValueError("P must be symmetric")
        if not is_positive_definite(P):
            raise ValueError("P must be positive definite")
        self._commit(x, 0.5 * (P + P.T))

    def restore(self, x: np.ndarray, P: np.ndarray) -> None:
        """Put back a state and covariance this filter had (a snapshot): not checked again."""
        self._x[:] = x
        self._P[:] = P

    def predict(self, dt_ns: int, u: np.ndarray | None = None) -> bool:
        """Eq. 7 and 9 over dt_ns nanoseconds with control u (k,) or None. False (state kept) if the
        prediction is not finite."""
        if type(dt_ns) is int and dt_ns > 0:  # the usual step: dt_seconds' checks hold
            dt = dt_ns / NS_PER_S
        else:
            dt = dt_seconds(dt_ns)
            if dt == 0.0:
                return True
        U = None
        if u is not None:
            if type(u) is not np.ndarray or u.dtype != np.float64:
                u = np.asarray(u, dtype=float)
            if u.shape != self._u_shape and (self._k is not None or u.ndim != 1):
                raise ValueError(f"control must be shaped ({self._k},), got {u.shape}")
            U = u[None]
        model, X, n = self.model, self._X, self._n
        if self._f_and_jacobian is not None:
            Xn, F = self._f_and_jacobian(X, U, dt)
        else:
            Xn, F = model.f(X, U, dt), model.jacobian(X, U, dt)
        Q = model.noise(X, U, dt)
        if Xn.shape != self._stack_shape or F.shape[-2:] != self._nn or Q.shape[-2:] != self._nn:
            raise ValueError(f"process model returned f {Xn.shape}, F {F.shape}, Q {Q.shape} for x ({n},)")
        F = F.reshape(n, n)
        Pn = F.dot(self._P).dot(F.T)  # eq. 9
        Pn += Q.reshape(n, n)
        xn = Xn[0]
        if not (math.isfinite(sum(xn.tolist())) and make_spd(Pn, self.min_variance)):  # (overflow: nonfinite)
            return False
        self._commit(xn, Pn)
        return True

    def update(self, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               mask: np.ndarray | None = None, gate_sigmas: float = math.inf,
               r_checked: bool = False, widen_above: float = math.inf) -> UpdateResult:
        """Eq. 10-12: fuse measurement z (m,) with covariance R (m, m); mask (m,) selects components.

        gate_sigmas rejects the update when the innovation's Mahalanobis distance exceeds it
        (math.inf: no gate). Bad values (non-finite, bad R) do not raise: the update is skipped
        and ``UpdateResult.reason`` says why; wrong shapes raise ValueError. ``r_checked``: the
        caller has checked z finite and R finite, symmetric and positive semi-definite (once per
        message, not at every replay of it): not tested again. ``widen_above``: the residual
        check (docs/models.md, "Tag corners and the residual check"): an innovation whose
        yᵀS⁻¹y exceeds it has R scaled by yᵀS⁻¹y / m before the gate and the update (math.inf:
        never); that factor is then ``last_widening`` (1: not widened)."""
        self.last_widening = 1.0
        m = model.m
        if type(z) is not np.ndarray or type(R) is not np.ndarray:
            z, R = np.asarray(z, dtype=float), np.asarray(R, dtype=float)
        if z.shape != (m,) or R.shape != (m, m):
            raise ValueError(f"z must be ({m},) and R ({m}, {m}), got {z.shape} and {R.shape}")
        gate_sq = math.inf if gate_sigmas == math.inf else gate_squared(gate_sigmas)
        x, P = self._x, self._P
        linear = getattr(model, "linear", False)
        j = None  # the state component a one-row H = e_jᵀ reads (core.linear's unit_row)
        if linear:  # z = H x, H constant and finite (LinearMeasurement checks it)
            H = model.H
            j = getattr(model, "unit_row", None)
            y = z - (H.dot(x) if j is None else x.item(j))  # eq. 11's residual (e_jᵀ x = x_j: read)
        else:
            with np.errstate(all="ignore"):  # a singular h gives nan: refused below
                y = z - np.asarray(model.h(self._X), dtype=float).reshape(m)
                H = np.asarray(model.jacobian(self._X), dtype=float).reshape(m, self._n)
        angles = getattr(model, "angle_components", None)
        for i in (_angle_components(model) if angles is None else angles):  # angle residuals wrapped
            y[i] = wrap_angle(y.item(i))
        if mask is not None:
            keep = _selected(mask, m)
            if keep is not None:  # the reduced measurement: only the selected components
                if keep.size == 0:
                    return UpdateResult(STATUS_SKIPPED, math.nan)
                y, H, R = y[keep], H[keep], R[np.ix_(keep, keep)]
                j = None
        if not (linear and r_checked):  # else z, H, R and x are finite: so is y
            total = np.add.reduce(y) + (0.0 if r_checked else np.add.reduce(R, axis=None)) \
                + (0.0 if linear else np.add.reduce(H, axis=None))
            if not math.isfinite(total) and not (  # (a finite sum is the usual case)
                    np.isfinite(y).all() and (linear or np.isfinite(H).all())
                    and (r_checked or np.isfinite(R).all())):
                return UpdateResult(STATUS_NONFINITE, math.nan)
        if not r_checked:
            R = symmetric_psd(R)
            if R is None:
                return UpdateResult(STATUS_BAD_R, math.nan)
        if y.size == 1:  # one component (an IMU's yaw, a yaw rate): S is a number
            return self._update_one(y, H[0], R.item(), gate_sq, widen_above, j)
        HP = H.dot(P)
        S = HP.dot(H.T)  # eq. 10: positive definite for a PD P and a PSD R, but for rounding
        S += R
        L, info = dpotrf(S, 1, 0)  # S = L Lᵀ, which exists iff S is PD
        if info != 0:
            return UpdateResult(STATUS_S_NOT_PD, math.nan)
        d2 = float(y.dot(dpotrs(L, y, 1)[0]))  # yᵀ S⁻¹ y (>= 0 but for rounding)
        if d2 < 0.0:
            d2 = 0.0
        if d2 > widen_above:  # the residual check: R scaled by the observed / expected NIS
            self.last_widening = d2 / y.size
            S = S + (self.last_widening - 1.0) * R  # H P Hᵀ + k R
            R = R * self.last_widening
            L, info = dpotrf(S, 1, 0)
            if info != 0:
                return UpdateResult(STATUS_S_NOT_PD, math.nan)
            d2 = max(float(y.dot(dpotrs(L, y, 1)[0])), 0.0)
        d = math.sqrt(d2)
        if not d2 <= gate_sq:
            return UpdateResult(STATUS_GATED, d, y, S)
        Kt = dpotrs(L, HP, 1)[0]  # eq. 10: Kᵀ = S⁻¹ H P
        K = Kt.T
        A = self._eye - K.dot(H)
        Pn = A.dot(P).dot(A.T)  # eq. 12, Joseph form
        Pn += K.dot(R).dot(Kt)
        xn = K.dot(y)  # eq. 11
        xn += x
        if not math.isfinite(sum(xn.tolist())):  # (an overflow counts as not finite)
            return UpdateResult(STATUS_NONFINITE, d, y, S)
        if not make_spd(Pn, self.min_variance):  # not finite, or no lift made it PD
            return UpdateResult(STATUS_NONFINITE if not np.isfinite(Pn).all() else STATUS_P_NOT_PD, d, y, S)
        self._commit(xn, Pn)
        return UpdateResult(STATUS_OK, d, y, S)

    def _update_one(self, y: np.ndarray, h: np.ndarray, r: float, gate_sq: float,
                    widen_above: float, j: int | None = None) -> UpdateResult:
        """:meth:`update` for one component, H = hᵀ (1, n): the same equations with S = hᵀ P h + r a
        number (docs/models.md, "The engine"). S⁻¹ is a division, and the Joseph form's products
        are outer products: with k = P h / S, (I - k hᵀ) P = P - k (P h)ᵀ, then
        ((I - k hᵀ) P)(I - k hᵀ)ᵀ = B - (B h) kᵀ for that B, plus r k kᵀ. With h = e_j (``j``,
        a measurement of one state component) M h is M's column j: read, not multiplied. An
        outer product a bᵀ is a (n, 1) by (1, n) ``dot``: the same products as broadcasting,
        at half its cost."""
        x, P = self._x, self._P
        if j is None:
            hp = P.dot(h)  # P h = (H P)ᵀ: P is symmetric
            s = float(hp.dot(h)) + r  # eq. 10's S
        else:
            hp = P[:, j]
            s = P.item(j, j) + r
        if not s > 0.0:  # (not positive definite, or nan)
            return UpdateResult(STATUS_S_NOT_PD, math.nan)
        v = y.item()
        d2 = v * v / s  # yᵀ S⁻¹ y
        if d2 > widen_above:  # the residual check: r scaled by the observed / expected NIS
            self.last_widening = d2
            s += (d2 - 1.0) * r
            r *= d2
            d2 = v * v / s
        d = math.sqrt(d2)
        S = np.array([[s]])
        if not d2 <= gate_sq:
            return UpdateResult(STATUS_GATED, d, y, S)
        k = hp / s  # eq. 10: K = P Hᵀ S⁻¹
        kc, kr = k[:, None], k[None]
        B = P - kc.dot(hp[None])  # (I - K H) P
        Bh = B.dot(h) if j is None else B[:, j]
        Pn = B - Bh[:, None].dot(kr)  # eq. 12, Joseph form: (I - K H) P (I - K H)ᵀ ...
        Pn += (r * kc).dot(kr)  # ... + K R Kᵀ
        xn = k * v  # eq. 11
        xn += x
        if not math.isfinite(sum(xn.tolist())):  # (an overflow counts as not finite)
            return UpdateResult(STATUS_NONFINITE, d, y, S)
        if not make_spd(Pn, self.min_variance):
            return UpdateResult(STATUS_NONFINITE if not np.isfinite(Pn).all() else STATUS_P_NOT_PD, d, y, S)
        self._commit(xn, Pn)
        return UpdateResult(STATUS_OK, d, y, S)

    def _commit(self, x: np.ndarray, P: np.ndarray) -> None:
        """The new state (angles wrapped) and covariance."""
        own = self._x
        own[:] = x
        for i in self._angle_rows:
            own[i] = wrap_angle(own.item(i))  # (a Python float: wrap_angle's arithmetic is cheaper on it)
        self._P[:] = P


def _angle_components(model: MeasurementModel) -> list[int]:
    """The components of ``model`` whose residual is an angle (kept on the model once found)."""
    angles = getattr(model, "angle_components", None)
    if angles is None:
        angles = np.flatnonzero(np.asarray(model.z_is_angle, dtype=bool)).tolist()
        with contextlib.suppress(AttributeError):  # a model that takes no attributes: found each time
            model.angle_components = angles
    return angles


def _selected(mask: np.ndarray, m: int) -> np.ndarray | None:
    """The indices ``mask`` (m,) selects; None when it selects every component."""
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != (m,):
        raise ValueError(f"mask must be shaped ({m},), got {mask.shape}")
    return None if mask.all() else np.flatnonzero(mask)


def symmetric_psd(R: np.ndarray) -> np.ndarray | None:
    """A finite R (m, m) symmetrised if it is symmetric (core.linalg's tolerance) and positive
    semi-definite, else None. A diagonal R needs only its variances >= 0."""
    variances = R.diagonal()
    if min(variances.tolist(), default=0.0) < 0.0:  # (Python's min: cheaper than numpy's at this size)
        return None
    if np.count_nonzero(R) == np.count_nonzero(variances):
        return R  # diagonal with variances >= 0
    if not is_symmetric(R):
        return None
    R = 0.5 * (R + R.T)
    jitter = 1e-12 * variances.max() + 1e-300  # a PSD R then passes the Cholesky test
    return R if has_cholesky(R + jitter * np.eye(R.shape[0])) else None
