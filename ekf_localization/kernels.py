"""Compiled covariance kernels shared by the single-trial and batched EKF.

Every kernel works on a batch: states ``X`` shaped (N, n), covariances ``P`` shaped
(N, n, n). A single filter is the case N = 1. The kernels are plain loops compiled by
numba (small fixed-size matrices: a generic BLAS call costs more in overhead than the
arithmetic) and allocate nothing: scratch space comes from a caller-owned ``work``
array (see :func:`predict_work_size`, :func:`update_work_size`). With no numba the
same code runs as plain Python (slow but correct).

Process models may provide their own fused predict kernel built from
:func:`commit_prediction` (f, F and F P Fᵀ + Q in one compiled call, no allocation).
"""

from __future__ import annotations

import functools
import hashlib
import math
from pathlib import Path

import numpy as np

try:  # pragma: no cover - exercised implicitly
    from numba import njit
except ImportError:  # pragma: no cover - numba is a pinned dependency

    def njit(*args, **kwargs):  # type: ignore[no-redef]
        if args and callable(args[0]):
            return args[0]
        return lambda f: f


class FastCall:
    """Call a compiled kernel while skipping numba's per-call type dispatch.

    After the first (dispatched) call, later calls go straight to the compiled entry
    point of the signature that call used. Only valid for a call site that always passes
    the same argument types: C-contiguous float64/bool/int64 arrays of fixed ndim, Python
    floats and bools. Each filter instance owns its own FastCall objects.
    """

    __slots__ = ("_dispatcher", "_entry")

    def __init__(self, dispatcher) -> None:
        self._dispatcher = dispatcher
        self._entry = None

    def __call__(self, *args):
        entry = self._entry
        if entry is not None:
            return entry(*args)
        out = self._dispatcher(*args)
        overloads = getattr(self._dispatcher, "overloads", None)
        if overloads is not None:
            sig = tuple(self._dispatcher.typeof_pyval(a) for a in args)
            cres = overloads.get(sig)
            if cres is not None:
                self._entry = cres.entry_point
        return out


def compiled_entry(dispatcher, *example_args):
    """The compiled entry point of a kernel for the argument types of ``example_args``.

    Compiles (or loads from numba's cache) that one signature now and returns a callable
    that skips numba's per-call type dispatch. The entry point checks dtypes but not ndim
    or memory layout: every later call must pass C-contiguous arrays of the same dtype
    and ndim as the examples (readonly or not does not matter). Without numba the plain
    function is returned.
    """
    compile_signature = getattr(dispatcher, "compile", None)
    if compile_signature is None:  # pragma: no cover - pure-Python fallback
        return dispatcher
    sig = tuple(dispatcher.typeof_pyval(a) for a in example_args)
    compile_signature(sig)
    return dispatcher.overloads[sig].entry_point


# Update status codes (one per trial).
STATUS_OK = 0
STATUS_SKIPPED = 1  # no component selected by the mask
STATUS_GATED = 2  # Mahalanobis distance above the gate
STATUS_NONFINITE = 3  # z, zhat, H or R not finite in a selected component, or a non-finite result
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

PI = math.pi
TWO_PI = 2.0 * math.pi



def predict_work_size(n: int) -> int:
    """Length of the float64 scratch array the predict kernels need for an n-state model."""
    return 4 * n * n + n


def update_work_size(n: int, m: int) -> int:
    """Length of the float64 scratch array an update kernel needs (n states, m components)."""
    return 3 * m + 4 * m * n + 2 * m * m + 2 * n * n + n


@njit(cache=True, inline="always")
def wrap(a: float) -> float:
    """Wrap an angle to (-pi, pi] (same result as :func:`angles.wrap_angle`)."""
    w = (a + PI) % TWO_PI  # [0, 2π], exact (fmod-based, as in Python)
    if w <= 0.0:
        w += TWO_PI
    return w - PI


_wrap = wrap  # backwards-compatible name


