"""The dead-wheel pods' offsets, angles and scales from camera pose fixes: a sparse batch fit (no ROS).

The model, its residuals and the observability rule are in docs/models.md ("Dead-wheel pods");
``ekf_calibrate`` (tools/ekf_calibrate.py) reads the bags and writes the YAML. The unknowns are
the pose at every fix (nuisance parameters) and the free pod parameters p = [o.., α.., k..]
(``PodGeometry.vector``); fixes come in chains joined by the pods' integrated displacement (a
new bag or a gap in the encoders starts a new chain). ``scipy.optimize.least_squares`` runs
with the analytic sparse Jacobian; the std is a moving-block bootstrap of the camera errors.

The fit takes any encoder geometry with ``PodGeometry``'s interface: ``count`` (encoders),
``vector`` and ``from_vector`` (its parameters), ``encoders_from_twist`` (count, 3) and
``rows_jacobian()`` (count, 3, parameters), and optionally ``columns`` (the twist components
the encoders determine; default :func:`twist_columns`). The driven wheels' radius and turning
lever (tools/driven_calibration.py) are fitted with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.sparse.linalg import splu

from ekf_localization.core.angles import wrap_angle, wrap_angles
from ekf_localization.models.sensors.dead_wheels import POD_FIELDS, PodGeometry

# A parameter whose formal std exceeds this is not observable from the drive (held):
# offsets 1 cm, angles 0.01 rad, scales 1 %.
MAX_STD = {"offsets": 0.01, "angles": 0.01, "scales": 0.01}
GAP_S = 0.5  # a longer gap between encoder samples breaks the chain of fixes
BLOCK_S = 5.0  # longest bootstrap block, s (successive camera errors may be correlated)


@dataclass(frozen=True)
class PodData:
    """Pod distances (m, along each pod's surface, k × the truth) at stamps t (s): shape (N, pods)."""

    t: np.ndarray
    d: np.ndarray


@dataclass(frozen=True)
class PoseFixes:
    """Camera pose fixes: stamps (s), poses [x y yaw] (N, 3), their variances (N, 3)."""

    t: np.ndarray
    pose: np.ndarray
    var: np.ndarray


@dataclass(frozen=True)
class Problem:
    """Fixes and the pods' increments between them.

    ``link[j]``: fix j is joined to j + 1 (False at a chain's end). The increments ``dd`` (K,
    pods) belong to link ``seg`` (K,); ``noise`` (K, pods) is each increment's variance (eq. 32
    over its interval); ``T`` the links' intervals; ``offset`` (n, 3) is added to each link's
    prediction (zero but in a bootstrap replicate)."""

    t: np.ndarray
    pose: np.ndarray
    sd_fix: np.ndarray
    link: np.ndarray
    T: np.ndarray
    dd: np.ndarray
    seg: np.ndarray
    noise: np.ndarray
    walk: np.ndarray  # process noise per second [x, y, yaw]
    offset: np.ndarray

    @property
    def n(self) -> int:
        return len(self.t)


def build_problem(pairs: list[tuple[PoseFixes, PodData]], walk: tuple[float, float, float],
                  speed_variance: tuple[float, float]) -> Problem:
    """One problem from each bag's fixes and pod distances; ``walk``: the filter's x, y, yaw
    process noise (m²/s, m²/s, rad²/s); ``speed_variance``: eq. 32's (a, b) of the pods."""
    parts = []
    offset = 0
    for fixes, pods in pairs:
        order = np.argsort(pods.t, kind="stable")
        tp, dp = pods.t[order], pods.d[order]
        keep = np.r_[True, np.diff(tp) > 0]
        tp, dp = tp[keep], dp[keep]
        f_order = np.argsort(fixes.t, kind="stable")
        tf, pf, vf = fixes.t[f_order], fixes.pose[f_order], fixes.var[f_order]
        inside = (tf >= tp[0]) & (tf <= tp[-1]) if len(tp) >= 2 else np.zeros(len(tf), bool)
        tf, pf, vf = tf[inside], pf[inside], vf[inside]
        uniq = np.r_[True, np.diff(tf) > 0]
        tf, pf, vf = tf[uniq], pf[uniq], vf[uniq]
        if len(tf) < 2:
            continue
        gaps = np.r_[0, np.cumsum(np.diff(tp) > GAP_S)]  # a fix inside a gap joins no neighbour
        link = np.r_[np.diff(np.interp(tf, tp, gaps)) == 0, False]
        # every encoder stamp and fix stamp from the first fix to the last, the distances there
        ts = np.union1d(tp[(tp > tf[0]) & (tp < tf[-1])], tf)
        ds = np.column_stack([np.interp(ts, tp, dp[:, i]) for i in range(dp.shape[1])])
        dd = np.diff(ds, axis=0)
        dt = np.diff(ts)
        seg = np.searchsorted(tf, ts[:-1], side="right") - 1
        a, b = speed_variance
        speed = dd / dt[:, None]
        noise = (a * speed ** 2 + b) * dt[:, None] ** 2
        parts.append((tf, pf, np.sqrt(vf), link, np.r_[np.diff(tf), 0.0], dd, seg + offset, noise))
        offset += len(tf)
    if not parts:
        return Problem(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, bool), np.zeros(0),
                       np.zeros((0, 3)), np.zeros(0, np.intp), np.zeros((0, 3)), np.asarray(walk, float),
                       np.zeros((0, 3)))
    cat = [np.concatenate(c) for c in zip(*parts, strict=True)]
    links = cat[3].astype(bool)
    ok = links[cat[6]]  # increments inside a chain's links only
    return Problem(cat[0], cat[1], cat[2], links, cat[4], cat[5][ok], cat[6][ok].astype(np.intp), cat[7][ok],
                   np.asarray(walk, float), np.zeros((len(cat[0]), 3)))


