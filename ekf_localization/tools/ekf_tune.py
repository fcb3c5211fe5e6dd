"""Fit ekf_node's noise parameters to recorded bags; write the tuned YAML and a consistency report.

    ekf_tune BAG [BAG ...] --params START.yaml --out DIR [--truth-topic T] [--holdout BAG]
             [--objective auto|truth|likelihood] [--jobs N] [--max-evals N]
             [--decades D] [--bound NAME=LO:HI ...] [--scale-start Q,R] [--node-name ekf_node]

Every candidate is scored by replaying the bags through the node's own Localizer
(:func:`ekf_localization.tools.replay.replay`). What is fitted (each in log space, within
bounds that keep it a positive finite variance or factor):

* the process noise rates the model uses (``process_noise_covariance`` diagonal entries of
  the fields the model estimates, e.g. the velocity random walk);
* ``<input>_variance_scale`` of every input: a factor on the covariances its messages carry;
* with ``use_control``, the commanded-velocity variances ``control_velocity_variance``.

Objectives (smaller is better): with ground truth in every bag, log of the (x, y) position
RMSE plus penalties when the mean pose NEES leaves its χ² 95% band or an input's NIS strays
from the others'; without, the innovation negative log likelihood Σ(log det S + νᵀS⁻¹ν), each
input part's mean per update summed. The fit is staged: covariance matching of the input scales
(each scale times its input's mean NIS per dimension, a few replays), then on the likelihood a
coordinate search in decades (each batch of moves in parallel), or on the RMSE scipy's
L-BFGS-B (bounded quasi-Newton; forward-difference gradients one batch in parallel) with the
common scale of the variances held, then set so that the NEES is in its band.
docs/ekf_tune.md has the details and the measured figures.

Writes DIR/tuned.yaml (config/ekf.yaml's format), DIR/report.md and its PNGs. Exit status 0;
2 on bad input (one line on stderr); 130 after Ctrl-C (the best configuration so far is written).
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.measurements import FIELD_NAMES, N_FIELDS
from ekf_localization.models.registry import MODELS
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml
from ekf_localization.tools import bag_io, extras
from ekf_localization.tools.consistency import InnovationLog, negative_log_likelihood, pose_nees
from ekf_localization.tools.evaluation import Trajectory, rmse
from ekf_localization.tools.replay import ReplayInput, abs_topic, read_replay_input, replay

PROG = "ekf_tune"
DEFAULT_TRUTH_TOPIC = "/ground_truth/odom"
INFEASIBLE = 1e3  # objective of a candidate whose replay diverged or failed (finite: L-BFGS-B needs it)
NEES_PENALTY_WEIGHT = 4.0  # per (log of the factor outside the band)²
# truth objective: each input's NIS per dimension stays within this factor of the inputs' common
# (geometric mean) level, else NEES_PENALTY_WEIGHT · (log of the factor beyond)² per input. Without it
# the RMSE fit on a 20 s bag that starts at a known pose switched the camera off (pose0 scale ×3e5,
# NIS 0.0009): dead reckoning drifts less than the camera's 3-9 cm noise in 20 s.
NIS_SPREAD_TOLERANCE = 1.5
GRADIENT_STEP = 0.02  # forward-difference step in log10 of each parameter (≈ 4.7 %)
GRADIENT_FTOL = 1e-3  # L-BFGS-B: stop when an iteration improves the objective by < this (absolute:
# 0.1 % of the RMSE; scipy's ftol is relative to |f|)
GRADIENT_GTOL = 1e-3
PATTERN_STEPS = (1.0, 0.5, 0.25)  # coordinate search (likelihood): decades per move
PATTERN_FTOL = 1e-3  # ... a move must improve the objective by this much
SCREEN_GRADIENT = 1e-4  # a knob whose first derivative (objective per decade) is below this is held
TIMING_DECADES = 1.0  # default bounds of time constants and the latency (with --fit-timing)
MATCH_ITERATIONS = 8  # covariance matching: replays at most
MATCH_TOLERANCE = 1.05  # ... until every input's NIS per dimension is within this factor of 1
CALIBRATION_EVALS = 3  # NEES calibration: replays at most
DEFAULT_DECADES = 6.0  # default bounds: this many decades either side of each start value
VARIANCE_LIMITS = (1e-15, 1e6)  # absolute limits of any fitted variance or factor
_FIELD_UNIT = {**dict.fromkeys(range(0, 3), "m"), **dict.fromkeys(range(3, 6), "rad"),
               **dict.fromkeys(range(6, 9), "m/s"), **dict.fromkeys(range(9, 12), "rad/s"),
               **dict.fromkeys(range(12, 15), "m/s²")}


class UsageError(Exception):
    """Bad input to the tool: printed as one line, exit status 2."""


class _BudgetSpentError(Exception):
    """The evaluation budget is spent."""


@dataclass(frozen=True)
class Knob:
    """One fitted parameter: where it lives in the flat parameter dict, its unit and bounds."""

    name: str  # shown in the report and used by --bound, e.g. "process_noise_covariance[vx]"
    parameter: str  # YAML parameter
    index: int | None  # element of a list parameter, or None for a scalar
    unit: str
    start: float
    lower: float
    upper: float
    tied: tuple[int, ...] = ()  # further elements of the list that take the same value

    def get(self, values: dict[str, Any]) -> float:
        v = values[self.parameter]
        return float(v if self.index is None else v[self.index])

    def set(self, values: dict[str, Any], value: float) -> None:
        if self.index is None:
            values[self.parameter] = float(value)
        else:
            lst = [float(x) for x in values[self.parameter]]
            for i in (self.index, *self.tied):
                lst[i] = float(value)
            values[self.parameter] = lst


def effective_values(values: dict[str, Any], config: EkfConfig) -> dict[str, Any]:
    """``values`` with the list parameters ekf_tune fits filled in from their defaults."""
    out = dict(values)
    out.setdefault("process_noise_covariance", [float(x) for x in config.process_noise_covariance.ravel()])
    out.setdefault("control_velocity_variance", [float(x) for x in config.control_velocity_variance])
    out.setdefault("control_time_constant", [float(x) for x in config.control_time_constant])
    out.setdefault("control_latency", float(config.control_latency))
    for inp in config.inputs:
        out.setdefault(f"{inp.name}_variance_scale", float(inp.variance_scale))
    return out


def make_knobs(values: dict[str, Any], config: EkfConfig, decades: float,
               bounds: dict[str, tuple[float, float]], fit_timing: bool = False,
               tie_position: bool = True) -> list[Knob]:
    """The parameters to fit, with bounds ``decades`` around the start unless given in ``bounds``.

    A zero start variance is left out (log space cannot leave zero; it is reported as fixed).
    ``tie_position``: the x and y pose diffusion are one knob ("process_noise_covariance[x,y]")
    when the start gives them the same value (a world-frame rate has no preferred direction; two
    free knobs over-fit one bag: x ×8 and y ×0.2 of the hand-tuned, bag 2 RMSE 1.14×).
    ``fit_timing``: also the drive's time constants and the command latency (TIMING_DECADES
    either side of the start): properties of the drive, not noise, and on a short bag an
    RMSE fit moves them far from the truth (the latency from the simulator's 20 ms to 0).
    """
    knobs: list[Knob] = []

    def add(name: str, parameter: str, index: int | None, unit: str, tied: tuple[int, ...] = ()) -> None:
        probe = Knob(name, parameter, index, unit, 0.0, 0.0, 0.0, tied)
        start = probe.get(values)
        if not (math.isfinite(start) and start > 0.0):
            return
        d = TIMING_DECADES if unit == "s" else decades
        lo, hi = bounds.get(name, (start * 10.0 ** -d, start * 10.0 ** d))
        lo, hi = max(lo, VARIANCE_LIMITS[0]), min(hi, VARIANCE_LIMITS[1])
        if not (lo < hi):
            raise UsageError(f"bounds of {name} cannot be met: [{lo:g}, {hi:g}] is empty "
                             f"(variances are limited to [{VARIANCE_LIMITS[0]:g}, {VARIANCE_LIMITS[1]:g}])")
        knobs.append(Knob(name, parameter, index, unit, start, lo, hi, tied))

    spec = MODELS[config.model]
    fields = list(spec.state_fields + spec.input_fields)
    q = values["process_noise_covariance"]
    tie_xy = tie_position and 0 in fields and 1 in fields and float(q[0]) == float(q[N_FIELDS + 1])
    for f in fields:
        # an input field's Q entry (differential: ax) is that input's variance, not a rate
        u = _FIELD_UNIT[f] if "/" not in _FIELD_UNIT[f] else f"({_FIELD_UNIT[f]})"
        unit = f"{u}²" if f in spec.input_fields else f"{u}²/s"
        if tie_xy and f == 1:
            continue
        if tie_xy and f == 0:  # the map frame has no preferred direction: one knob for x and y
            add("process_noise_covariance[x,y]", "process_noise_covariance", 0, unit, (N_FIELDS + 1,))
            continue
        add(f"process_noise_covariance[{FIELD_NAMES[f]}]", "process_noise_covariance", f * N_FIELDS + f, unit)
    for inp in config.inputs:
        add(f"{inp.name}_variance_scale", f"{inp.name}_variance_scale", None, "-")
    if config.use_control:
        for i in (0, 1, 5):
            u = "(m/s)²" if i < 3 else "(rad/s)²"
            add(f"control_velocity_variance[v{FIELD_NAMES[i]}]", "control_velocity_variance", i, u)
        if fit_timing:
            for i in (0, 1, 5):  # the drive response (0 = none, a different model: left as it is)
                add(f"control_time_constant[v{FIELD_NAMES[i]}]", "control_time_constant", i, "s")
            add("control_latency", "control_latency", None, "s")
    unknown = sorted(set(bounds) - {k.name for k in knobs})
    if unknown:
        raise UsageError(f"--bound {unknown[0]}: not a fitted parameter (fitted: "
                         + ", ".join(k.name for k in knobs) + ")")
    for k in knobs:
        if not (k.lower <= k.start <= k.upper):
            raise UsageError(f"bounds of {k.name} cannot be met: the start value {k.start:g} is outside "
                             f"[{k.lower:g}, {k.upper:g}]")
    if not knobs:
        raise UsageError("nothing to fit: every process noise entry and variance scale is zero")
    return knobs


def scaled_noise(values: dict[str, Any], config: EkfConfig, process_noise_factor: float,
                 variance_scale_factor: float) -> dict[str, Any]:
    """``values`` with every process noise entry and every input's variance scale multiplied
    (a deliberately bad start for experiments: e.g. ×100 and ×0.01)."""
    out = effective_values(values, config)
    out["process_noise_covariance"] = [float(v) * process_noise_factor
                                       for v in out["process_noise_covariance"]]
    for inp in config.inputs:
        key = f"{inp.name}_variance_scale"
        out[key] = float(out[key]) * variance_scale_factor
    return out


# --- scoring ----------------------------------------------------------------------------------

@dataclass
class BagData:
    """One bag read once: the replay input and the ground truth (None without)."""

    path: Path
    replay_input: ReplayInput
    truth: Trajectory | None


@dataclass
class Score:
    """One candidate replayed over every bag (per-bag lists in the order of ``Problem.bags``)."""

    feasible: bool
    rmse_xy: list[float] = field(default_factory=list)
    nees: list[float] = field(default_factory=list)
    nees_band: list[tuple[float, float]] = field(default_factory=list)
    nll_per_update: float = float("nan")  # with innovations
    nll_per_input: float = float("nan")  # Σ over input parts of their mean NLL per update
    input_nis: dict[str, float] = field(default_factory=dict)  # input -> Σ NIS / Σ m (Localizer.nis)

    def value(self, objective: str) -> float:
        """The objective ``objective`` ("truth", "rmse" or "likelihood"); INFEASIBLE if unusable."""
        if not self.feasible:
            return INFEASIBLE
        if objective == "likelihood":
            # Σ over input parts of each part's mean (log det S + NIS) per update, not the mean over
            # all updates (where the camera's 3 % of the updates, the only ones that see the pose
            # diffusion, are drowned). With a correct model every update's term is smallest at the
            # true noise, so any positive weights have the same minimiser.
            f = self.nll_per_input
        elif objective == "rmse":
            f = (float(np.mean(np.log(self.rmse_xy))) + nis_spread_penalty(self.input_nis)
                 if self.rmse_xy else math.nan)
        else:
            f = (float(np.mean([math.log(r) + nees_penalty(n, b) for r, n, b
                                in zip(self.rmse_xy, self.nees, self.nees_band, strict=True)]))
                 + nis_spread_penalty(self.input_nis) if self.rmse_xy else math.nan)
        return f if math.isfinite(f) else INFEASIBLE


@dataclass
class Problem:
    """What a worker needs to score a candidate (shared with forked workers)."""

    values: dict[str, Any]
    knobs: list[Knob]
    bags: list[BagData]
    objective: str  # "truth" | "likelihood"

    def values_at(self, x: np.ndarray) -> dict[str, Any]:
        out = dict(self.values)
        for k, xi in zip(self.knobs, x, strict=True):
            k.set(out, float(np.clip(10.0 ** xi, k.lower, k.upper)))
        return out

    def config_at(self, x: np.ndarray) -> EkfConfig:
        return parse_ekf_config(self.values_at(x), MODELS)

    def log_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.log10([k.lower for k in self.knobs]), np.log10([k.upper for k in self.knobs])


def nees_penalty(mean_nees: float, band: tuple[float, float]) -> float:
    """0 inside the band, else NEES_PENALTY_WEIGHT · (log of the factor outside it)²: smooth (C¹)
    in log space, so a gradient method sees it."""
    lo, hi = band
    if mean_nees > hi:
        return NEES_PENALTY_WEIGHT * math.log(mean_nees / hi) ** 2
    if mean_nees < lo:
        return NEES_PENALTY_WEIGHT * math.log(lo / mean_nees) ** 2
    return 0.0


def nis_spread_penalty(input_nis: dict[str, float]) -> float:
    """Σ over inputs of NEES_PENALTY_WEIGHT · (log of the factor by which its NIS per dimension is
    beyond NIS_SPREAD_TOLERANCE of the inputs' geometric mean)². Invariant to scaling every
    variance by one factor (the NEES calibration's direction); 0 with fewer than two inputs."""
    if len(input_nis) < 2:
        return 0.0
    logs = np.log(list(input_nis.values()))
    excess = np.maximum(np.abs(logs - logs.mean()) - math.log(NIS_SPREAD_TOLERANCE), 0.0)
    return float(NEES_PENALTY_WEIGHT * np.sum(excess ** 2))


def score(problem: Problem, x: np.ndarray, innovations: bool | None = None) -> Score:
    """Replay every bag with the candidate; infeasible (never raising) if anything diverges.

    ``innovations``: also collect the innovations (likelihood, NIS per input); default: when
    the problem's objective is the likelihood.
    """
    if innovations is None:
        innovations = problem.objective == "likelihood"
    try:
        config = problem.config_at(x)
    except (ParameterError, ValueError):
        return Score(False)
    out = Score(True)
    total_nll, total_updates = 0.0, 0
    part_nll: dict[str, list[float]] = {}  # "<input> <part>" -> [Σ NLL, updates]
    nis_sums: dict[str, list[float]] = {}
    for bag in problem.bags:
        log = InnovationLog() if innovations else None
        try:
            with np.errstate(all="ignore"):
                res = replay(bag.replay_input, config, innovation_listener=log)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return Score(False)
        loc = res.localizer
        if loc.predict_failures or loc.nonfinite_outputs or not res.estimates:
            return Score(False)
        if log is not None:
            per = log.per_input()
            nll, count = negative_log_likelihood(per)
            total_nll += nll
            total_updates += count
            for label, inn in per.items():
                acc = part_nll.setdefault(label, [0.0, 0])
                acc[0] += float(np.sum(inn.logdet + inn.nis))
                acc[1] += inn.nis.size
        for key, (nis_sum, count, dim) in loc.nis.items():  # the Localizer's own sums (first pass)
            acc = nis_sums.setdefault(key.split("/")[0], [0.0, 0.0])
            acc[0] += nis_sum
            acc[1] += count * dim
        if bag.truth is not None:
            traj = res.trajectory()
            r = rmse(traj, bag.truth)["xy"]
            nees = pose_nees(traj, bag.truth)
            if not (math.isfinite(r) and math.isfinite(nees.mean) and r > 0.0):
                return Score(False)
            out.rmse_xy.append(r)
            out.nees.append(nees.mean)
            out.nees_band.append(nees.band)
    out.nll_per_update = total_nll / total_updates if total_updates else float("nan")
    out.nll_per_input = (sum(v / n for v, n in part_nll.values() if n) if part_nll else float("nan"))
    out.input_nis = {name: s / m for name, (s, m) in nis_sums.items() if m > 0}
    if innovations and not math.isfinite(out.nll_per_update):
        return Score(False)
    if not all(math.isfinite(v) and v > 0 for v in out.input_nis.values()):
        return Score(False)
    return out


_PROBLEM: Problem | None = None  # set in the parent before the pool forks


def _worker_init() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle


def _worker_score(x: np.ndarray, innovations: bool) -> Score:
    assert _PROBLEM is not None
    return score(_PROBLEM, x, innovations)


# --- the optimiser ----------------------------------------------------------------------------

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
        # scored here first: compiles the kernels before forking
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


# --- input checks -----------------------------------------------------------------------------

def load_bag(path: Path, config: EkfConfig, truth_topic: str | None) -> BagData:
    """Read a bag for tuning; UsageError if it is unreadable or lacks a configured topic."""
    if not path.exists():
        raise UsageError(f"no bag at {path}")
    try:
        types = bag_io.topic_types(path)
    except bag_io.BagError as exc:
        raise UsageError(str(exc)) from None
    missing = [f"{inp.name} ({abs_topic(inp.topic)})" for inp in config.inputs
               if abs_topic(inp.topic) not in types]
    if missing:
        raise UsageError(f"bag {path} has no messages for the configured input(s) " + ", ".join(missing)
                         + "; its topics: " + ", ".join(sorted(types)))
    truth = None
    if truth_topic is not None and abs_topic(truth_topic) in types:
        truth = bag_io.read_odometry(path, abs_topic(truth_topic))
    try:
        data = read_replay_input(path, config)
    except bag_io.BagError as exc:
        raise UsageError(str(exc)) from None
    if not data.events:
        raise UsageError(f"bag {path} has no messages on the configured input topics")
    return BagData(path, data, truth)


def _parse_factors(text: str) -> tuple[float, float]:
    try:
        q, r = (float(v) for v in text.split(","))
    except ValueError:
        q = r = math.nan
    if not (math.isfinite(q) and math.isfinite(r) and q > 0 and r > 0):
        raise UsageError(f"--scale-start {text!r}: expected Q_FACTOR,R_FACTOR, two finite numbers > 0")
    return q, r


def parse_bounds(items: list[str]) -> dict[str, tuple[float, float]]:
    out = {}
    for item in items:
        name, sep, rng = item.partition("=")
        lo_s, sep2, hi_s = rng.partition(":")
        try:
            lo, hi = float(lo_s), float(hi_s)
        except ValueError:
            lo = hi = math.nan
        if not (sep and sep2 and name) or not (math.isfinite(lo) and math.isfinite(hi)):
            raise UsageError(f"--bound {item!r}: expected NAME=LO:HI with finite numbers")
        if not (0.0 < lo < hi):
            raise UsageError(f"--bound {item!r} cannot be met: a variance needs 0 < LO < HI")
        out[name.strip()] = (lo, hi)
    return out


# --- output -----------------------------------------------------------------------------------

def write_tuned_yaml(path: Path, values: dict[str, Any], node_name: str, header: str) -> None:
    """The parameters as a ROS 2 params file (floats always with a decimal point or exponent)."""

    class _Dumper(yaml.SafeDumper):
        pass

    def _float(dumper, v: float):
        text = repr(float(v))
        if "e" in text and "." not in text.split("e")[0]:
            mant, exp = text.split("e")
            text = f"{mant}.0e{exp}"
        return dumper.represent_scalar("tag:yaml.org,2002:float", text)

    _Dumper.add_representer(float, _float)
    lines = [f"{node_name}:", "  ros__parameters:"]
    for key, value in values.items():
        if isinstance(value, list) and len(value) == N_FIELDS * N_FIELDS:  # a 15x15 matrix: 15 per line
            rows = [", ".join(_float(_Dumper(None), float(v)).value for v in value[i:i + N_FIELDS])
                    for i in range(0, len(value), N_FIELDS)]
            pad = " " * (len(key) + 7)
            lines.append(f"    {key}: [" + (",\n" + pad).join(rows) + "]")
            continue
        flow = None if isinstance(value, list) else False  # lists inline, as config/ekf.yaml writes them
        text = yaml.dump({key: value}, Dumper=_Dumper, sort_keys=False, default_flow_style=flow,
                         width=1_000_000, allow_unicode=True).rstrip("\n")
        lines.extend("    " + line for line in text.splitlines())
    path.write_text(header + "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bags", type=Path, nargs="+", metavar="BAG", help="bags to fit on")
    parser.add_argument("--params", type=Path, required=True, help="start configuration (ekf_node YAML)")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--node-name", default="ekf_node")
    parser.add_argument("--truth-topic", default=None,
                        help=f"ground-truth nav_msgs/Odometry topic (default {DEFAULT_TRUTH_TOPIC} "
                        "when present)")
    parser.add_argument("--objective", choices=("auto", "truth", "likelihood"), default="auto",
                        help="auto: truth when every bag has the truth topic, else likelihood")
    parser.add_argument("--holdout", type=Path, action="append", default=[],
                        help="a bag not fitted on, reported before/after")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes")
    parser.add_argument("--max-evals", type=int, default=60, help="replays of the bag set, at most")
    parser.add_argument("--decades", type=float, default=DEFAULT_DECADES,
                        help="default bounds: this many decades either side of each start value")
    parser.add_argument("--scale-start", default=None, metavar="Q_FACTOR,R_FACTOR",
                        help="multiply the start's process noise by Q_FACTOR and every input's variance "
                        "scale by R_FACTOR first (a deliberately bad start, e.g. 100,0.01)")
    parser.add_argument("--fit-timing", action="store_true",
                        help="also fit control_latency and the non-zero control_time_constant entries "
                        f"(±{TIMING_DECADES:g} decade)")
    parser.add_argument("--separate-xy", action="store_true",
                        help="fit the x and y pose diffusion separately (default: one knob when the "
                        "start gives them the same value)")
    parser.add_argument("--bound", action="append", default=[], metavar="NAME=LO:HI",
                        help="bounds of one fitted parameter, e.g. odom0_variance_scale=0.1:100.0")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if extras.check(PROG, "rosbags"):
        return 2
    try:
        return _run(args)
    except UsageError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    if args.jobs < 1 or args.max_evals < 1 or not (args.decades > 0):
        raise UsageError("--jobs and --max-evals must be >= 1 and --decades > 0")
    try:
        values = parameters_from_yaml(args.params, args.node_name)
        start_config = parse_ekf_config(values, MODELS)
    except ParameterError as exc:
        raise UsageError(f"start config {args.params} does not load: {exc}") from None
    values = effective_values(values, start_config)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.scale_start is not None:
        factors = _parse_factors(args.scale_start)
        values = scaled_noise(values, start_config, *factors)
        start_config = parse_ekf_config(values, MODELS)
        write_tuned_yaml(args.out / "start.yaml", values, args.node_name,
                         f"# ekf_tune: {args.params} with --scale-start {args.scale_start}\n")
    knobs = make_knobs(values, start_config, args.decades, parse_bounds(args.bound), args.fit_timing,
                       tie_position=not args.separate_xy)
    truth_topic = args.truth_topic or DEFAULT_TRUTH_TOPIC
    bags = [load_bag(b, start_config, truth_topic) for b in args.bags]
    holdouts = [load_bag(b, start_config, truth_topic) for b in args.holdout]
    objective = args.objective
    if objective == "auto":
        objective = "truth" if all(b.truth is not None for b in bags) else "likelihood"
    if objective == "truth":
        lacking = [str(b.path) for b in bags if b.truth is None]
        if lacking:
            raise UsageError(f"objective 'truth' needs {truth_topic} in every bag; missing in "
                             + ", ".join(lacking))
    elif args.truth_topic is not None and any(b.truth is None for b in bags):
        raise UsageError(f"--truth-topic {args.truth_topic} is not in every bag")
    problem = Problem(values, knobs, bags, objective)

    progress = Progress(args.max_evals)
    t0 = time.monotonic()
    interrupted = False
    tuner = Tuner(problem, args.jobs, args.max_evals, progress)
    try:
        with tuner:
            ended = tuner.run()
    except KeyboardInterrupt:
        interrupted = True
        ended = "interrupted (Ctrl-C): the best configuration so far"
    progress.close()
    seconds = time.monotonic() - t0
    best_values = problem.values_at(tuner.best_x)
    scaled = f" with --scale-start {args.scale_start}" if args.scale_start else ""
    header = (f"# ekf_tune: fitted from {', '.join(str(b) for b in args.bags)} starting from {args.params}"
              f"{scaled}\n"
              f"# objective {objective}, {tuner.evals} evaluations in {seconds:.1f} s, {ended}\n"
              f"# report: report.md next to this file (docs/ekf_tune.md explains it)\n")
    write_tuned_yaml(args.out / "tuned.yaml", best_values, args.node_name, header)
    print(f"{PROG}: {ended}; {tuner.evals} evaluations in {seconds:.1f} s, best objective {tuner.best_f:.5g}")
    print(f"{PROG}: wrote {args.out / 'tuned.yaml'}")
    if interrupted:
        return 130
    from ekf_localization.tools.tune_report import write_report

    write_report(args.out, problem, tuner, holdouts, ended, seconds, args)
    print(f"{PROG}: wrote {args.out / 'report.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