@functools.cache
def _cholesky_fixed(k: int):
    """Compiled ``cholesky(A) -> bool`` for (k, k) matrices, k known at compile time.

    Writes the lower Cholesky factor of A into its lower triangle (only the lower triangle
    is read). False if A is not positive definite or not finite.
    """

    @njit(cache=True, error_model="numpy")
    def cholesky(A):
        for j in range(k):
            s = A[j, j]
            for p in range(j):
                s -= A[j, p] * A[j, p]
            if not (s > 0.0) or not math.isfinite(s):
                return False
            d = math.sqrt(s)
            A[j, j] = d
            inv = 1.0 / d
            for i in range(j + 1, k):
                t = A[i, j]
                for p in range(j):
                    t -= A[i, p] * A[j, p]
                A[i, j] = t * inv
        return True

    return cholesky


def is_positive_definite(P: np.ndarray) -> bool:
    """True when the symmetric matrix P (its lower triangle) is finite and positive definite."""
    W = np.array(P, dtype=float, order="C")
    if W.ndim != 2 or W.shape[0] != W.shape[1]:
        raise ValueError(f"expected a square matrix, got shape {W.shape}")
    return bool(_cholesky_fixed(W.shape[0])(W))


@functools.cache
def spd_projector(n: int):
    """Compiled ``make_spd(P, min_variance, W) -> bool`` for (n, n) matrices.

    Symmetrises P in place and, if it is not positive definite, lifts its diagonal by
    ``min_variance``, then tenfold more per try, until it is. False (P unusable) if P is
    not finite or 40 tries fail. W (n, n) is scratch.
    """
    cholesky = _cholesky_fixed(n)

    @njit(cache=True, error_model="numpy")
    def is_pd(P, W):
        for i in range(n):
            for j in range(i + 1):
                W[i, j] = P[i, j]
        return cholesky(W)

    @njit(cache=True, error_model="numpy")
    def make_spd(P, min_variance, W):
        for i in range(n):
            for j in range(i + 1, n):
                v = 0.5 * (P[i, j] + P[j, i])
                P[i, j] = v
                P[j, i] = v
        if is_pd(P, W):
            return True
        for i in range(n):
            for j in range(n):
                if not math.isfinite(P[i, j]):
                    return False
        lift = min_variance
        for _ in range(40):
            for i in range(n):
                P[i, i] += lift
            if is_pd(P, W):
                return True
            lift *= 10.0
        return False

    return make_spd


@functools.cache
def prediction_committer(n: int):
    """Compiled ``commit(x, P, xn, F, Q, x_is_angle, min_variance, work) -> bool`` for n states.

    One trial: x <- xn (angles wrapped), P <- F P Fᵀ + (Q + Qᵀ)/2 made symmetric PD, in
    place. Returns False, leaving x and P untouched, if xn or the new P is not finite.
    ``work`` holds at least 3 n² floats. n is a compile-time constant (loops unrolled).
    """
    make_spd = spd_projector(n)

    @njit(cache=True, error_model="numpy")
    def commit(x, P, xn, F, Q, x_is_angle, min_variance, work):
        nn = n * n
        FP = work[0:nn].reshape((n, n))
        Pn = work[nn:2 * nn].reshape((n, n))
        W = work[2 * nn:3 * nn].reshape((n, n))
        for i in range(n):
            if not math.isfinite(xn[i]):
                return False
        for i in range(n):  # FP = F P, skipping the (many) zeros of F
            for j in range(n):
                FP[i, j] = 0.0
            for k in range(n):
                f = F[i, k]
                if f != 0.0:
                    for j in range(n):
                        FP[i, j] += f * P[k, j]
        for i in range(n):  # Pn = FP Fᵀ + (Q + Qᵀ)/2 (eq. 9), upper triangle mirrored
            for j in range(i, n):
                s = 0.5 * (Q[i, j] + Q[j, i])
                for k in range(n):
                    s += FP[i, k] * F[j, k]
                Pn[i, j] = s
                Pn[j, i] = s
        if not make_spd(Pn, min_variance, W):
            return False
        for i in range(n):
            v = xn[i]
            if x_is_angle[i]:
                v = wrap(v)
            x[i] = v
            for j in range(n):
                P[i, j] = Pn[i, j]
        return True

    return commit


def source_stamp(*paths: str) -> str:
    """Hash of this module's source and the given files: a closure constant that makes
    numba's on-disk cache miss when any of them changes (numba only watches the file that
    defines a function, not the compiled functions it calls from other modules)."""
    h = hashlib.sha256(Path(__file__).read_bytes())
    for p in paths:
        h.update(Path(p).read_bytes())
    return h.hexdigest()


