"""CPython's ``math.hypot(a, b)`` in plain float arithmetic, so compiled code gets its last bit.

libm's hypot (what ``np.hypot`` and numba's ``math.hypot`` call) differs from CPython's in the
last bit for about 0.3 % of inputs. CPython computes a length its own way (``vector_norm`` in
Modules/mathmodule.c): scale by a power of two so the largest coordinate is in [0.5, 1), sum
the exact squares with compensation, take the square root, then correct it once with the
residual (below the normal range: divide by the largest, then a compensated sum). This is
that algorithm for two coordinates, as in CPython 3.11. The exact square comes from Dekker's
split instead of ``fma`` (which CPython uses): both give the exact product of numbers below 1.
``kernels`` compiles it (``py_hypot``); test/test_hypot.py compares it with ``math.hypot``.
"""

from __future__ import annotations

import math

_SPLIT = 134217729.0  # 2**27 + 1: Dekker's split of a double into two 26-bit halves


def _exact_square(x: float) -> tuple[float, float]:
    """(x², its rounding error) exactly, for |x| < 1 (Dekker)."""
    p = x * x
    c = _SPLIT * x
    hi = c - (c - x)
    lo = x - hi
    return p, lo * lo - (((p - hi * hi) - lo * hi) - hi * lo)


def python_hypot(a: float, b: float) -> float:
    """``math.hypot(a, b)`` of CPython 3.8+, bit for bit."""
    a = abs(a)
    b = abs(b)
    found_nan = math.isnan(a) or math.isnan(b)
    big = 0.0
    if a > big:
        big = a
    if b > big:
        big = b
    if math.isinf(big):
        return big
    if found_nan:
        return math.nan
    if big == 0.0:
        return big
    exponent = math.frexp(big)[1]
    if exponent < -1023:  # subnormal: a power-of-two scale would overflow
        csum = 1.0
        frac = 0.0
        for v in (a, b):
            v /= big
            v *= v
            s = csum + v
            frac += (csum - s) + v
            csum = s
        return big * math.sqrt(csum - 1.0 + frac)
    scale = math.ldexp(1.0, -exponent)
    csum = 1.0
    frac1 = 0.0
    frac2 = 0.0
    for v in (a, b):
        sq, sq_lo = _exact_square(v * scale)  # lossless scaling, exact square
        s = csum + sq  # compensated sum, |csum| >= |sq|
        frac2 += (csum - s) + sq
        csum = s
        frac1 += sq_lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    sq, sq_lo = _exact_square(h)
    s = csum - sq
    frac2 += (csum - s) - sq
    csum = s
    frac1 -= sq_lo
    x = csum - 1.0 + (frac1 + frac2)
    h += x / (2.0 * h)  # differential correction
    return h / scale
