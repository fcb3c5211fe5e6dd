"""ekf_tune's staged search over the knobs of a :class:`~ekf_localization.tools.tuning.Problem`.

Covariance matching of the input scales (each scale times its input's mean NIS per dimension,
a few replays), then on the likelihood a coordinate search in decades (each batch of moves in
parallel), or on the RMSE scipy's L-BFGS-B (bounded quasi-Newton; forward-difference gradients
one batch in parallel) with the common scale of the variances held, then set so that the NEES
is in its band. Every candidate is scored once (:func:`ekf_localization.tools.tuning.score`),
batches in forked worker processes. docs/ekf_tune.md, "How it fits", has the details.
"""

from __future__ import annotations

import math
import multiprocessing
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

from ekf_localization.tools.tuning import PROG, Knob, Problem, Score, score

GRADIENT_STEP = 0.02  # forward-difference step in log10 of each parameter (≈ 4.7 %)
GRADIENT_FTOL = 1e-3  # L-BFGS-B: stop when an iteration improves the objective by < this (absolute:
# 0.1 % of the RMSE; scipy's ftol is relative to |f|)
GRADIENT_GTOL = 1e-3
PATTERN_STEPS = (1.0, 0.5, 0.25)  # coordinate search (likelihood): decades per move
PATTERN_FTOL = 1e-3  # ... a move must improve the objective by this much
SCREEN_GRADIENT = 1e-4  # a knob whose first derivative (objective per decade) is below this is held
MATCH_ITERATIONS = 8  # covariance matching: replays at most
MATCH_TOLERANCE = 1.05  # ... until every input's NIS per dimension is within this factor of 1
CALIBRATION_EVALS = 3  # NEES calibration: replays at most


class _BudgetSpentError(Exception):
    """The evaluation budget is spent."""


_PROBLEM: Problem | None = None  # set in the parent before the pool forks


def _worker_init() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle


def _worker_score(x: np.ndarray, innovations: bool) -> Score:
    assert _PROBLEM is not None
    return score(_PROBLEM, x, innovations)


class Progress:
    """One stderr line: evaluations done, best objective, time left (rewritten in place)."""

    def __init__(self, budget: int, stream=sys.stderr) -> None:
        self.budget = budget
        self.done = 0
        self.best = math.inf
        self.stage = ""
        self.t0 = time.monotonic()
        self._stream = stream
        self._tty = hasattr(stream, "isatty") and stream.isatty()

    def update(self, done: int, best: float) -> None:
        self.done, self.best = done, best
        elapsed = time.monotonic() - self.t0
        left = elapsed / done * max(self.budget - done, 0) if done else float("nan")
        width = 24
        fill = int(width * min(done / self.budget, 1.0))
        line = (f"{PROG}: [{'#' * fill}{'.' * (width - fill)}] {done}/{self.budget} evaluations  "
                f"best {best:.5g}  {elapsed:.0f} s elapsed, ≤{left:.0f} s left  {self.stage}")
        self._stream.write(("\r" + line) if self._tty else (line + "\n"))
        self._stream.flush()

    def close(self) -> None:
        if self._tty:
            self._stream.write("\n")
            self._stream.flush()


