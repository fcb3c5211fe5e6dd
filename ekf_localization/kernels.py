"""Compiled covariance kernels shared by the single-trial and batched EKF.

Every kernel works on a batch: states ``X`` shaped (N, n), covariances ``P`` shaped
(N, n, n). A single filter is the case N = 1. The kernels are plain loops compiled by
numba (small fixed-size matrices: a generic BLAS call costs more in overhead than the
arithmetic), with a pure-Python fallback when numba is not importable.
"""

from __future__ import annotations

import math

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
    the same argument types: C-contiguous float64/bool/int64 arrays of fixed ndim, and
    Python floats. Each filter instance owns its own FastCall objects.
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


# Update status codes (one per trial).
STATUS_OK = 0
STATUS_SKIPPED = 1  # no component selected by the mask
STATUS_GATED = 2  # Mahalanobis distance above the gate
STATUS_NONFINITE = 3  # z, zhat, H or R not finite in a selected component
STATUS_BAD_R = 4  # R not symmetric or has a negative variance
STATUS_S_NOT_PD = 5  # innovation covariance not positive definite
STATUS_P_NOT_PD = 6  # update would make P lose positive definiteness: reverted

STATUS_TEXT = {
    STATUS_OK: "ok",
    STATUS_SKIPPED: "no valid component",
    STATUS_GATED: "rejected by Mahalanobis gate",
    STATUS_NONFINITE: "non-finite measurement, prediction, Jacobian or covariance",
    STATUS_BAD_R: "measurement covariance not symmetric or has a negative variance",
    STATUS_S_NOT_PD: "innovation covariance not positive definite",
    STATUS_P_NOT_PD: "update would break positive definiteness of P (reverted)",
}

PI = math.pi
TWO_PI = 2.0 * math.pi


@njit(cache=True, inline="always")
def _wrap(a: float) -> float:
    t = a + PI
    w = t - TWO_PI * math.floor(t / TWO_PI)  # [0, 2π)
    if w <= 0.0:
        w += TWO_PI
    return w - PI


@njit(cache=True)
def cholesky_inplace(A: np.ndarray, k: int) -> bool:
    """Lower Cholesky factor of A[:k, :k] written into its lower triangle. False if not PD."""
    for j in range(k):
        s = A[j, j]
        for p in range(j):
            s -= A[j, p] * A[j, p]
        if not (s > 0.0) or not math.isfinite(s):
            return False
        d = math.sqrt(s)
        A[j, j] = d
        for i in range(j + 1, k):
            t = A[i, j]
            for p in range(j):
                t -= A[i, p] * A[j, p]
            A[i, j] = t / d
    return True


@njit(cache=True)
def is_positive_definite(P: np.ndarray) -> bool:
    """True when the symmetric matrix P is finite and positive definite."""
    n = P.shape[0]
    W = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            W[i, j] = P[i, j]
    return cholesky_inplace(W, n)