def at_mount(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(N, 3) poses ∘ Δ: where a camera whose mount is off by Δ puts base_link (F = B ∘ Δ)."""
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    return np.column_stack([pose[:, 0] + c * delta[0] - s * delta[1],
                            pose[:, 1] + s * delta[0] + c * delta[1], pose[:, 2] + delta[2]])


def twist_columns(count: int) -> np.ndarray:
    """The body-twist components [ẋ ẏ θ̇] the pods determine (two pods: ẋ and θ̇, ẏ = 0)."""
    return np.array([0, 1, 2] if count >= 3 else [0, 2])


def columns_of(geom) -> np.ndarray:
    """The twist components ``geom``'s encoders determine: its ``columns``, else the pods'."""
    cols = getattr(geom, "columns", None)
    return twist_columns(geom.count) if cols is None else np.asarray(cols)


def _solver(M: np.ndarray) -> np.ndarray:
    """A with Δb = A·Δd: M's inverse, or its least-squares inverse for more encoders than unknowns."""
    return np.linalg.inv(M) if M.shape[0] == M.shape[1] else np.linalg.pinv(M)


def integrate(p: Problem, pods: PodGeometry, with_jacobian: bool = True):
    """Each link's predicted displacement Δ (n, 3) in the frame of its first fix and, with
    ``with_jacobian``, ∂Δ/∂p (n, 3, parameters); docs/models.md, "Dead-wheel pods"."""
    cols = columns_of(pods)
    M = pods.encoders_from_twist[:, cols]
    A = _solver(M)
    db = np.zeros((len(p.dd), 3))
    db[:, cols] = p.dd @ A.T
    start = np.r_[0, np.flatnonzero(np.diff(p.seg)) + 1] if len(p.seg) else np.zeros(0, np.intp)

    def within(x: np.ndarray) -> np.ndarray:  # per-segment cumsum, exclusive
        c = np.cumsum(x, axis=0) - x
        first = np.repeat(c[start], np.diff(np.r_[start, len(x)]), axis=0)
        return c - first

    phi = within(db[:, 2]) + 0.5 * db[:, 2]
    c, s = np.cos(phi), np.sin(phi)
    step = np.column_stack([c * db[:, 0] - s * db[:, 1], s * db[:, 0] + c * db[:, 1], db[:, 2]])
    delta = np.zeros((p.n, 3))
    np.add.at(delta, p.seg, step)
    if not with_jacobian:
        return delta, None
    J = pods.rows_jacobian()[:, cols, :]  # (encoders, len(cols), P)
    P = J.shape[2]
    g = np.einsum("kc,icm->kim", db[:, cols], J)  # (∂M/∂p_m)·Δb_k
    ddb = np.zeros((len(p.dd), 3, P))
    ddb[:, cols, :] = -np.einsum("ci,kim->kcm", A, g)
    if M.shape[0] > M.shape[1]:  # the least-squares inverse's other term: (MᵀM)⁻¹·∂Mᵀ·(Δd − M·Δb)
        misfit = p.dd - db[:, cols] @ M.T
        ddb[:, cols, :] += np.einsum("cj,ki,ijm->kcm", np.linalg.inv(M.T @ M), misfit, J)
    dphi = within(ddb[:, 2, :]) + 0.5 * ddb[:, 2, :]
    dx = c[:, None] * ddb[:, 0] - s[:, None] * ddb[:, 1] - step[:, 1, None] * dphi
    dy = s[:, None] * ddb[:, 0] + c[:, None] * ddb[:, 1] + step[:, 0, None] * dphi
    dstep = np.stack([dx, dy, ddb[:, 2]], axis=1)
    ddelta = np.zeros((p.n, 3, P))
    np.add.at(ddelta, p.seg, dstep)
    return delta, ddelta


def link_sd(p: Problem, pods: PodGeometry) -> np.ndarray:
    """(n, 3) std of each link's x, y, yaw: the slip over its interval and the pods' noise."""
    cols = columns_of(pods)
    A = _solver(pods.encoders_from_twist[:, cols])
    S = np.zeros((p.n, pods.count))
    np.add.at(S, p.seg, p.noise)
    cov = np.einsum("ci,ki,ci->kc", A, S, A)  # diag(A diag(S) Aᵀ)
    full = np.zeros((p.n, 3))
    full[:, cols] = cov
    xy = 0.5 * (full[:, 0] + full[:, 1])  # the body frame turns: x and y alike
    var = p.T[:, None] * p.walk[None, :] + np.column_stack([xy, xy, full[:, 2]])
    return np.sqrt(np.maximum(var, 1e-12))


def initial_poses(p: Problem, pods: PodGeometry) -> np.ndarray:
    """The fixes, each yaw taken to the branch nearest the pods' prediction (the camera's is wrapped)."""
    pose = np.array(p.pose, dtype=float)
    delta, _ = integrate(p, pods, with_jacobian=False)
    for j in range(p.n - 1):
        if p.link[j]:
            pred = pose[j, 2] + delta[j, 2]
            pose[j + 1, 2] = pred + wrap_angle(p.pose[j + 1, 2] - pred)
    return pose


class _Fit:
    """Residuals and sparse Jacobian over x = [poses (n, 3) flattened, free pod parameters]."""

    def __init__(self, p: Problem, start: PodGeometry, free: np.ndarray) -> None:
        self.p, self.start, self.free = p, start, np.asarray(free, bool)
        self.links = np.flatnonzero(p.link)
        self.sd_link = link_sd(p, start)[self.links]
        n, m = p.n, len(self.links)
        fix = sparse.diags((-1.0 / p.sd_fix).ravel())
        self._fix = sparse.hstack([fix, sparse.csr_matrix((3 * n, int(self.free.sum())))], format="csr")
        self.m = m
        self.mounted = getattr(start, "mount", None) is not None  # Δ: the last 3 (tools/mount_calibration.py)

    def pods_of(self, x: np.ndarray) -> PodGeometry:
        v = self.start.vector
        v[self.free] = x[3 * self.p.n:]
        return self.start.from_vector(v)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        p = self.p
        pose = x[:3 * p.n].reshape(-1, 3)
        pods = self.pods_of(x)
        fix = p.pose - (at_mount(pose, pods.mount) if self.mounted else pose)  # F = B ∘ Δ
        fix[:, 2] = wrap_angles(fix[:, 2])
        delta, _ = integrate(p, pods, with_jacobian=False)
        return np.r_[(fix / p.sd_fix).ravel(), (self._link(pose, delta + p.offset) / self.sd_link).ravel()]

    def _link(self, pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
        j = self.links
        d = pose[j + 1, :2] - pose[j, :2]
        c, s = np.cos(pose[j, 2]), np.sin(pose[j, 2])
        return np.column_stack([c * d[:, 0] + s * d[:, 1] - delta[j, 0],
                                -s * d[:, 0] + c * d[:, 1] - delta[j, 1],
                                pose[j + 1, 2] - pose[j, 2] - delta[j, 2]])

    def jacobian(self, x: np.ndarray) -> sparse.csr_matrix:
        p, j = self.p, self.links
        pose = x[:3 * p.n].reshape(-1, 3)
        _, ddelta = integrate(p, self.pods_of(x))
        d = pose[j + 1, :2] - pose[j, :2]
        c, s = np.cos(pose[j, 2]), np.sin(pose[j, 2])
        w = 1.0 / self.sd_link  # (m, 3)
        r = np.arange(self.m)
        rows, cols, vals = [], [], []

        def put(row: np.ndarray, col: np.ndarray, val: np.ndarray) -> None:
            rows.append(row), cols.append(col), vals.append(val)

        for comp, (cx, sx) in enumerate(((c, s), (-s, c))):  # body x, body y of the step
            put(3 * r + comp, 3 * (j + 1), cx * w[:, comp])
            put(3 * r + comp, 3 * (j + 1) + 1, sx * w[:, comp])
            put(3 * r + comp, 3 * j, -cx * w[:, comp])
            put(3 * r + comp, 3 * j + 1, -sx * w[:, comp])
        put(3 * r, 3 * j + 2, (-s * d[:, 0] + c * d[:, 1]) * w[:, 0])
        put(3 * r + 1, 3 * j + 2, (-c * d[:, 0] - s * d[:, 1]) * w[:, 1])
        put(3 * r + 2, 3 * (j + 1) + 2, w[:, 2])
        put(3 * r + 2, 3 * j + 2, -w[:, 2])
        nfree = int(self.free.sum())
        link = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                 shape=(3 * self.m, 3 * p.n + nfree))
        dp = -(ddelta[j][:, :, self.free] * w[:, :, None]).reshape(3 * self.m, nfree)
        params = sparse.hstack([sparse.csr_matrix((3 * self.m, 3 * p.n)), sparse.csr_matrix(dp)])
        fix = self._fix_jacobian(pose, self.pods_of(x)) if self.mounted else self._fix
        return sparse.vstack([fix, link + params], format="csr")

    def _fix_jacobian(self, pose: np.ndarray, pods) -> sparse.csr_matrix:
        """∂(fix residuals)/∂x for fixes predicted as B ∘ Δ (docs/models.md, "Camera mount")."""
        p, n = self.p, self.p.n
        dx, dy, _ = pods.mount
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        w = 1.0 / p.sd_fix
        r = np.arange(n)
        rows = [3 * r, 3 * r + 1, 3 * r + 2, 3 * r, 3 * r + 1]
        cols = [3 * r, 3 * r + 1, 3 * r + 2, 3 * r + 2, 3 * r + 2]
        vals = [-w[:, 0], -w[:, 1], -w[:, 2], (s * dx + c * dy) * w[:, 0], -(c * dx - s * dy) * w[:, 1]]
        first = 3 * n + int(self.free[:-3].sum())  # Δ's free components come last in x
        dmount = (np.column_stack([-c * w[:, 0], s * w[:, 0]]), np.column_stack([-s * w[:, 1], -c * w[:, 1]]))
        for k in np.flatnonzero(self.free[-3:]):
            col = np.full(n, first + int(self.free[-3:][:k].sum()))
            if k == 2:
                rows.append(3 * r + 2), cols.append(col), vals.append(-w[:, 2])
            else:
                rows += [3 * r, 3 * r + 1]
                cols += [col, col]
                vals += [dmount[0][:, k], dmount[1][:, k]]
        return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                 shape=(3 * n, 3 * n + int(self.free.sum())))


