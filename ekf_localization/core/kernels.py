"""Compiled covariance kernels shared by the single-trial and batched EKF.

Every kernel works on a batch: states ``X`` shaped (N, n), covariances ``P`` shaped
(N, n, n). A single filter is the case N = 1. The kernels are plain loops compiled by
numba (small fixed-size matrices: a generic BLAS call costs more in overhead than the
arithmetic), specialised for the state and measurement sizes (``predict_kernel(n)``,
``update_kernel(n, m)``: every loop has a compile-time length), and allocate nothing:
scratch space comes from a caller-owned array (:func:`predict_work_shape`,
:func:`update_work_shape`). Call them through :func:`compiled_entry` to skip numba's
per-call dispatch. With no numba the same code runs as plain Python (slow but correct).

Process models may provide their own fused predict kernel built on
:func:`commit_prediction` (f, F and F P Fᵀ + Q in one compiled call, no allocation).
Compiled code is cached on disk; the first use of each (n, m) compiles for a few seconds.
"""

from __future__ import annotations

import functools
import hashlib
import math
from pathlib import Path

import numpy as np

from ekf_localization.core import angles, hypot, kernel_cache, linalg
from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.linalg import nearly_symmetric_pair

kernel_cache.configure()  # before numba reads its configuration: a read-only install starts warm
try:  # pragma: no cover - exercised implicitly
    from llvmlite import ir
    from numba import njit, types
    from numba.core.errors import TypingError
    from numba.extending import intrinsic, register_jitable

    # what a kernel called with arguments it cannot be typed for raises (before it runs)
    ARGUMENT_TYPE_ERRORS: tuple[type[Exception], ...] = (TypeError, TypingError)

    @intrinsic
    def fma(typingctx, a, b, c):
        """a·b + c rounded once (LLVM's fma; no Python equivalent before 3.13)."""
        sig = types.float64(types.float64, types.float64, types.float64)

        def codegen(context, builder, signature, args):
            d = ir.DoubleType()
            fn = builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d]))
            return builder.call(fn, args)

        return sig, codegen
except ImportError:  # pragma: no cover - numba is a pinned dependency

    def njit(*args, **kwargs):  # type: ignore[no-redef]
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

    ARGUMENT_TYPE_ERRORS = (TypeError,)

    def register_jitable(fn):  # type: ignore[no-redef]
        return fn

    def fma(a: float, b: float, c: float) -> float:  # type: ignore[misc]
        """a·b + c rounded once (exact rational arithmetic, then one rounding)."""
        from fractions import Fraction

        return float(Fraction(a) * Fraction(b) + Fraction(c))


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

def predict_work_shape(n: int) -> tuple[int, int]:
    """Shape of the float64 scratch array of the predict kernels (n states): rows [0, 3n) are
    :func:`commit_prediction`'s, then f(x) (1 row), F (n rows) and n rows for the model."""
    return 5 * n + 1, n


def update_work_shape(n: int, m: int) -> tuple[int, int]:
    """Shape of the float64 scratch array of the update kernels (n states, m components)."""
    return 4 + 5 * m + 3 * n, max(n, m)


# One angle wrap and one symmetry tolerance, compiled from the same Python functions the
# rest of the package calls (see also source_stamp).
wrap = njit(cache=True, inline="always")(wrap_angle)
nearly_symmetric = njit(cache=True, inline="always")(nearly_symmetric_pair)
# the quaternion conversions of the compiled message readers and writers (ros/cdr.py); the
# helpers they call are compiled where called
for _helper in (angles.wrap_angle, angles._scaled_quaternion, angles.quaternion_to_yaw):
    register_jitable(_helper)
quaternion_rpy = njit(cache=True, inline="always")(angles.quaternion_to_rpy)
register_jitable(hypot._exact_square)
py_hypot = njit(cache=True, inline="always")(hypot.python_hypot)  # math.hypot's last bit
rpy_quaternion = njit(cache=True, inline="always")(angles.rpy_to_quaternion)


