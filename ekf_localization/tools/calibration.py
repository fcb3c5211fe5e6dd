"""The IMU yaw-rate scale and bias from camera heading fixes: a sparse batch fit (no ROS).

The model, its residuals and the observability rule are in docs/models.md ("IMU yaw-rate scale
and bias"); ``ekf_calibrate`` (tools/ekf_calibrate.py) reads the bags and writes the YAML.

The unknowns are the gyro's scale s and bias b (each free or held) and the true heading at
every fix. Fixes come in *chains*: runs of fixes joined by gyro integrals (a new bag, or a gap
in the gyro, starts a new chain). The fit is ``scipy.optimize.least_squares`` with the
analytic sparse Jacobian (each residual touches at most two headings); the std of s and b is a
moving-block bootstrap of the camera errors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.sparse.linalg import splu

from ekf_localization.core.angles import wrap_angle, wrap_angles

NAMES = ("scale", "bias")
# A parameter whose formal std exceeds this is not observable from the drive (left unchanged):
# 1 % of scale (a drive with little rotation), 0.01 rad/s of bias (hardly any fixes).
MAX_STD = (0.01, 0.01)
# A fitted scale or bias outside these is refused (a gyro further off is broken, not miscalibrated).
BOUNDS = ((0.5, 2.0), (-1.0, 1.0))
GYRO_GAP_S = 0.5  # a longer gap between gyro samples breaks the chain of heading fixes
BLOCK_S = 5.0  # bootstrap block length (successive camera errors are correlated)


@dataclass(frozen=True)
class Gyro:
    """Gyro z samples: stamps (s), rates (rad/s), their variances ((rad/s)²)."""

    t: np.ndarray
    rate: np.ndarray
    var: np.ndarray


@dataclass(frozen=True)
class Fixes:
    """Camera heading fixes: stamps (s), yaw (rad), its variance (rad²)."""

    t: np.ndarray
    yaw: np.ndarray
    var: np.ndarray


@dataclass(frozen=True)
class Problem:
    """Fixes and the gyro integrals between successive fixes of a chain.

    ``link[k]``: the gyro residual joins fix k and k + 1 (False at a chain's end); ``G``, ``T``,
    ``var_g``: the integrated gyro (rad), the interval (s) and the variance of the heading change
    the model cannot explain (rad²), per k (only where linked)."""

    t: np.ndarray  # fix stamps (s; chains of different bags may overlap in time)
    yaw: np.ndarray
    sd_fix: np.ndarray
    link: np.ndarray
    G: np.ndarray
    T: np.ndarray
    sd_link: np.ndarray
    chain_start: np.ndarray  # indices of the first fix of each chain

    @property
    def n(self) -> int:
        return len(self.yaw)


def build_problem(pairs: list[tuple[Fixes, Gyro]], heading_walk: float) -> Problem:
    """One problem from each bag's fixes and gyro; ``heading_walk``: the filter's yaw process
    noise (rad²/s), the heading random walk the gyro does not see."""
    parts = []
    for fixes, gyro in pairs:
        order = np.argsort(gyro.t, kind="stable")
        tg, wg, vg = gyro.t[order], gyro.rate[order], gyro.var[order]
        keep = np.r_[True, np.diff(tg) > 0]
        tg, wg, vg = tg[keep], wg[keep], vg[keep]
        f_order = np.argsort(fixes.t, kind="stable")
        tf, yf, vf = fixes.t[f_order], fixes.yaw[f_order], fixes.var[f_order]
        inside = (tf >= tg[0]) & (tf <= tg[-1]) if len(tg) >= 2 else np.zeros(len(tf), bool)
        tf, yf, vf = tf[inside], yf[inside], vf[inside]
        uniq = np.r_[True, np.diff(tf) > 0]
        tf, yf, vf = tf[uniq], yf[uniq], vf[uniq]
        if len(tf) == 0:
            continue
        integral = np.r_[0.0, np.cumsum(0.5 * (wg[1:] + wg[:-1]) * np.diff(tg))]
        noise = np.r_[0.0, np.cumsum(vg[1:] * np.diff(tg) ** 2)]  # Σ σ²Δt² of the white noise
        gaps = np.r_[0.0, np.cumsum(np.diff(tg) > GYRO_GAP_S)]  # a fix inside a gap joins no neighbour
        at = np.interp(tf, tg, integral)
        nz = np.interp(tf, tg, noise)
        seg = np.interp(tf, tg, gaps)
        link = np.r_[np.diff(seg) == 0, False]
        T = np.r_[np.diff(tf), 0.0]
        var = heading_walk * T + np.r_[np.diff(nz), 0.0]
        parts.append((tf, yf, np.sqrt(vf), link, np.r_[np.diff(at), 0.0], T, np.sqrt(np.maximum(var, 1e-12))))
    if not parts:
        return Problem(*(np.zeros(0) for _ in range(7)), np.zeros(0, dtype=np.intp))
    cat = [np.concatenate(c) for c in zip(*parts, strict=True)]
    cat[3] = cat[3].astype(bool)
    starts = np.flatnonzero(np.r_[True, ~cat[3][:-1]])
    return Problem(*cat, chain_start=starts)


def _initial_headings(p: Problem, s: float, b: float) -> np.ndarray:
    """Each chain integrated from its first fix, every heading taken to the fix's branch nearest the
    gyro's prediction (the camera's yaw is wrapped)."""
    th = np.array(p.yaw, dtype=float)
    for k in range(p.n - 1):
        if p.link[k]:
            pred = th[k] + (p.G[k] - b * p.T[k]) / s
            th[k + 1] = pred + wrap_angle(p.yaw[k + 1] - pred)
    return th


class _Fit:
    """Residuals and sparse Jacobian over x = [headings, free globals]."""

    def __init__(self, p: Problem, start: tuple[float, float], free: tuple[bool, bool]) -> None:
        self.p, self.start, self.free = p, start, free
        self.links = np.flatnonzero(p.link)
        n, m = p.n, len(self.links)
        rows = np.r_[np.arange(n), n + np.arange(m), n + np.arange(m)]
        cols = np.r_[np.arange(n), self.links + 1, self.links]
        vals = np.r_[-1.0 / p.sd_fix, 1.0 / p.sd_link[self.links], -1.0 / p.sd_link[self.links]]
        self._theta_jac = sparse.csr_matrix((vals, (rows, cols)), shape=(n + m, n))

    def globals_of(self, x: np.ndarray) -> tuple[float, float]:
        g, tail = list(self.start), list(x[self.p.n:])
        for i in range(2):
            if self.free[i]:
                g[i] = tail.pop(0)
        return g[0], g[1]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        p, k = self.p, self.links
        th = x[:p.n]
        s, b = self.globals_of(x)
        fix = wrap_angles(p.yaw - th)
        gyro = th[k + 1] - th[k] - (p.G[k] - b * p.T[k]) / s
        return np.r_[fix / p.sd_fix, gyro / p.sd_link[k]]

    def jacobian(self, x: np.ndarray) -> sparse.csr_matrix:
        p, k = self.p, self.links
        s, b = self.globals_of(x)
        cols = []
        if self.free[0]:
            cols.append(np.r_[np.zeros(p.n), (p.G[k] - b * p.T[k]) / s ** 2 / p.sd_link[k]])
        if self.free[1]:
            cols.append(np.r_[np.zeros(p.n), p.T[k] / s / p.sd_link[k]])
        if not cols:
            return self._theta_jac
        return sparse.hstack([self._theta_jac, sparse.csr_matrix(np.column_stack(cols))], format="csr")


@dataclass(frozen=True)
class FitResult:
    scale: float
    bias: float
    rms: float  # RMS of the normalised residuals (about 1 when the model and the noise hold)
    headings: np.ndarray
    formal_std: tuple[float, float]  # from the Schur complement of the headings (inf: not free/observable)


def fit(p: Problem, start: tuple[float, float], free: tuple[bool, bool] = (True, True),
        headings: np.ndarray | None = None) -> FitResult:
    """Least squares over the headings and the free globals (a held one stays at ``start``)."""
    f = _Fit(p, start, free)
    th0 = _initial_headings(p, *start) if headings is None else headings
    x0 = np.r_[th0, [v for v, fr in zip(start, free, strict=True) if fr]]
    sol = least_squares(f.residuals, x0, jac=f.jacobian, method="trf", tr_solver="lsmr", x_scale="jac")
    s, b = f.globals_of(sol.x)
    r = f.residuals(sol.x)
    return FitResult(s, b, float(np.sqrt(np.mean(r ** 2))), sol.x[:p.n],
                     _formal_std(f.jacobian(sol.x), p.n, free))


def _formal_std(J: sparse.csr_matrix, n: int, free: tuple[bool, bool]) -> tuple[float, float]:
    """Std of the free globals from the information left once the headings are solved for."""
    out = [math.inf, math.inf]
    if not any(free):
        return (out[0], out[1])
    A, B = J[:, :n].tocsc(), J[:, n:].toarray()
    AtA = (A.T @ A).tocsc()
    AtB = A.T @ B
    info = B.T @ B - AtB.T @ splu(AtA).solve(AtB)
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return (out[0], out[1])
    std = iter(np.sqrt(np.maximum(np.diag(cov), 0.0)) if np.all(np.diag(cov) > 0) else [math.inf] * 2)
    for i in range(2):
        if free[i]:
            out[i] = float(next(std))
    return (out[0], out[1])


def observable(p: Problem, start: tuple[float, float]) -> tuple[bool, bool]:
    """Which of (scale, bias) the drive determines to within :data:`MAX_STD`, judged at ``start``
    (the headings fitted, the globals held there: a fit run away on too little data cannot vouch
    for itself) with both free. When neither is (a constant turn rate confounds them), the bias
    alone with the scale held."""
    if p.n < 3 or not p.link.any():
        return (False, False)
    headings = fit(p, start, (False, False)).headings
    x = np.r_[headings, start]
    both = _formal_std(_Fit(p, start, (True, True)).jacobian(x), p.n, (True, True))
    ok = (both[0] <= MAX_STD[0], both[1] <= MAX_STD[1])
    if any(ok):
        return ok
    alone = _formal_std(_Fit(p, start, (False, True)).jacobian(np.r_[headings, start[1]]), p.n, (False, True))
    return (False, alone[1] <= MAX_STD[1])


def design_std(p: Problem, start: tuple[float, float]) -> tuple[float, float]:
    """The formal std of (scale, bias), both free, at ``start`` (what :func:`observable` judges)."""
    if p.n < 3 or not p.link.any():
        return (math.inf, math.inf)
    x = np.r_[fit(p, start, (False, False)).headings, start]
    return _formal_std(_Fit(p, start, (True, True)).jacobian(x), p.n, (True, True))


def bootstrap_std(p: Problem, best: FitResult, free: tuple[bool, bool], replicates: int,
                  seed: int, block_s: float = BLOCK_S) -> tuple[float, float]:
    """Std of (scale, bias) over ``replicates`` refits to data rebuilt from the fit (fixed seed).

    The camera errors are the fit's fix residuals, drawn in blocks of consecutive fixes about
    ``block_s`` long (a moving-block bootstrap: successive camera errors are correlated). The
    heading random walk between fixes cannot be read off the residuals (the fitted headings
    absorb it), so it is drawn from its model variance (docs/models.md)."""
    n = p.n
    if n < 3 or replicates < 2 or not any(free):
        return (math.nan, math.nan)
    f = _Fit(p, (best.scale, best.bias), (False, False))
    e_fix = f.residuals(best.headings)[:n]
    span = max(float(p.t[-1] - p.t[0]), 1e-9)
    size = int(min(n, max(1, round(block_s * n / span))))
    rng = np.random.default_rng(seed)
    th, s0, b0 = best.headings, best.scale, best.bias
    step = np.r_[np.diff(th), 0.0]
    draws = []
    for _ in range(replicates):
        starts = rng.integers(0, n - size + 1, -(-n // size))
        src = (starts[:, None] + np.arange(size)).ravel()[:n]
        yaw = wrap_angles(th + e_fix[src] * p.sd_fix)
        walk = rng.standard_normal(n) * p.sd_link
        G = np.where(p.link, s0 * (step - walk) + b0 * p.T, 0.0)
        rep = fit(replace(p, yaw=yaw, G=G), (s0, b0), free, headings=th)
        draws.append((rep.scale, rep.bias))
    std = np.std(np.array(draws), axis=0, ddof=1)
    return (float(std[0]) if free[0] else math.nan, float(std[1]) if free[1] else math.nan)
