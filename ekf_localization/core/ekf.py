"""Generic extended Kalman filter: one trial or N independent trials at once.

Time enters as integer nanoseconds (ROS stamps) and becomes seconds only inside the
step. Residual angles are wrapped to (-pi, pi], the covariance update is Joseph form,
P stays symmetric positive definite, and non-finite inputs are rejected with a reason.

Process and measurement models work on batches, states shaped (N, n):

* process model: ``n``, ``x_is_angle`` (n,), ``f(X, U, dt)`` -> (N, n),
  ``jacobian(X, U, dt)`` -> (N, n, n) or (1, n, n), optionally ``f_and_jacobian`` (both),
  ``noise(X, U, dt)`` -> (N, n, n), (1, n, n) or (n, n) (return the same array object for
  the same dt to skip its checks); optionally ``control_dim`` (k: U is (N, k), checked).
  Fast path (optional): ``predict_kernel``, a numba function
  ``(X, P, U, has_control, dt, steps, Q, kernel_params, x_is_angle, min_variance, ok, work)``
  doing f, F and F P Fᵀ + Q ``steps`` times in place with :func:`kernels.commit_prediction`
  (ok[b]: every step of trial b committed; steps > 1 only with a Q shared by the trials; work has
  :func:`kernels.predict_work_shape`; key its cache with :func:`kernels.source_stamp`), and
  ``kernel_params``, a 1-D float64 array of the model's constants.
* measurement model: ``m``, ``z_is_angle`` (m,), ``h(X)`` -> (N, m),
  ``jacobian(X)`` -> (N, m, n) or (1, m, n) when it is the same for every trial;
  ``linear = True`` declares h(X) = H X (the kernel then evaluates it itself).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple, Protocol

import numpy as np

from ekf_localization.core import kernels, message_step
from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.kernels import STATUS_OK, STATUS_TEXT
from ekf_localization.core.linalg import is_positive_definite, is_symmetric, symmetrise
from ekf_localization.core.units import NS_PER_S, ns_to_seconds

_NO_ZHAT = np.empty((0, 0))  # Zhat of a linear model (computed inside the kernel)
_MAX_CACHED_MEASUREMENTS = 64


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


_new_result = tuple.__new__  # UpdateResult without the NamedTuple constructor's Python overhead


def _as_spd(P: np.ndarray, name: str) -> np.ndarray:
    """P (..., n, n) checked finite, symmetric and positive definite; returned symmetrised."""
    P = np.array(P, dtype=float)
    if not np.all(np.isfinite(P)):
        raise ValueError(f"{name} must be finite")
    if not is_symmetric(P):
        raise ValueError(f"{name} must be symmetric")
    if not is_positive_definite(P):
        raise ValueError(f"{name} must be positive definite")
    return symmetrise(P)


def _c(a: np.ndarray, ndim: int, name: str) -> np.ndarray:
    """C-contiguous float64 array of the given ndim (the kernels' fixed argument types)."""
    a = np.ascontiguousarray(a, dtype=float)
    if a.ndim != ndim:
        raise ValueError(f"{name}: expected a {ndim}-d array, got shape {a.shape}")
    return a


def dt_seconds(dt_ns: int) -> float:
    """Integer nanoseconds -> float seconds, refusing negative or non-integer input."""
    if type(dt_ns) is not int and (isinstance(dt_ns, bool) or not isinstance(dt_ns, np.integer)):
        raise TypeError(f"dt must be integer nanoseconds, got {type(dt_ns).__name__}")
    if dt_ns < 0:
        raise ValueError(f"dt must not be negative, got {dt_ns} ns")
    return ns_to_seconds(int(dt_ns))


def gate_squared(gate_sigmas: float) -> float:
    if gate_sigmas is math.inf:
        return math.inf
    g = float(gate_sigmas)
    if not g > 0.0:
        raise ValueError(f"gate_sigmas must be > 0 (math.inf disables the gate), got {gate_sigmas!r}")
    return g * g


BoundUpdate = Callable[[np.ndarray, np.ndarray], tuple[int, float]]  # (z, R) -> (status, squared distance)
# (dt_ns, buf, nis, v0, c0, v1, c1, fuse) -> code: ExtendedKalmanFilter.message_stepper
MessageStep = Callable[[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool],
                       int]


class _Prepared(NamedTuple):
    """Per measurement model: validated constants, its compiled kernel and scratch space."""

    model: object
    m: int
    linear: bool
    all_components: np.ndarray  # (1, m) True
    kernel: object  # compiled entry point of the update kernel for (n, m)
    tail: tuple  # the kernel's constant trailing arguments
    checked_jacobian: list  # [last Jacobian array that passed the checks]
    z_shape: tuple[int]
    R_shape: tuple[int, int]


class _FilterCore:
    """State, covariance, scratch space and kernel calls shared by both filter classes."""

    def __init__(self, model: ProcessModel, X0: np.ndarray, P0: np.ndarray, min_variance: float) -> None:
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
        x_is_angle = np.ascontiguousarray(model.x_is_angle, dtype=np.bool_)
        if x_is_angle.shape != (n,):
            raise ValueError(f"model.x_is_angle must have {n} entries, got shape {x_is_angle.shape}")
        k = getattr(model, "control_dim", None)
        self.model = model
        self._n = n
        self._min_variance = min_variance
        self._x_is_angle = x_is_angle
        self._control_dim = None if k is None else int(k)
        self._X = np.ascontiguousarray(np.where(x_is_angle, wrap_angles(X0), X0))
        self._P = np.ascontiguousarray(_as_spd(P0, "initial covariance"))
        self._ok = np.ones(N, dtype=np.bool_)
        self._status = np.zeros(N, dtype=np.int64)
        self._d2 = np.zeros(N)
        self._prepared: dict[int, _Prepared] = {}
        self._checked_Q: np.ndarray | None = None  # last Q that passed the checks (models cache Q)
        # predict: the model's fused kernel when it has one, else f/F/Q from Python + commit
        pwork = np.zeros(kernels.predict_work_shape(n))
        self._no_control = np.zeros((N, max(self._control_dim or 0, 1)))
        Q_example = np.zeros((1, n, n))
        fused = getattr(model, "predict_kernel", None)
        if fused is None:
            self._fused = None
            self._commit_tail = (x_is_angle, min_variance, self._ok, pwork)
            self._commit_kernel = kernels.compiled_entry(
                kernels.predict_kernel(n), self._X, self._P, self._X, self._P, Q_example, *self._commit_tail)
        else:
            params = np.ascontiguousarray(model.kernel_params, dtype=float).ravel()
            self._fused_tail = (params, x_is_angle, min_variance, self._ok, pwork)
            self._fused = kernels.compiled_entry(fused, self._X, self._P, self._no_control, False, 0.0, 1,
                                                 Q_example, *self._fused_tail)

    @property
    def min_variance(self) -> float:
        """Smallest diagonal lift used to keep P positive definite (fixed at construction)."""
        return self._min_variance

    # -- shared steps ---------------------------------------------------------------
    def _check_control(self, U: np.ndarray) -> np.ndarray:
        U = np.ascontiguousarray(U, dtype=float)
        k = self._control_dim
        if U.ndim != 2 or U.shape[0] != self._X.shape[0] or (k is not None and U.shape[1] != k):
            raise ValueError(f"control must be shaped ({self._X.shape[0]}, {k}), got {U.shape}")
        return U

    def _check_noise(self, Q: np.ndarray) -> np.ndarray:
        Q0 = Q
        if Q.ndim == 2:
            Q = Q[None]
        Q = _c(Q, 3, "process noise Q")
        n = self._n
        if Q.shape[1:] != (n, n) or Q.shape[0] not in (1, self._X.shape[0]):
            raise ValueError(f"process noise Q must be (n, n) or (1|N, n, n) with n = {n}, got {Q.shape}")
        if Q is Q0:
            self._checked_Q = Q
        return Q

    def _predict(self, dt: float, U: np.ndarray | None, steps: int = 1) -> np.ndarray:
        """Propagate every trial ``steps`` times by dt seconds (dt > 0); U already checked.

        The fused kernel takes the steps in one call when Q is shared by the trials (it
        depends on dt and the command only); a per-trial Q (of the state) is made per step."""
        X = self._X
        Q = self.model.noise(X, U, dt)
        if Q is not self._checked_Q:
            Q = self._check_noise(Q)
        if steps > 1 and (self._fused is None or Q.shape[0] > 1):
            ok = self._predict(dt, U).copy()
            for _ in range(steps - 1):
                ok &= self._predict(dt, U)
            self._ok[:] = ok
            return self._ok
        if self._fused is not None:
            if U is None:
                self._fused(X, self._P, self._no_control, False, dt, steps, Q, *self._fused_tail)
            else:
                self._fused(X, self._P, U, True, dt, steps, Q, *self._fused_tail)
            return self._ok
        model = self.model
        fj = getattr(model, "f_and_jacobian", None)
        if fj is not None:
            Xn, F = fj(X, U, dt)
        else:
            Xn = model.f(X, U, dt)
            F = model.jacobian(X, U, dt)
        Xn = _c(Xn, 2, "f(X, U, dt)")
        F = _c(F, 3, "process Jacobian")
        n = self._n
        if Xn.shape != X.shape or F.shape[1:] != (n, n) or F.shape[0] not in (1, X.shape[0]):
            raise ValueError(f"process model returned f {Xn.shape}, F {F.shape} for X {X.shape}")
        self._commit_kernel(X, self._P, Xn, F, Q, *self._commit_tail)
        return self._ok

    def _prepare(self, model: MeasurementModel) -> _Prepared:
        prep = self._prepared.get(id(model))
        if prep is not None and prep.model is model:
            return prep
        m = int(model.m)
        if m < 1:
            raise ValueError(f"measurement must have at least one component, got m = {m}")
        z_is_angle = np.ascontiguousarray(model.z_is_angle, dtype=np.bool_)
        if z_is_angle.shape != (m,):
            raise ValueError(f"measurement z_is_angle must have {m} entries, got {z_is_angle.shape}")
        n = self._n
        N = self._X.shape[0]
        all_components = np.ones((1, m), dtype=np.bool_)
        work = np.zeros(kernels.update_work_shape(n, m))
        tail = (z_is_angle, self._x_is_angle, self._min_variance, self._status, self._d2, work)
        Z0 = np.zeros((N, m))
        kernel = kernels.compiled_entry(kernels.update_kernel(n, m), self._X, self._P, Z0, Z0,
                                        np.zeros((1, m, n)), np.zeros((1, m, m)), all_components, 0.0, *tail)
        prep = _Prepared(model, m, bool(getattr(model, "linear", False)), all_components, kernel, tail,
                         [None], (m,), (m, m))
        if len(self._prepared) >= _MAX_CACHED_MEASUREMENTS:
            self._prepared.clear()
        self._prepared[id(model)] = prep
        return prep

    def _predicted_measurement(self, prep: _Prepared) -> tuple[np.ndarray, np.ndarray]:
        """(Zhat (N, m), or no rows for a linear model; Jacobian (1|N, m, n)), both checked."""
        X = self._X
        model = prep.model
        if prep.linear:
            Zhat = _NO_ZHAT
            H = model.jacobian(X)
        else:
            with np.errstate(all="ignore"):  # a singular h gives nan: rejected by the kernel
                Zhat = _c(model.h(X), 2, "h(X)")
                H = model.jacobian(X)
            if Zhat.shape != (X.shape[0], prep.m):
                raise ValueError(f"h(X) must be shaped ({X.shape[0]}, {prep.m}), got {Zhat.shape}")
        if H is not prep.checked_jacobian[0]:
            H0 = H
            H = _c(H, 3, "measurement Jacobian")
            if H.shape[1] != prep.m or H.shape[2] != self._n or H.shape[0] not in (1, X.shape[0]):
                raise ValueError(f"measurement Jacobian must be (1|N, {prep.m}, {self._n}), got {H.shape}")
            if H is H0:  # constant Jacobians (linear models) are checked once
                prep.checked_jacobian[0] = H
        return Zhat, H

    def _constant_jacobian(self, prep: _Prepared) -> np.ndarray:
        """A linear model's Jacobian: constant, checked once (prep.checked_jacobian)."""
        H = prep.checked_jacobian[0]
        return self._predicted_measurement(prep)[1] if H is None else H

    def _mask(self, prep: _Prepared, mask: np.ndarray | None) -> np.ndarray:
        if mask is None:
            return prep.all_components
        mask = np.ascontiguousarray(mask, dtype=np.bool_)
        if mask.ndim == 1:
            mask = mask[None]
        N = self._X.shape[0]
        if mask.ndim != 2 or mask.shape[1] != prep.m or mask.shape[0] not in (1, N):
            raise ValueError(f"mask must be shaped ({prep.m},) or ({N}, {prep.m}), got {mask.shape}")
        return mask


class BatchedEKF(_FilterCore):
    """N independent EKFs sharing one process model, stepped together by the same kernels."""

    def __init__(self, model: ProcessModel, X0: np.ndarray, P0: np.ndarray,
                 min_variance: float = 1e-12) -> None:
        super().__init__(model, X0, P0, min_variance)

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
        P = _as_spd(P, "P")
        self._X[:] = np.where(self._x_is_angle, wrap_angles(X), X)
        self._P[:] = P

    def predict(self, dt_ns: int, U: np.ndarray | None = None, steps: int = 1) -> np.ndarray:
        """Propagate every trial by dt_ns nanoseconds with controls U (N, k) or None, ``steps``
        times in a row (sub-steps with the same U: one compiled call with a fused kernel).

        Returns a bool (N,): False for a trial with a prediction that was not finite (that
        step kept it as it was). The array belongs to the filter and is overwritten by the
        next predict.
        """
        dt = dt_seconds(dt_ns)
        if U is not None:
            U = self._check_control(U)
        if type(steps) is not int or steps < 1:
            raise ValueError(f"steps must be an int >= 1, got {steps!r}")
        if dt == 0.0:
            self._ok[:] = True
            return self._ok
        return self._predict(dt, U, steps)

    def update(self, model: MeasurementModel, Z: np.ndarray, R: np.ndarray,
               mask: np.ndarray | None = None,
               gate_sigmas: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """Fuse one measurement per trial. Returns (status (N,), squared Mahalanobis (N,)).

        R is (m, m) shared or (N, m, m); mask is (m,) shared or (N, m), True = fuse.
        The returned arrays belong to the filter and are overwritten by the next update.
        """
        prep = self._prepare(model)
        m = prep.m
        N = self._X.shape[0]
        Z = np.ascontiguousarray(Z, dtype=float)
        if Z.shape != (N, m):
            raise ValueError(f"Z must be shaped ({N}, {m}), got {Z.shape}")
        R = np.ascontiguousarray(R, dtype=float)
        if R.ndim == 2:
            R = R[None]
        if R.ndim != 3 or R.shape[1:] != (m, m) or R.shape[0] not in (1, N):
            raise ValueError(f"R must be shaped ({m}, {m}) or ({N}, {m}, {m}), got {R.shape}")
        mask = self._mask(prep, mask)
        gate_sq = gate_squared(gate_sigmas)
        Zhat, H = self._predicted_measurement(prep)
        prep.kernel(self._X, self._P, Z, Zhat, H, R, mask, gate_sq, *prep.tail)
        return self._status, self._d2


class ExtendedKalmanFilter(_FilterCore):
    """A single EKF: :class:`BatchedEKF`'s compiled kernels with N = 1, flat shapes."""

    def __init__(self, model: ProcessModel, x0: np.ndarray, P0: np.ndarray,
                 min_variance: float = 1e-12) -> None:
        x0 = np.asarray(x0, dtype=float)
        P0 = np.asarray(P0, dtype=float)
        if x0.ndim != 1 or P0.ndim != 2:
            raise ValueError(f"x0 must be (n,) and P0 (n, n), got {x0.shape} and {P0.shape}")
        super().__init__(model, x0[None, :], P0[None, :, :], min_variance)
        self._x = self._X[0]
        self._P1 = self._P[0]
        self._zero_Q = np.zeros((1, self._n, self._n))
        self._message_work: np.ndarray | None = None

    @property
    def x(self) -> np.ndarray:
        """State (n,), a view: copy it before keeping it."""
        return self._x

    @property
    def P(self) -> np.ndarray:  # noqa: N802 - the usual symbol
        """Covariance (n, n), a view: copy it before keeping it."""
        return self._P1

    def set_state(self, x: np.ndarray, P: np.ndarray) -> None:
        """Replace the state (n,) and covariance (n, n) (checked: finite, symmetric PD)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self._n,) or not np.all(np.isfinite(x)):
            raise ValueError(f"state must be {self._n} finite values")
        P = np.asarray(P, dtype=float)
        if P.shape != (self._n, self._n):
            raise ValueError(f"P must be shaped ({self._n}, {self._n}), got {P.shape}")
        P = _as_spd(P, "P")
        self._x[:] = np.where(self._x_is_angle, wrap_angles(x), x)
        self._P1[:] = P

    def predict(self, dt_ns: int, u: np.ndarray | None = None) -> bool:
        """Propagate by dt_ns nanoseconds with control u (k,) or None. False if rejected."""
        dt = dt_ns / NS_PER_S if type(dt_ns) is int and dt_ns >= 0 else dt_seconds(dt_ns)
        if u is None:
            U = None
        else:
            U = np.ascontiguousarray(u, dtype=float)
            if U.ndim != 1 or (self._control_dim is not None and U.shape[0] != self._control_dim):
                raise ValueError(f"control must be shaped ({self._control_dim},), got {U.shape}")
            U = U[None]
        if dt == 0.0:
            return True
        if self._fused is None:
            return self._predict(dt, U).item(0)
        X = self._X  # the fused-kernel path of _predict, inlined: this is the hot path
        Q = self.model.noise(X, U, dt)
        if Q is not self._checked_Q:
            Q = self._check_noise(Q)
        if U is None:
            self._fused(X, self._P, self._no_control, False, dt, 1, Q, *self._fused_tail)
        else:
            self._fused(X, self._P, U, True, dt, 1, Q, *self._fused_tail)
        return self._ok.item(0)

    def message_stepper(self, kernel: Callable, ints: np.ndarray, floats: np.ndarray) -> MessageStep:
        """``kernel`` (the model's ``message_kernel``) bound once to this filter and one input's
        constants (core.message_step.StepLayout's ``ints`` and ``floats``): ``f(dt_ns, buf, nis,
        v0, c0, v1, c1, fuse) -> code``, one compiled call per message (core.message_step says
        what the arguments and the code are): checks, snapshot, ``predict(dt_ns, None)`` and the
        updates. dt_ns: int >= 0."""
        if self._fused is None:
            raise ValueError("message_stepper needs a model with a fused predict kernel")
        X, P, zero_Q, noise = self._X, self._P, self._zero_Q, self.model.noise
        work = self._message_work
        if work is None:
            work = self._message_work = np.zeros(message_step.work_shape(self._n))

        def step(dt_ns: int, buf: np.ndarray, nis: np.ndarray, v0: np.ndarray, c0: np.ndarray,
                 v1: np.ndarray, c1: np.ndarray, fuse: bool) -> int:
            dt = dt_ns / NS_PER_S
            if dt == 0.0:
                Q = zero_Q
            else:
                Q = noise(X, None, dt)
                if Q is not self._checked_Q:
                    Q = self._check_noise(Q)
            return kernel(X, P, buf, dt, Q, ints, floats, work, nis, v0, c0, v1, c1, fuse)

        return step

    def linear_updater(self, model: MeasurementModel, gate_sigmas: float = math.inf) -> BoundUpdate | None:
        """``update(model, z, R, gate_sigmas=gate_sigmas)`` bound once, without its per-call checks:
        ``f(z, R) -> (status, squared Mahalanobis distance)``, z (m,) and R (m, m) C-contiguous
        float64 (a ValueError otherwise). None for a model that is not linear (its Jacobian is
        then evaluated per update)."""
        prep = self._prepare(model)
        if not prep.linear:
            return None
        H = self._constant_jacobian(prep)
        kernel, X, P, mask, tail, status, d2 = (prep.kernel, self._X, self._P, prep.all_components, prep.tail,
                                                self._status, self._d2)
        gate_sq = gate_squared(gate_sigmas)
        m = prep.m
        z_shape, R_shape = prep.z_shape, prep.R_shape

        def update(z: np.ndarray, R: np.ndarray) -> tuple[int, float]:
            if (z.shape != z_shape or R.shape != R_shape or z.dtype != np.float64 or R.dtype != np.float64
                    or not (z.flags.c_contiguous and R.flags.c_contiguous)):
                raise ValueError(f"z must be C-contiguous float64 {z_shape} and R {R_shape}")
            kernel(X, P, z.reshape(1, m), _NO_ZHAT, H, R.reshape(1, m, m), mask, gate_sq, *tail)
            return status.item(0), d2.item(0)

        return update

    def update(self, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               mask: np.ndarray | None = None, gate_sigmas: float = math.inf) -> UpdateResult:
        """Fuse measurement z (m,) with covariance R (m, m); mask (m,) selects components.

        gate_sigmas rejects the update when the innovation's Mahalanobis distance exceeds
        it (math.inf: no gate). Bad values (non-finite, bad R) do not raise: the update is
        skipped and ``UpdateResult.reason`` says why; wrong shapes raise ValueError.
        """
        prep = self._prepared.get(id(model))
        if prep is None or prep.model is not model:
            prep = self._prepare(model)
        z = np.ascontiguousarray(z, dtype=float)
        R = np.ascontiguousarray(R, dtype=float)
        if z.shape != prep.z_shape or R.shape != prep.R_shape:
            raise ValueError(f"z must be {prep.z_shape} and R {prep.R_shape}, got {z.shape} and {R.shape}")
        mask = prep.all_components if mask is None else self._mask(prep, mask)
        gate_sq = math.inf if gate_sigmas is math.inf else gate_squared(gate_sigmas)
        if prep.linear:
            Zhat = _NO_ZHAT
            H = self._constant_jacobian(prep)
        else:
            Zhat, H = self._predicted_measurement(prep)
        prep.kernel(self._X, self._P, z[None], Zhat, H, R[None], mask, gate_sq, *prep.tail)
        d2 = self._d2.item(0)
        return _new_result(UpdateResult, (self._status.item(0), math.sqrt(d2) if d2 >= 0.0 else math.nan))