@functools.cache
def fused_predict_kernel(n: int, row, stamp: str):
    """Compiled predict for a process model that supplies a one-trial numba function
    ``row(x, u, has_control, dt, params, xn, F)`` writing f(x, u) into xn (n,) and its
    Jacobian into F (n, n, zeroed before each call).

    Returns ``predict(X, P, U, has_control, dt, Q, params, x_is_angle, min_variance, ok,
    work)``: f, F and F P Fᵀ + Q for every trial in one compiled call with no allocation
    (the ``predict_kernel`` protocol of :mod:`ekf_localization.ekf`). ``stamp`` must be
    :func:`source_stamp` of the module defining ``row``.
    """
    commit = prediction_committer(n)
    nn = n * n

    @njit(cache=True, error_model="numpy")
    def predict(X, P, U, has_control, dt, Q, params, x_is_angle, min_variance, ok, work):
        if len(stamp) == 0:  # never true: references the stamp so it keys numba's cache
            return
        nq = Q.shape[0]
        xn = work[0:n]
        F = work[n:n + nn].reshape((n, n))
        scratch = work[n + nn:]
        for b in range(X.shape[0]):
            x = X[b]
            F[:, :] = 0.0
            row(x, U[b], has_control, dt, params, xn, F)
            ok[b] = commit(x, P[b], xn, F, Q[b if nq > 1 else 0], x_is_angle, min_variance, scratch)

    return predict


@functools.cache
def predict_kernel(n: int):
    """Compiled ``predict(X, P, Xn, F, Q, x_is_angle, min_variance, ok, work)`` for n states.

    Commits a prediction computed outside: X[b] = Xn[b], P[b] = F[b] P[b] F[b]ᵀ + Q[b], in
    place. F and Q may have a leading dimension of 1 (shared by all trials). A trial whose
    predicted state or covariance is not finite keeps its old X and P (ok[b] = False).
    """
    commit = prediction_committer(n)

    @njit(cache=True, error_model="numpy")
    def predict(X, P, Xn, F, Q, x_is_angle, min_variance, ok, work):
        N = X.shape[0]
        nf = F.shape[0]
        nq = Q.shape[0]
        for b in range(N):
            ok[b] = commit(X[b], P[b], Xn[b], F[b if nf > 1 else 0], Q[b if nq > 1 else 0],
                           x_is_angle, min_variance, work)

    return predict