@dataclass(frozen=True)
class FitResult:
    pods: PodGeometry
    rms: float  # RMS of the normalised residuals
    poses: np.ndarray
    formal_std: np.ndarray  # per parameter of PodGeometry.vector (inf: held or not observable)


def fit(p: Problem, start: PodGeometry, free: np.ndarray, poses: np.ndarray | None = None) -> FitResult:
    """Least squares over the poses and the free pod parameters (the others stay at ``start``)."""
    free = np.asarray(free, bool)
    f = _Fit(p, start, free)
    x0 = np.r_[(initial_poses(p, start) if poses is None else poses).ravel(), start.vector[free]]
    sol = least_squares(f.residuals, x0, jac=f.jacobian, method="trf", tr_solver="lsmr", x_scale="jac")
    r = f.residuals(sol.x)
    return FitResult(f.pods_of(sol.x), float(np.sqrt(np.mean(r ** 2))), sol.x[:3 * p.n].reshape(-1, 3),
                     _formal_std(f.jacobian(sol.x), 3 * p.n, free))


def _formal_std(J: sparse.csr_matrix, n: int, free: np.ndarray,
                prior: np.ndarray | None = None) -> np.ndarray:
    """Std of the free parameters from the information left once the poses are solved for;
    ``prior``: a weak information added on the diagonal, so that confounded ones come out large
    rather than the inverse failing."""
    out = np.full(len(free), math.inf)
    if not free.any():
        return out
    A, B = J[:, :n].tocsc(), J[:, n:].toarray()
    AtB = A.T @ B
    info = B.T @ B - AtB.T @ splu((A.T @ A).tocsc()).solve(AtB)
    if prior is not None:
        info = info + np.diag(prior)
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return out
    diag = np.diag(cov)
    out[free] = np.where(diag > 0, np.sqrt(np.abs(diag)), math.inf)
    return out