@njit(cache=True, inline="always")
def dot3_fma(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> float:
    """a·b of two 3-vectors as this machine's BLAS forms a matrix product's entry: products
    added in order into 0 by fused multiply-adds (numpy's matmul of (N >= 2, 3) by (3, 3)
    and of 3×3 stacks, bit for bit here: test/test_dead_wheel_sampler.py)."""
    return fma(a2, b2, fma(a1, b1, fma(a0, b0, 0.0)))

# The helpers below take the matrix sizes as arguments. The kernels are closures over
# those sizes (plain ints, which keeps numba's on-disk cache valid across processes) and
# pass them as constants. The helpers on every step are inlined by numba (inline="always"),
# so their loops have fixed lengths: LLVM alone did not inline the Cholesky test, which then
# cost 2.3x as much (a 6x6 test in a loop over 100 trials: 115 vs 50 ns per trial).


@njit(cache=True, inline="always", error_model="numpy")
def cholesky_rows(A: np.ndarray, r0: int, k: int) -> bool:
    """Lower Cholesky factor of the k×k block of A starting at row r0, column 0, in place
    (only its lower triangle is read). False if it is not positive definite or not finite."""
    for j in range(k):
        s = A[r0 + j, j]
        for p in range(j):
            s -= A[r0 + j, p] * A[r0 + j, p]
        if not (s > 0.0) or not math.isfinite(s):
            return False
        d = math.sqrt(s)
        A[r0 + j, j] = d
        inv = 1.0 / d
        for i in range(j + 1, k):
            t = A[r0 + i, j]
            for p in range(j):
                t -= A[r0 + i, p] * A[r0 + j, p]
            A[r0 + i, j] = t * inv
    return True


# Relative margin of clearly_pd3: its leading minors, scaled by the diagonal, must exceed it.
# Their rounding errors are a few 1e-16 of that scale, so past it cholesky_rows cannot fail.
PD_MARGIN = 1e-6


@njit(cache=True, inline="always", error_model="numpy")
def clearly_pd3(a00: float, a01: float, a02: float, a11: float, a12: float, a22: float) -> bool:
    """True when the symmetric 3×3 matrix is positive definite with a margin (Sylvester's
    minors, each above PD_MARGIN of its scale): :func:`cholesky_rows` would succeed, without
    its square roots and divisions. False says nothing: take cholesky_rows's answer."""
    if not (a00 > 0.0 and a11 > 0.0 and a22 > 0.0):
        return False
    d2 = a00 * a11 - a01 * a01
    if not d2 > PD_MARGIN * a00 * a11:
        return False
    d3 = a22 * d2 - a00 * a12 * a12 - a11 * a02 * a02 + 2.0 * a01 * a02 * a12
    return d3 > PD_MARGIN * d2 * a22


@njit(cache=True, inline="always", error_model="numpy")
def _clearly_pd_rows(A: np.ndarray, ra: int, W: np.ndarray, rw: int, n: int) -> bool:
    """:func:`clearly_pd3`'s test for the symmetric n×n block of A at row ra: an LDLᵀ
    factorisation (one division per pivot, no square roots) whose every pivot exceeds
    PD_MARGIN of its diagonal entry (pivot k is the ratio of leading minors k and k - 1, so
    this is clearly_pd3's criterion). Each pivot's rounding error is a few 1e-16 of that
    entry, so where this says PD the Cholesky test would too. The block of W at rw is
    scratch: W[j, p] = lⱼₚ dₚ below the diagonal, W[j, j] = 1/dⱼ, W[p, j] = lⱼₚ above it."""
    for j in range(n):
        d = A[ra + j, j]
        for p in range(j):
            c = A[ra + j, p]
            for q in range(p):
                c -= W[rw + j, q] * W[rw + q, p]
            W[rw + j, p] = c
            lj = c * W[rw + p, p]
            W[rw + p, j] = lj
            d -= c * lj
        if not d > PD_MARGIN * A[ra + j, j]:
            return False
        W[rw + j, j] = 1.0 / d
    return True


@njit(cache=True, inline="always", error_model="numpy")
def _is_pd_rows(A: np.ndarray, ra: int, W: np.ndarray, rw: int, n: int) -> bool:
    """Cholesky test of the symmetric n×n block of A at row ra, using the block of W at rw."""
    for i in range(n):
        for j in range(i + 1):
            W[rw + i, j] = A[ra + i, j]
    return cholesky_rows(W, rw, n)


@njit(cache=True, inline="always", error_model="numpy")
def _make_spd_rows(A: np.ndarray, ra: int, W: np.ndarray, rw: int, n: int, min_variance: float) -> bool:
    """Symmetrise the n×n block of A at row ra in place and, if it is not positive definite,
    lift its diagonal by ``min_variance``, then tenfold more per try, until it is. False
    (unusable) if it is not finite or 40 tries fail. The block of W at rw is scratch.
    The usual case (already PD) is inlined; the lifting is a call."""
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (A[ra + i, j] + A[ra + j, i])
            A[ra + i, j] = v
            A[ra + j, i] = v
    if _clearly_pd_rows(A, ra, W, rw, n) or _is_pd_rows(A, ra, W, rw, n):
        return True
    return _lift_to_pd_rows(A, ra, W, rw, n, min_variance)


@njit(cache=True, error_model="numpy")
def _lift_to_pd_rows(A: np.ndarray, ra: int, W: np.ndarray, rw: int, n: int, min_variance: float) -> bool:
    """:func:`_make_spd_rows` for a symmetric block that is not PD: the diagonal lifts."""
    for i in range(n):
        for j in range(n):
            if not math.isfinite(A[ra + i, j]):
                return False
    lift = min_variance
    for _ in range(40):
        for i in range(n):
            A[ra + i, i] += lift
        if _is_pd_rows(A, ra, W, rw, n):
            return True
        lift *= 10.0
    return False


@njit(cache=True, inline="always", error_model="numpy")
def commit_prediction(x: np.ndarray, P: np.ndarray, xn: np.ndarray, F: np.ndarray, Q: np.ndarray,
                      x_is_angle: np.ndarray, min_variance: float, ws: np.ndarray, n: int, p: int) -> bool:
    """One trial: x <- xn (angles wrapped), P <- F P Fᵀ + (Q + Qᵀ)/2 (seed 000 eq. 9) made
    symmetric PD, in place. Returns False, leaving x and P untouched, if xn or the new P is
    not finite. ``ws`` is (≥ 3n, ≥ n) scratch; pass n and p as compile-time constants.

    p = n in general. p < n when F's rows [p, n) are 0 (a command sets those states: seed 000
    eq. 25) and Q was accepted by :func:`commanded_tail_is_pd`: the new P is then
    [[F_p P F_pᵀ + Q_pp, 0], [0, Q_vv]], so only its p×p block is computed and Cholesky-tested
    (a block-diagonal matrix's factor is its blocks' factors, the zeros exactly zero, and Q_vv's
    passed), bit for bit the p = n result. A block that fails takes the general lift."""
    rP = n  # rows [0, n): F P ; [n, 2n): new P ; [2n, 3n): Cholesky scratch
    rW = 2 * n
    for i in range(n):
        if not math.isfinite(xn[i]):
            return False
    for i in range(p):  # FP = F P (rows [p, n) are 0), skipping the (many) zeros of F
        for j in range(n):
            ws[i, j] = 0.0
        for k in range(n):
            f = F[i, k]
            if f != 0.0:
                for j in range(n):
                    ws[i, j] += f * P[k, j]
    for i in range(n):  # Pn = FP Fᵀ + (Q + Qᵀ)/2, upper triangle mirrored
        for j in range(i, n):
            s = 0.5 * (Q[i, j] + Q[j, i])
            if j < p:
                for k in range(n):
                    s += ws[i, k] * F[j, k]
            ws[rP + i, j] = s
            ws[rP + j, i] = s
    if not ((p < n and _is_pd_rows(ws, rP, ws, rW, p)) or _make_spd_rows(ws, rP, ws, rW, n, min_variance)):
        return False
    for i in range(n):
        v = xn[i]
        if x_is_angle[i]:
            v = wrap(v)
        x[i] = v
        for j in range(n):
            P[i, j] = ws[rP + i, j]
    return True


@njit(cache=True, inline="always", error_model="numpy")
def commanded_tail_is_pd(Q: np.ndarray, ws: np.ndarray, rw: int, n: int, p: int) -> bool:
    """Whether :func:`commit_prediction` with this p < n applies to (Q + Qᵀ)/2: no terms
    between states [0, p) and [p, n), and its [p, n) block passes the Cholesky test (on the
    rows of ws from rw). Once per kernel call for a Q shared by every trial."""
    for i in range(p):
        for j in range(p, n):
            if 0.5 * (Q[i, j] + Q[j, i]) != 0.0:
                return False
    for i in range(n - p):
        for j in range(i + 1):
            ws[rw + i, j] = 0.5 * (Q[p + i, p + j] + Q[p + j, p + i])
    return cholesky_rows(ws, rw, n - p)


@njit(cache=True, inline="always", error_model="numpy")
def update_one(x: np.ndarray, Pb: np.ndarray, zb: np.ndarray, zhb: np.ndarray, linear: bool, Hb: np.ndarray,
               Rb: np.ndarray, mk: np.ndarray, gate_sq: float, z_is_angle: np.ndarray, x_is_angle: np.ndarray,
               min_variance: float, ws: np.ndarray, n: int, m: int) -> tuple[int, float]:
    """One trial of :func:`update_kernel`, in place: (status, squared Mahalanobis distance).
    ``zhb`` is read only when not ``linear``; pass n and m as compile-time constants."""
    # row blocks of ws; rows 0-3: zh, y (residual), w = L⁻¹ y, x'
    rHs = 4  # m×n: rows of H selected by the mask (others 0)
    rHP = rHs + m  # m×n: Hs P = (P Hsᵀ)ᵀ
    rKt = rHP + m  # m×n: Kᵀ = S⁻¹ Hs P
    rM = rKt + m  # n×m: K R - A P Hsᵀ
    rS = rM + n  # m×m: S = Hs P Hsᵀ + R, then its Cholesky factor
    rRs = rS + m  # m×m: selected block of R (unit diagonal elsewhere)
    rT = rRs + m  # n×n: A P with A = I - K Hs
    rPn = rT + n  # n×n: P'
    k = 0
    for a in range(m):
        if mk[a]:
            k += 1
    if k == 0:
        return STATUS_SKIPPED, math.nan
    # gather the selected components; finite stays True only if all of them are
    finite = True
    for a in range(m):
        if mk[a]:
            for c in range(n):
                h = Hb[a, c]
                ws[rHs + a, c] = h
                finite &= math.isfinite(h)
        else:
            for c in range(n):
                ws[rHs + a, c] = 0.0
    diagonal = True
    asymmetric = False
    for a in range(m):
        for c in range(m):
            ws[rRs + a, c] = 0.0
        if mk[a]:
            r = Rb[a, a]
            finite &= math.isfinite(r)
            ws[rRs + a, a] = r
            for c in range(a + 1, m):
                if mk[c]:
                    r1 = Rb[a, c]
                    r2 = Rb[c, a]
                    finite &= math.isfinite(r1) & math.isfinite(r2)
                    if not nearly_symmetric(r1, r2):
                        asymmetric = True
                    if r1 != 0.0 or r2 != 0.0:
                        diagonal = False
        else:
            ws[rRs + a, a] = 1.0
    if not diagonal:
        for a in range(m):
            for c in range(a + 1, m):
                if mk[a] and mk[c]:
                    r = 0.5 * (Rb[a, c] + Rb[c, a])
                    ws[rRs + a, c] = r
                    ws[rRs + c, a] = r
    for a in range(m):
        if mk[a]:
            if linear:
                s = 0.0
                for c in range(n):
                    s += ws[rHs + a, c] * x[c]
                ws[0, a] = s
            else:
                ws[0, a] = zhb[a]
            v = zb[a] - ws[0, a]
            finite &= math.isfinite(v)
            if z_is_angle[a]:
                v = wrap(v)
            ws[1, a] = v
        else:
            ws[1, a] = 0.0
    if not finite:
        return STATUS_NONFINITE, math.nan
    # R (selected part) must be symmetric positive semi-definite
    bad_r = asymmetric
    for a in range(m):
        if ws[rRs + a, a] < 0.0:
            bad_r = True
    if not bad_r and not diagonal:
        big = 0.0
        for a in range(m):
            big = max(big, ws[rRs + a, a])
        for a in range(m):
            for c in range(a + 1):
                ws[rS + a, c] = ws[rRs + a, c]
            ws[rS + a, a] += 1e-12 * big + 1e-300
        bad_r = not cholesky_rows(ws, rS, m)
    if bad_r:
        return STATUS_BAD_R, math.nan
    # HP = Hs P (skipping zeros of H); S = HP Hsᵀ + R (lower triangle); S = L Lᵀ
    for a in range(m):
        for j in range(n):
            ws[rHP + a, j] = 0.0
        for c in range(n):
            h = ws[rHs + a, c]
            if h != 0.0:
                for j in range(n):
                    ws[rHP + a, j] += h * Pb[c, j]
    for a in range(m):
        for c in range(a + 1):
            s = ws[rRs + a, c]
            for j in range(n):
                h = ws[rHs + c, j]
                if h != 0.0:
                    s += ws[rHP + a, j] * h
            ws[rS + a, c] = s
    if not cholesky_rows(ws, rS, m):
        return STATUS_S_NOT_PD, math.nan
    # w = L⁻¹ y, d² = |w|² (squared Mahalanobis distance of the innovation)
    d2 = 0.0
    for a in range(m):
        t = ws[1, a]
        for c in range(a):
            t -= ws[rS + a, c] * ws[2, c]
        t /= ws[rS + a, a]
        ws[2, a] = t
        d2 += t * t
    if not (d2 <= gate_sq):
        return STATUS_GATED, d2
    # Kᵀ = S⁻¹ HP = L⁻ᵀ L⁻¹ HP (seed 000 eq. 10), two triangular solves on rows
    for a in range(m):
        for j in range(n):
            ws[rKt + a, j] = ws[rHP + a, j]
        for c in range(a):
            s = ws[rS + a, c]
            for j in range(n):
                ws[rKt + a, j] -= s * ws[rKt + c, j]
        inv = 1.0 / ws[rS + a, a]
        for j in range(n):
            ws[rKt + a, j] *= inv
    for a in range(m - 1, -1, -1):
        for c in range(a + 1, m):
            s = ws[rS + c, a]
            for j in range(n):
                ws[rKt + a, j] -= s * ws[rKt + c, j]
        inv = 1.0 / ws[rS + a, a]
        for j in range(n):
            ws[rKt + a, j] *= inv
    # Joseph form P' = A P Aᵀ + K R Kᵀ with A = I - K H, evaluated as
    # T = A P = P - K HP ; P' = T + (K R - T Hᵀ) Kᵀ        (n² m work, not n³)
    for i in range(n):
        for j in range(n):
            s = Pb[i, j]
            for a in range(m):
                s -= ws[rKt + a, i] * ws[rHP + a, j]
            ws[rT + i, j] = s
    for i in range(n):
        for a in range(m):
            if diagonal:
                s = ws[rKt + a, i] * ws[rRs + a, a]
            else:
                s = 0.0
                for c in range(m):
                    s += ws[rKt + c, i] * ws[rRs + c, a]
            for j in range(n):
                h = ws[rHs + a, j]
                if h != 0.0:
                    s -= ws[rT + i, j] * h
            ws[rM + i, a] = s
    finite = True
    for i in range(n):  # upper triangle, mirrored
        for j in range(i, n):
            s = ws[rT + i, j]
            for a in range(m):
                s += ws[rM + i, a] * ws[rKt + a, j]
            ws[rPn + i, j] = s
            ws[rPn + j, i] = s
            finite &= math.isfinite(s)
    # x' = x + K y (eq. 11)
    for i in range(n):
        s = x[i]
        for a in range(m):
            s += ws[rKt + a, i] * ws[1, a]
        ws[3, i] = s
        finite &= math.isfinite(s)
    if not finite:
        return STATUS_NONFINITE, d2
    if not _make_spd_rows(ws, rPn, ws, rT, n, min_variance):  # T is free: Cholesky scratch
        return STATUS_P_NOT_PD, d2
    for i in range(n):
        v = ws[3, i]
        if x_is_angle[i]:
            v = wrap(v)
        x[i] = v
        for j in range(n):
            Pb[i, j] = ws[rPn + i, j]
    return STATUS_OK, d2



@njit(cache=True)
def all_finite(x: np.ndarray, P: np.ndarray) -> bool:
    """Whether every entry of a state (n,) and its covariance (n, n) is finite."""
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    for i in range(P.shape[0]):
        for j in range(P.shape[1]):
            if not math.isfinite(P[i, j]):
                return False
    return True


def source_stamp(*paths: str) -> str:
    """Hash of this module's source, of the angles, hypot and linalg modules its helpers are
    compiled from, and of the given files.

    A compiled function that inlines helpers from here keys itself with this stamp (a
    closure constant): numba's on-disk cache only watches the file that defines a function,
    so without it a change here would leave stale machine code there.
    """
    h = hashlib.sha256()
    for p in (__file__, angles.__file__, hypot.__file__, linalg.__file__, *paths):
        try:
            h.update(Path(p).read_bytes())
        except OSError:  # pragma: no cover - sources not readable (e.g. zipped): key by name
            h.update(str(p).encode())
    return h.hexdigest()


_STAMP = source_stamp()


@functools.cache
def predict_kernel(n: int):
    """Compiled ``predict(X, P, Xn, F, Q, x_is_angle, min_variance, ok, work)`` for n states.

    Commits a prediction computed outside: X[b] = Xn[b], P[b] = F[b] P[b] F[b]ᵀ + Q[b], in
    place. F and Q may have a leading dimension of 1 (shared by all trials). A trial whose
    predicted state or covariance is not finite keeps its old X and P (ok[b] = False).
    """

    stamp = _STAMP

    @njit(cache=True, error_model="numpy")
    def predict(X, P, Xn, F, Q, x_is_angle, min_variance, ok, work):
        if len(stamp) < 0:  # never true: references the stamp so that it keys the cache
            return
        nf = F.shape[0]
        nq = Q.shape[0]
        for b in range(X.shape[0]):
            ok[b] = commit_prediction(X[b], P[b], Xn[b], F[b if nf > 1 else 0], Q[b if nq > 1 else 0],
                                      x_is_angle, min_variance, work, n, n)

    return predict


@functools.cache
def update_kernel(n: int, m: int):
    """Compiled EKF update of N trials, n states and m measurement components (compile-time).

    ``update(X, P, Z, Zhat, H, R, mask, gate_sq, z_is_angle, x_is_angle, min_variance,
    status, d2, ws)`` updates every trial in place with a Joseph-form covariance.
    X (N, n), P (N, n, n), Z and Zhat (N, m), H (N, m, n), R (N, m, m), mask (N, m) bool
    selects the components to fuse (a partial update); H, R and mask may have a leading
    dimension of 1 (shared by all trials). A Zhat with no rows means the model is linear:
    Zhat = H X is computed here. Residuals with z_is_angle and states with x_is_angle are
    wrapped to (-pi, pi]. A trial whose squared Mahalanobis distance exceeds gate_sq is
    left untouched (status GATED); d2[b] gets that distance (nan when not reached).
    ``ws`` is scratch of :func:`update_work_shape`.

    Row blocks of ``ws`` are used by offset, not through views: creating numba array
    views per trial costs more than the arithmetic of a 6×6 update.

    A component left out by the mask is neutralised (its row of H, its residual and its
    cross-covariances set to 0, its variance to 1), which leaves the update exactly equal
    to one with the reduced measurement while every loop keeps its compile-time length.
    """

    stamp = _STAMP

    @njit(cache=True, error_model="numpy")
    def update(X, P, Z, Zhat, H, R, mask, gate_sq, z_is_angle, x_is_angle, min_variance, status, d2_out,
               ws):
        if len(stamp) < 0:  # never true: references the stamp so that it keys the cache
            return
        nh = H.shape[0]
        nr = R.shape[0]
        nm = mask.shape[0]
        linear = Zhat.shape[0] == 0
        for b in range(X.shape[0]):
            st, d2 = update_one(X[b], P[b], Z[b], Z[b] if linear else Zhat[b], linear, H[b if nh > 1 else 0],
                                R[b if nr > 1 else 0], mask[b if nm > 1 else 0], gate_sq, z_is_angle,
                                x_is_angle, min_variance, ws, n, m)
            status[b] = st
            d2_out[b] = d2

    return update