@functools.cache
def _update_parts(n: int, m: int):
    """(scratch-view maker, one-trial update) for n states and m components."""
    nn = n * n
    mn = m * n
    mm = m * m
    make_spd = spd_projector(n)
    cholesky = _cholesky_fixed(m)

    @njit(cache=True, error_model="numpy")
    def scratch(work):
        """Views into ``work``: zh, y, w (m), Hs, HP, Kt (m, n), M (n, m), S, Rs (m, m),
        T, Pn (n, n), xn (n)."""
        o = 0
        zh = work[o:o + m]
        o += m
        y = work[o:o + m]
        o += m
        w = work[o:o + m]
        o += m
        Hs = work[o:o + mn].reshape((m, n))  # selected rows of H (others 0)
        o += mn
        HP = work[o:o + mn].reshape((m, n))  # Hs P = (P Hsᵀ)ᵀ
        o += mn
        Kt = work[o:o + mn].reshape((m, n))  # Kᵀ = S⁻¹ Hs P
        o += mn
        M = work[o:o + mn].reshape((n, m))  # K R - A P Hᵀ
        o += mn
        S = work[o:o + mm].reshape((m, m))
        o += mm
        Rs = work[o:o + mm].reshape((m, m))
        o += mm
        T = work[o:o + nn].reshape((n, n))  # A P with A = I - K H
        o += nn
        Pn = work[o:o + nn].reshape((n, n))
        o += nn
        xn = work[o:o + n]
        return zh, y, w, Hs, HP, Kt, M, S, Rs, T, Pn, xn

    @njit(cache=True, error_model="numpy", inline="always")
    def trial(x, P, z, zhat, linear, H, R, mask, z_is_angle, x_is_angle, gate_sq, min_variance, ws):
        """Update one trial in place; returns (status, squared Mahalanobis distance)."""
        zh, y, w, Hs, HP, Kt, M, S, Rs, T, Pn, xn = ws
        k = 0
        for a in range(m):
            if mask[a]:
                k += 1
        if k == 0:
            return STATUS_SKIPPED, math.nan
        # gather the selected components; chk stays 0 only if they are all finite
        chk = 0.0
        diagonal = True
        asymmetric = False
        for a in range(m):
            sel = mask[a]
            for c in range(n):
                h = H[a, c] if sel else 0.0
                Hs[a, c] = h
                chk += h - h
            for c in range(m):
                if sel and mask[c]:
                    r1 = R[a, c]
                    r2 = R[c, a]
                    r = 0.5 * (r1 + r2)
                    chk += (r1 - r1) + (r2 - r2)
                    if abs(r1 - r2) > 1e-9 * (abs(r1) + abs(r2)) + 1e-300:
                        asymmetric = True
                    if a != c and r != 0.0:
                        diagonal = False
                else:
                    r = 1.0 if a == c else 0.0
                Rs[a, c] = r
        for a in range(m):
            if mask[a]:
                if linear:
                    s = 0.0
                    for c in range(n):
                        s += Hs[a, c] * x[c]
                    zh[a] = s
                else:
                    zh[a] = zhat[a]
                v = z[a] - zh[a]
                chk += v - v
                if z_is_angle[a]:
                    v = wrap(v)
                y[a] = v
            else:
                y[a] = 0.0
        if chk != 0.0:
            return STATUS_NONFINITE, math.nan
        # R (selected part) must be symmetric positive semi-definite
        bad_r = asymmetric
        for a in range(m):
            if Rs[a, a] < 0.0:
                bad_r = True
        if not bad_r and not diagonal:
            big = 0.0
            for a in range(m):
                big = max(big, Rs[a, a])
            for a in range(m):
                for c in range(a + 1):
                    S[a, c] = Rs[a, c]
                S[a, a] += 1e-12 * big + 1e-300
            bad_r = not cholesky(S)
        if bad_r:
            return STATUS_BAD_R, math.nan
        # HP = Hs P (skipping zeros of H); S = HP Hsᵀ + R (lower triangle); S = L Lᵀ
        for a in range(m):
            for j in range(n):
                HP[a, j] = 0.0
            for c in range(n):
                h = Hs[a, c]
                if h != 0.0:
                    for j in range(n):
                        HP[a, j] += h * P[c, j]
        for a in range(m):
            for c in range(a + 1):
                s = Rs[a, c]
                for j in range(n):
                    h = Hs[c, j]
                    if h != 0.0:
                        s += HP[a, j] * h
                S[a, c] = s
        if not cholesky(S):
            return STATUS_S_NOT_PD, math.nan
        # w = L⁻¹ y, d² = |w|² (squared Mahalanobis distance of the innovation)
        d2 = 0.0
        for a in range(m):
            t = y[a]
            for c in range(a):
                t -= S[a, c] * w[c]
            w[a] = t / S[a, a]
            d2 += w[a] * w[a]
        if not (d2 <= gate_sq):
            return STATUS_GATED, d2
        # Kᵀ = S⁻¹ HP = L⁻ᵀ L⁻¹ HP (seed 000 eq. 10), two triangular solves on rows
        for a in range(m):
            for j in range(n):
                Kt[a, j] = HP[a, j]
            for c in range(a):
                s = S[a, c]
                for j in range(n):
                    Kt[a, j] -= s * Kt[c, j]
            inv = 1.0 / S[a, a]
            for j in range(n):
                Kt[a, j] *= inv
        for a in range(m - 1, -1, -1):
            for c in range(a + 1, m):
                s = S[c, a]
                for j in range(n):
                    Kt[a, j] -= s * Kt[c, j]
            inv = 1.0 / S[a, a]
            for j in range(n):
                Kt[a, j] *= inv
        # Joseph form P' = A P Aᵀ + K R Kᵀ with A = I - K H, evaluated as
        # T = A P = P - K HP ; P' = T + (K R - T Hᵀ) Kᵀ        (n² m work, not n³)
        for i in range(n):
            for j in range(n):
                s = P[i, j]
                for a in range(m):
                    s -= Kt[a, i] * HP[a, j]
                T[i, j] = s
        for i in range(n):
            for a in range(m):
                if diagonal:
                    s = Kt[a, i] * Rs[a, a]
                else:
                    s = 0.0
                    for c in range(m):
                        s += Kt[c, i] * Rs[c, a]
                for j in range(n):
                    h = Hs[a, j]
                    if h != 0.0:
                        s -= T[i, j] * h
                M[i, a] = s
        chk = 0.0
        for i in range(n):  # upper triangle, mirrored
            for j in range(i, n):
                s = T[i, j]
                for a in range(m):
                    s += M[i, a] * Kt[a, j]
                Pn[i, j] = s
                Pn[j, i] = s
                chk += s - s
        # x' = x + K y (eq. 11)
        for i in range(n):
            s = x[i]
            for a in range(m):
                s += Kt[a, i] * y[a]
            xn[i] = s
            chk += s - s
        if chk != 0.0:
            return STATUS_NONFINITE, d2
        if not make_spd(Pn, min_variance, T):
            return STATUS_P_NOT_PD, d2
        for i in range(n):
            v = xn[i]
            if x_is_angle[i]:
                v = wrap(v)
            x[i] = v
            for j in range(n):
                P[i, j] = Pn[i, j]
        return STATUS_OK, d2

    return scratch, trial