class Tuner:
    """The staged fit (docs/ekf_tune.md, "How it fits"); every candidate scored once, batches in
    parallel, the best candidate by the final objective kept in best_x / best_f."""

    def __init__(self, problem: Problem, jobs: int, max_evals: int, progress: Progress | None = None) -> None:
        self.problem = problem
        self.jobs = max(1, jobs)
        self.max_evals = max_evals
        self.progress = progress
        self.evals = 0
        self.best_x = np.log10([k.start for k in problem.knobs])
        self.best_f = math.inf
        self.start_f = math.nan
        self.history: list[float] = []  # best objective after each batch
        self.stages: list[str] = []  # what each stage did, for the report
        self.fitted: list[str] = [k.name for k in problem.knobs]  # the knobs the gradient stage moved
        self._pool: ProcessPoolExecutor | None = None
        self._cache: dict[tuple[float, ...], tuple[Score, bool]] = {}
        self._innovations = False  # the stage needs the innovations (the likelihood)
        lo, hi = problem.log_bounds()
        self._lo, self._hi = lo, hi
        self._variance = np.array([_is_variance(k) for k in problem.knobs])
        self._input_scale = np.array([k.parameter.endswith("_variance_scale") for k in problem.knobs])

    def __enter__(self) -> Tuner:
        global _PROBLEM
        x0 = self.best_x.copy()
        self._x0 = x0
        # the start is scored here, before the pool forks
        self._innovations = self.problem.objective == "likelihood"
        self.start_f = self._note(x0, score(self.problem, x0, self._innovations), self._innovations)
        if self.jobs > 1:
            _PROBLEM = self.problem
            ctx = multiprocessing.get_context("fork")
            self._pool = ProcessPoolExecutor(self.jobs, mp_context=ctx, initializer=_worker_init)
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=exc[0] is None, cancel_futures=True)
            self._pool = None

    # --- scoring in batches -----------------------------------------------------------------

    def scores(self, xs: list[np.ndarray]) -> list[Score]:
        """Scores of a batch of candidates (in parallel with jobs > 1; repeats are not rescored)."""
        xs = [np.clip(np.asarray(x, dtype=float), self._lo, self._hi) for x in xs]
        out: list[Score | None] = [self._cached(x) for x in xs]
        todo = [i for i, s in enumerate(out) if s is None]
        if todo and self.evals + len(todo) > self.max_evals:
            raise _BudgetSpentError
        if self._pool is None or len(todo) == 1:
            for i in todo:
                out[i] = score(self.problem, xs[i], self._innovations)
                self._note(xs[i], out[i], self._innovations)
        else:
            futures = {self._pool.submit(_worker_score, xs[i], self._innovations): i for i in todo}
            for fut in as_completed(futures):
                i = futures[fut]
                out[i] = fut.result()
                self._note(xs[i], out[i], self._innovations)
        self.history.append(self.best_f)
        return out  # type: ignore[return-value]

    def _cached(self, x: np.ndarray) -> Score | None:
        hit = self._cache.get(_key(x))
        if hit is None or (self._innovations and not hit[1]):
            return None
        return hit[0]

    def _note(self, x: np.ndarray, s: Score, innovations: bool) -> float:
        self.evals += 1
        self._cache[_key(x)] = (s, innovations)
        f = s.value(self.problem.objective)
        if f < self.best_f:
            self.best_f, self.best_x = f, np.array(x, dtype=float)
        if self.progress is not None:
            self.progress.update(self.evals, self.best_f)
        return f

    # --- stages -----------------------------------------------------------------------------

    def run(self) -> str:
        """Fit; returns how it ended. The best candidate is in best_x / best_f."""
        try:
            x = self.match_scales(self.best_x.copy())
            if self.problem.objective == "likelihood":
                self.pattern_search(x, "likelihood")
            else:
                reserve = min(CALIBRATION_EVALS, max(self.max_evals - self.evals - 1, 0))
                self.max_evals -= reserve  # kept for the NEES calibration
                try:  # from the matching's iterate of lowest RMSE (the NEES is calibrated after)
                    x = self.gradient_stage(self._lowest("rmse", x), "rmse")
                finally:
                    self.max_evals += reserve
                self.calibrate_nees(x)
        except _BudgetSpentError:
            self.stages.append(f"evaluation budget ({self.max_evals}) spent")
            return f"evaluation budget ({self.max_evals}) spent"
        return "; ".join(self.stages[-1:]) or "done"

    def _lowest(self, objective: str, default: np.ndarray) -> np.ndarray:
        """The scored candidate with the lowest ``objective`` (``default`` if none is feasible)."""
        best, out = math.inf, default
        for key, (s, _) in self._cache.items():
            f = s.value(objective)
            if f < best:
                best, out = f, np.array(key)
        return out

    def match_scales(self, x: np.ndarray, innovations: bool = False, note: bool = True) -> np.ndarray:
        """Innovation covariance matching (Mehra 1970): multiply every input's variance scale by
        its mean NIS per dimension (1 for a consistent input) until each is within
        MATCH_TOLERANCE of 1; one replay per iteration. Returns the matched point.
        ``innovations``: the replays also collect them (the likelihood is scored on the way)."""
        idx = {k.parameter[: -len("_variance_scale")]: i for i, k in enumerate(self.problem.knobs)
               if k.index is None and k.parameter.endswith("_variance_scale")}
        if not idx:
            return x
        self._innovations = innovations  # else the Localizer's NIS sums are enough
        replays = 0
        while replays < MATCH_ITERATIONS:
            s = self.scores([x])[0]
            replays += 1
            if not s.feasible:  # back to the last feasible point (the start is scored already)
                x = self.best_x.copy()
                break
            ratios = {name: s.input_nis[name] for name in idx if name in s.input_nis}
            if all(abs(math.log(r)) < math.log(MATCH_TOLERANCE) for r in ratios.values()):
                break
            x = x.copy()
            for name, r in ratios.items():
                x[idx[name]] += math.log10(r)
            x = np.clip(x, self._lo, self._hi)
        if note:
            self.stages.append(f"covariance matching of {len(idx)} input scales: {replays} replays")
        return x

    def pattern_search(self, x: np.ndarray, objective: str) -> np.ndarray:
        """Coordinate search in decades over the knobs other than the input scales: one batch
        scores every knob PATTERN_STEPS[j] decades up and down; the improving moves are taken
        (all together, or the best one alone if that is lower), the input scales re-matched, and
        the step halved when nothing improves. A knob whose two moves change the objective by
        less than PATTERN_FTOL is dropped. For the likelihood, which is flat along the pose
        diffusion (the camera's few updates carry it), where gradient steps spent the budget.
        Returns the best point of the stage."""
        self._innovations = objective == "likelihood"
        which = [i for i in range(x.size) if not self._input_scale[i]]
        f = self.scores([x])[0].value(objective)
        moves = 0
        message = "converged"
        try:
            for step in PATTERN_STEPS:
                while which:
                    cands = []
                    for i in which:
                        for h in (step, -step):
                            xi = x.copy()
                            xi[i] = float(np.clip(x[i] + h, self._lo[i], self._hi[i]))
                            if xi[i] != x[i]:
                                cands.append((i, xi))
                    fs = [s.value(objective) for s in self.scores([c for _, c in cands])]
                    gains: dict[int, tuple[float, float]] = {}
                    spread: dict[int, float] = {}
                    for (i, xi), fi in zip(cands, fs, strict=True):
                        spread[i] = max(spread.get(i, 0.0), abs(fi - f))
                        if fi < f - PATTERN_FTOL and fi < gains.get(i, (math.inf, 0.0))[0]:
                            gains[i] = (fi, xi[i])
                    which = [i for i in which if spread.get(i, 0.0) >= PATTERN_FTOL]
                    if not gains:
                        break
                    single = min(gains, key=lambda i: gains[i][0])
                    xs = x.copy()
                    xs[single] = gains[single][1]
                    xn, fn = xs, gains[single][0]
                    if len(gains) > 1:
                        xc = x.copy()
                        for i, (_, v) in gains.items():
                            xc[i] = v
                        fc = self.scores([xc])[0].value(objective)
                        if fc < fn:
                            xn, fn = xc, fc
                    xm = self.match_scales(xn, innovations=self._innovations, note=False)
                    fm = self.scores([xm])[0].value(objective)
                    x, f = (xm, fm) if fm < fn else (xn, fn)
                    moves += 1
        except _BudgetSpentError:
            message = "evaluation budget spent"
        self.stages.append(f"coordinate search on the {objective} in steps of "
                           f"{', '.join(f'{s:g}' for s in PATTERN_STEPS)} decades: {moves} moves, {message}")
        return x

    def gradient_stage(self, x0: np.ndarray, objective: str) -> np.ndarray:
        """L-BFGS-B on ``objective`` over the knobs it depends on, from ``x0``. For "rmse" the
        common scale of every variance is held (RMSE does not depend on it; calibrate_nees sets it).
        Returns the best point of the stage."""
        from scipy.optimize import minimize

        self._innovations = objective == "likelihood"
        n = x0.size
        best = [math.inf, x0.copy()]
        active: list[int] = []
        message = "evaluation budget spent"
        try:
            grad0, best[0] = self._gradient(x0, list(range(n)), objective)
            g = np.abs(grad0)
            active = [i for i in range(n) if g[i] >= SCREEN_GRADIENT]
            if objective == "rmse":  # hold the gauge: the most sensitive input scale stays (the
                # matching set it; holding a process noise entry kept the pose diffusion at 30× the
                # hand-tuned, bag 2 RMSE 1.6×)
                held = ([i for i in active if self._input_scale[i]]
                        or [i for i in active if self._variance[i]])
                if held:
                    active.remove(max(held, key=lambda i: g[i]))
            self.fitted = [self.problem.knobs[i].name for i in active]

            def full(sub: np.ndarray) -> np.ndarray:
                out = x0.copy()
                out[active] = sub
                return out

            def fun(sub: np.ndarray) -> tuple[float, np.ndarray]:
                xf = full(sub)
                grad, f = self._gradient(xf, active, objective)
                if f < best[0]:
                    best[0], best[1] = f, xf
                return f, grad[active]

            if active:
                res = minimize(fun, x0[active], jac=True, method="L-BFGS-B",
                               bounds=list(zip(self._lo[active], self._hi[active], strict=True)),
                               options={"maxiter": 200, "ftol": GRADIENT_FTOL / max(abs(best[0]), 1.0),
                                        "gtol": GRADIENT_GTOL})
                message = f"L-BFGS-B: {res.message}"
        except _BudgetSpentError:
            pass
        self.stages.append(f"L-BFGS-B on the {objective} over {len(active)} of {n} parameters "
                           f"({', '.join(self.fitted)}): {message}")
        return best[1]

    def _gradient(self, x: np.ndarray, which: list[int], objective: str) -> tuple[np.ndarray, float]:
        """Forward differences of ``objective`` in the ``which`` coordinates (one batch)."""
        xs = [np.array(x, dtype=float)]
        steps = []
        step = GRADIENT_STEP
        for i in which:
            h = step if x[i] + step <= self._hi[i] else -step
            xi = np.array(x, dtype=float)
            xi[i] += h
            xs.append(xi)
            steps.append(h)
        fs = [s.value(objective) for s in self.scores(xs)]
        grad = np.zeros(x.size)
        for j, i in enumerate(which):
            grad[i] = (fs[j + 1] - fs[0]) / steps[j]
        return grad, fs[0]

    def calibrate_nees(self, x: np.ndarray) -> np.ndarray:
        """Multiply every variance by one factor so that the mean NEES is at the geometric centre
        of its band (estimates unchanged: only the covariance level moves); secant steps in log."""
        self._innovations = False
        u = self._variance.astype(float)
        shift, closest = 0.0, (math.inf, 0.0)
        for _ in range(CALIBRATION_EVALS):
            s = self.scores([x + shift * u])[0]
            if not s.feasible:
                break
            ratio = float(np.mean([math.log10(n / math.sqrt(b[0] * b[1]))
                                   for n, b in zip(s.nees, s.nees_band, strict=True)]))
            closest = min(closest, (abs(ratio), shift))
            if abs(ratio) < math.log10(MATCH_TOLERANCE):
                break
            shift += ratio  # NEES ∝ 1 / (the common factor)
        shift = closest[1]
        self.stages.append(f"NEES calibration: every variance ×{10.0 ** shift:.3g}")
        return np.clip(x + shift * u, self._lo, self._hi)


def _is_variance(k: Knob) -> bool:
    """A variance or variance factor (scales the covariance level), not a time constant or latency."""
    return k.unit != "s"


def _key(x: np.ndarray) -> tuple[float, ...]:
    return tuple(float(v) for v in np.round(x, 12))