@njit(cache=True)
def _make_spd(P: np.ndarray, min_variance: float) -> bool:
    """Symmetrise P in place and, if needed, lift its diagonal until it is PD."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v
    if is_positive_definite(P):
        return True
    lift = min_variance
    for _ in range(40):
        for i in range(n):
            P[i, i] += lift
        if is_positive_definite(P):
            return True
        lift *= 10.0
    return False


@njit(cache=True)
def predict(X: np.ndarray, P: np.ndarray, Xn: np.ndarray, F: np.ndarray, Q: np.ndarray,
            x_is_angle: np.ndarray, min_variance: float, ok: np.ndarray) -> None:
    """Commit a prediction: X[b] = Xn[b], P[b] = F[b] P[b] F[b]^T + Q[b], in place.

    Q may have a leading dimension of 1 (shared by all trials). Angles in the state are
    wrapped, P is kept symmetric positive definite. A trial whose
    predicted state or covariance is not finite keeps its old X and P (ok[b] = False).
    """
    N, n, _ = P.shape
    T = np.empty((n, n))
    Pn = np.empty((n, n))
    nq = Q.shape[0]
    for b in range(N):
        qb = b if nq > 1 else 0
        good = True
        for i in range(n):
            if not math.isfinite(Xn[b, i]):
                good = False
        for i in range(n):
            for j in range(n):
                s = 0.0
                for k in range(n):
                    s += F[b, i, k] * P[b, k, j]
                T[i, j] = s
        for i in range(n):
            for j in range(i, n):
                s = 0.5 * (Q[qb, i, j] + Q[qb, j, i])
                for k in range(n):
                    s += T[i, k] * F[b, j, k]
                if not math.isfinite(s):
                    good = False
                Pn[i, j] = s
                Pn[j, i] = s
        if good:
            good = _make_spd(Pn, min_variance)
        ok[b] = good
        if not good:
            continue
        for i in range(n):
            v = Xn[b, i]
            if x_is_angle[i]:
                v = _wrap(v)
            X[b, i] = v
            for j in range(n):
                P[b, i, j] = Pn[i, j]


@njit(cache=True)
def update(X: np.ndarray, P: np.ndarray, Z: np.ndarray, Zhat: np.ndarray, H: np.ndarray,
           R: np.ndarray, mask: np.ndarray, z_is_angle: np.ndarray, x_is_angle: np.ndarray,
           gate_sq: float, status: np.ndarray, d2_out: np.ndarray) -> None:
    """EKF update of every trial, in place, with Joseph-form covariance.

    X (N, n), P (N, n, n), Z and Zhat (N, m), H (N, m, n), R (N, m, m), mask (N, m) bool
    selects the components to fuse (a partial update), z_is_angle (m,) marks residuals
    to wrap, x_is_angle (n,) marks states to wrap. A trial whose squared Mahalanobis
    distance exceeds gate_sq is left untouched (status GATED). d2_out gets that distance.
    H, R and mask may have a leading dimension of 1 (shared by all trials). A Zhat with no
    rows means the model is linear: Zhat = H X is computed here.
    """
    N, n = X.shape
    m = Z.shape[1]
    idx = np.empty(m, np.int64)
    nh = H.shape[0]
    nr = R.shape[0]
    nm = mask.shape[0]
    linear = Zhat.shape[0] == 0
    zh = np.empty(m)
    for b in range(N):
        hb = b if nh > 1 else 0
        rb = b if nr > 1 else 0
        mb = b if nm > 1 else 0
        for j in range(m):
            if linear:
                s = 0.0
                for c in range(n):
                    s += H[hb, j, c] * X[b, c]
                zh[j] = s
            else:
                zh[j] = Zhat[b, j]
        d2_out[b] = math.nan
        k = 0
        for j in range(m):
            if mask[mb, j]:
                idx[k] = j
                k += 1
        if k == 0:
            status[b] = STATUS_SKIPPED
            continue
        ok = True
        bad_r = False
        for a in range(k):
            ja = idx[a]
            if not (math.isfinite(Z[b, ja]) and math.isfinite(zh[ja])):
                ok = False
            for c in range(n):
                if not math.isfinite(H[hb, ja, c]):
                    ok = False
            for c in range(k):
                jc = idx[c]
                r = R[rb, ja, jc]
                if not math.isfinite(r):
                    ok = False
                elif abs(r - R[rb, jc, ja]) > 1e-9 * (abs(r) + abs(R[rb, jc, ja])) + 1e-300:
                    bad_r = True
            if R[rb, ja, ja] < 0.0:
                bad_r = True
        if not ok:
            status[b] = STATUS_NONFINITE
            continue
        if bad_r:
            status[b] = STATUS_BAD_R
            continue
        # residual, wrapped where it is an angle
        y = np.empty(k)
        for a in range(k):
            ja = idx[a]
            v = Z[b, ja] - zh[ja]
            if z_is_angle[ja]:
                v = _wrap(v)
            y[a] = v
        Pb = P[b]
        # PHt = P H^T  (n, k)
        PHt = np.empty((n, k))
        for i in range(n):
            for a in range(k):
                ja = idx[a]
                s = 0.0
                for c in range(n):
                    s += Pb[i, c] * H[hb, ja, c]
                PHt[i, a] = s
        # S = H P H^T + R  (k, k), then its Cholesky factor in place
        S = np.empty((k, k))
        for a in range(k):
            ja = idx[a]
            for c in range(a, k):
                jc = idx[c]
                s = 0.5 * (R[rb, ja, jc] + R[rb, jc, ja])
                for i in range(n):
                    s += H[hb, ja, i] * PHt[i, c]
                S[a, c] = s
                S[c, a] = s
        if not cholesky_inplace(S, k):
            status[b] = STATUS_S_NOT_PD
            continue
        # w = L^-1 y ; d2 = |w|^2
        w = np.empty(k)
        for a in range(k):
            t = y[a]
            for c in range(a):
                t -= S[a, c] * w[c]
            w[a] = t / S[a, a]
        d2 = 0.0
        for a in range(k):
            d2 += w[a] * w[a]
        d2_out[b] = d2
        if d2 > gate_sq:
            status[b] = STATUS_GATED
            continue
        # K = PHt S^-1 = PHt L^-T L^-1 : solve row by row
        K = np.empty((n, k))
        for i in range(n):
            # forward: L u = PHt[i]^T
            for a in range(k):
                t = PHt[i, a]
                for c in range(a):
                    t -= S[a, c] * K[i, c]
                K[i, a] = t / S[a, a]
            # backward: L^T v = u
            for a in range(k - 1, -1, -1):
                t = K[i, a]
                for c in range(a + 1, k):
                    t -= S[c, a] * K[i, c]
                K[i, a] = t / S[a, a]
        # Joseph form: P' = A P A^T + K R K^T with A = I - K H
        A = np.empty((n, n))
        for i in range(n):
            for c in range(n):
                s = 1.0 if i == c else 0.0
                for a in range(k):
                    s -= K[i, a] * H[hb, idx[a], c]
                A[i, c] = s
        T = np.empty((n, n))
        for i in range(n):
            for c in range(n):
                s = 0.0
                for q in range(n):
                    s += A[i, q] * Pb[q, c]
                T[i, c] = s
        KR = np.empty((n, k))
        for i in range(n):
            for a in range(k):
                s = 0.0
                for c in range(k):
                    s += K[i, c] * R[rb, idx[c], idx[a]]
                KR[i, a] = s
        Pn = np.empty((n, n))
        for i in range(n):
            for c in range(i, n):
                s = 0.0
                for q in range(n):
                    s += T[i, q] * A[c, q]
                for a in range(k):
                    s += KR[i, a] * K[c, a]
                Pn[i, c] = s
                Pn[c, i] = s
        if not is_positive_definite(Pn):
            status[b] = STATUS_P_NOT_PD
            continue
        for i in range(n):
            s = 0.0
            for a in range(k):
                s += K[i, a] * y[a]
            v = X[b, i] + s
            if x_is_angle[i]:
                v = _wrap(v)
            X[b, i] = v
        for i in range(n):
            for c in range(n):
                Pb[i, c] = Pn[i, c]
        status[b] = STATUS_OK