@functools.cache
def update_kernel(n: int, m: int):
    """Compiled EKF update of N trials, n states and m measurement components (compile-time).

    ``update(X, P, Z, Zhat, H, R, mask, gate_sq, z_is_angle, x_is_angle, min_variance,
    status, d2, work)`` updates every trial in place with a Joseph-form covariance.
    X (N, n), P (N, n, n), Z and Zhat (N, m), H (N, m, n), R (N, m, m), mask (N, m) bool
    selects the components to fuse (a partial update); H, R and mask may have a leading
    dimension of 1 (shared by all trials). A Zhat with no rows means the model is linear:
    Zhat = H X is computed here. Residuals with z_is_angle and states with x_is_angle are
    wrapped to (-pi, pi]. A trial whose squared Mahalanobis distance exceeds gate_sq is
    left untouched (status GATED); d2[b] gets that distance (nan when not reached).
    ``work`` holds :func:`update_work_size` floats.

    A component left out by the mask is neutralised (its row of H, its residual and its
    cross-covariances set to 0, its variance to 1), which leaves the update exactly equal
    to one with the reduced measurement while every loop keeps its compile-time length.
    """
    scratch, trial = _update_parts(n, m)

    @njit(cache=True, error_model="numpy")
    def update(X, P, Z, Zhat, H, R, mask, gate_sq, z_is_angle, x_is_angle, min_variance,
               status, d2_out, work):
        ws = scratch(work)
        nh = H.shape[0]
        nr = R.shape[0]
        nm = mask.shape[0]
        linear = Zhat.shape[0] == 0
        for b in range(X.shape[0]):
            st, d2 = trial(X[b], P[b], Z[b], Z[b] if linear else Zhat[b], linear, H[b if nh > 1 else 0],
                           R[b if nr > 1 else 0], mask[b if nm > 1 else 0], z_is_angle, x_is_angle,
                           gate_sq, min_variance, ws)
            status[b] = st
            d2_out[b] = d2

    return update


@functools.cache
def update_one_kernel(n: int, m: int):
    """The same update for one trial with flat shapes, returning (status, Mahalanobis distance).

    ``update_one(x (n,), P (n, n), z (m,), zhat (m,) or (0,) if linear, H (m, n), R (m, m),
    mask (m,), gate_sq, z_is_angle, x_is_angle, min_variance, work)``. Runs exactly the
    per-trial code of :func:`update_kernel`, so results are bitwise identical.
    """
    scratch, trial = _update_parts(n, m)

    @njit(cache=True, error_model="numpy")
    def update_one(x, P, z, zhat, H, R, mask, gate_sq, z_is_angle, x_is_angle, min_variance, work):
        linear = zhat.shape[0] == 0
        status, d2 = trial(x, P, z, z if linear else zhat, linear, H, R, mask, z_is_angle, x_is_angle,
                           gate_sq, min_variance, scratch(work))
        return status, math.sqrt(d2)  # nan stays nan

    return update_one