def limits(count: int) -> np.ndarray:
    """:data:`MAX_STD` per parameter of ``PodGeometry.vector``."""
    return np.repeat([MAX_STD[f] for f in POD_FIELDS], count)


def observable(p: Problem, start: PodGeometry, free: np.ndarray | None = None,
               lim: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(which parameters the drive determines within :data:`MAX_STD`, their formal std: a held
    one's when it was held), judged at ``start`` with the poses fitted: the worst (std over its
    limit) is held, one at a time, until the rest are within. ``free``: the candidates (default
    all; a weak prior of 1000 limits keeps confounded ones finite); ``lim``: the limits (default
    :func:`limits`)."""
    size = len(start.vector)
    free = np.ones(size, bool) if free is None else np.array(free, bool)
    if p.n < 3 or not p.link.any():
        return np.zeros(size, bool), np.full(size, math.inf)
    poses = fit(p, start, np.zeros(size, bool)).poses
    lim = limits(start.count) if lim is None else np.asarray(lim, float)
    held = np.full(size, math.inf)  # each held parameter's std when it was held
    while free.any():
        x = np.r_[poses.ravel(), start.vector[free]]
        std = _formal_std(_Fit(p, start, free).jacobian(x), 3 * p.n, free, (1e-3 / lim[free]) ** 2)
        ratio = np.where(free, std / lim, 0.0)
        if ratio.max() <= 1.0:
            return free, np.where(free, std, held)
        worst = int(np.argmax(ratio))
        free[worst], held[worst] = False, std[worst]
    return free, held


def correlated_run(z: np.ndarray, longest: int) -> int:
    """The block length, in fixes, for resampling the fix residuals ``z`` (n, components, each
    normalised): 1 + the lags from 1 up at which their autocorrelation (the components pooled)
    stays above 2/√(their count), at most ``longest``. The camera's own correlated errors keep the
    residuals positively correlated over their correlation time; beyond it, what is left is the
    fitted poses' imprint (they absorb the slow part of the camera errors, leaving the residuals
    negatively correlated over the poses' smoothing window). Blocks that carried that imprint
    would lack the slow errors the parameters respond to, and the std would come out small."""
    z = np.asarray(z, dtype=float)
    power = float(np.sum(z * z))
    if power <= 0.0 or len(z) < 3:
        return max(1, min(longest, len(z)))
    bar = 2.0 / math.sqrt(z.size)
    run = 1
    while run < min(longest, len(z) - 1) and float(np.sum(z[:-run] * z[run:])) / power > bar:
        run += 1
    return run


def bootstrap_std(p: Problem, best: FitResult, free: np.ndarray, replicates: int, seed: int,
                  block_s: float = BLOCK_S, shown: np.ndarray | None = None) -> np.ndarray:
    """Std of the pod parameters over ``replicates`` refits to data rebuilt from the fit (fixed
    seed): the camera errors the fit's fix residuals drawn in blocks as long as they stay
    correlated (:func:`correlated_run`), at most about ``block_s``; each link's slip and pod noise
    drawn from its model (the fitted poses absorb them); ``shown``: the parameters to give a std
    (default ``free``: add those a geometry ties to free ones)."""
    n, size = p.n, len(best.pods.vector)
    out = np.full(size, math.nan)
    if n < 3 or replicates < 2 or not free.any():
        return out
    f = _Fit(p, best.pods, np.zeros(size, bool))
    r = f.residuals(best.poses.ravel())
    e_fix = r[:3 * n].reshape(-1, 3) * p.sd_fix  # camera minus fitted pose
    e_link = r[3 * n:].reshape(-1, 3) * f.sd_link  # the fit's link misfit
    span = max(float(p.t[-1] - p.t[0]), 1e-9)
    size_b = correlated_run(r[:3 * n].reshape(-1, 3), int(min(n, max(1, round(block_s * n / span)))))
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(replicates):
        starts = rng.integers(0, n - size_b + 1, -(-n // size_b))
        src = (starts[:, None] + np.arange(size_b)).ravel()[:n]
        pose = best.poses + e_fix[src]
        pose[:, 2] = wrap_angles(pose[:, 2])
        offset = np.zeros((n, 3))
        offset[f.links] = e_link + rng.standard_normal(e_link.shape) * f.sd_link
        rep = fit(replace(p, pose=pose, offset=offset), best.pods, free, poses=best.poses)
        draws.append(rep.pods.vector)
    shown = free if shown is None else np.asarray(shown, bool)  # free, and those tied to them
    out[shown] = np.std(np.array(draws), axis=0, ddof=1)[shown]
    return out
