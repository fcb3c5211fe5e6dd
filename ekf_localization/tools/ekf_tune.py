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
RMSE plus a penalty when the mean pose NEES leaves its χ² 95% band; without, the innovation
negative log likelihood Σ(log det S + νᵀS⁻¹ν) per update. Optimiser: scipy's L-BFGS-B (bounded
quasi-Newton) with forward-difference gradients computed as one batch of candidates in
parallel worker processes. docs/ekf_tune.md has the details and the measured figures.

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
from ekf_localization.tools import bag_io
from ekf_localization.tools.consistency import InnovationLog, negative_log_likelihood, pose_nees
from ekf_localization.tools.evaluation import Trajectory, rmse
from ekf_localization.tools.replay import ReplayInput, abs_topic, read_replay_input, replay

PROG = "ekf_tune"
DEFAULT_TRUTH_TOPIC = "/ground_truth/odom"
INFEASIBLE = 1e3  # objective of a candidate whose replay diverged or failed (finite: L-BFGS-B needs it)
NEES_PENALTY_WEIGHT = 4.0  # per (log of the factor outside the band)²
GRADIENT_STEP = 0.02  # forward-difference step in log10 of each parameter (≈ 4.7 %)
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

    def get(self, values: dict[str, Any]) -> float:
        v = values[self.parameter]
        return float(v if self.index is None else v[self.index])

    def set(self, values: dict[str, Any], value: float) -> None:
        if self.index is None:
            values[self.parameter] = float(value)
        else:
            lst = [float(x) for x in values[self.parameter]]
            lst[self.index] = float(value)
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
               bounds: dict[str, tuple[float, float]]) -> list[Knob]:
    """The parameters to fit, with bounds ``decades`` around the start unless given in ``bounds``.

    A zero start variance is left out (log space cannot leave zero; it is reported as fixed).
    """
    knobs: list[Knob] = []

    def add(name: str, parameter: str, index: int | None, unit: str) -> None:
        probe = Knob(name, parameter, index, unit, 0.0, 0.0, 0.0)
        start = probe.get(values)
        if not (math.isfinite(start) and start > 0.0):
            return
        lo, hi = bounds.get(name, (start * 10.0 ** -decades, start * 10.0 ** decades))
        lo, hi = max(lo, VARIANCE_LIMITS[0]), min(hi, VARIANCE_LIMITS[1])
        if not (lo < hi):
            raise UsageError(f"bounds of {name} cannot be met: [{lo:g}, {hi:g}] is empty "
                             f"(variances are limited to [{VARIANCE_LIMITS[0]:g}, {VARIANCE_LIMITS[1]:g}])")
        knobs.append(Knob(name, parameter, index, unit, start, lo, hi))

    spec = MODELS[config.model]
    for f in spec.state_fields + spec.input_fields:
        # an input field's Q entry (differential: ax) is that input's variance, not a rate
        u = _FIELD_UNIT[f] if "/" not in _FIELD_UNIT[f] else f"({_FIELD_UNIT[f]})"
        unit = f"{u}²" if f in spec.input_fields else f"{u}²/s"
        add(f"process_noise_covariance[{FIELD_NAMES[f]}]", "process_noise_covariance", f * N_FIELDS + f, unit)
    for inp in config.inputs:
        add(f"{inp.name}_variance_scale", f"{inp.name}_variance_scale", None, "-")
    if config.use_control:
        for i in (0, 1, 5):
            u = "(m/s)²" if i < 3 else "(rad/s)²"
            add(f"control_velocity_variance[v{FIELD_NAMES[i]}]", "control_velocity_variance", i, u)
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
    """One candidate replayed over every bag."""

    objective: float
    feasible: bool
    rmse_xy: list[float] = field(default_factory=list)
    nees: list[float] = field(default_factory=list)
    nll_per_update: float = float("nan")


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


def nees_penalty(mean_nees: float, band: tuple[float, float]) -> float:
    """0 inside the band, else NEES_PENALTY_WEIGHT · (log of the factor outside it)²."""
    lo, hi = band
    if mean_nees > hi:
        return NEES_PENALTY_WEIGHT * math.log(mean_nees / hi) ** 2
    if mean_nees < lo:
        return NEES_PENALTY_WEIGHT * math.log(lo / mean_nees) ** 2
    return 0.0


def score(problem: Problem, x: np.ndarray) -> Score:
    """Replay every bag with the candidate; infeasible (never raising) if anything diverges."""
    try:
        config = problem.config_at(x)
    except (ParameterError, ValueError):
        return Score(INFEASIBLE, False)
    out = Score(0.0, True)
    total_nll, total_updates, truth_terms = 0.0, 0, []
    for bag in problem.bags:
        log = InnovationLog() if problem.objective == "likelihood" else None
        try:
            with np.errstate(all="ignore"):
                res = replay(bag.replay_input, config, innovation_listener=log)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return Score(INFEASIBLE, False)
        loc = res.localizer
        if loc.predict_failures or loc.nonfinite_outputs or not res.estimates:
            return Score(INFEASIBLE, False)
        if log is not None:
            nll, count = negative_log_likelihood(log.per_input())
            total_nll += nll
            total_updates += count
        if bag.truth is not None:
            traj = res.trajectory()
            r = rmse(traj, bag.truth)["xy"]
            nees = pose_nees(traj, bag.truth)
            out.rmse_xy.append(r)
            out.nees.append(nees.mean)
            if not (math.isfinite(r) and math.isfinite(nees.mean) and r > 0.0):
                return Score(INFEASIBLE, False)
            truth_terms.append(math.log(r) + nees_penalty(nees.mean, nees.band))
    out.nll_per_update = total_nll / total_updates if total_updates else float("nan")
    if problem.objective == "truth":
        out.objective = float(np.mean(truth_terms))
    else:
        out.objective = out.nll_per_update
    if not math.isfinite(out.objective):
        return Score(INFEASIBLE, False)
    return out


_PROBLEM: Problem | None = None  # set in the parent before the pool forks


def _worker_init() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle


def _worker_objective(x: np.ndarray) -> float:
    assert _PROBLEM is not None
    return score(_PROBLEM, x).objective


# --- the optimiser ----------------------------------------------------------------------------

class Progress:
    """One stderr line: evaluations done, best objective, time left (rewritten in place)."""

    def __init__(self, budget: int, stream=sys.stderr) -> None:
        self.budget = budget
        self.done = 0
        self.best = math.inf
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
                f"best {best:.5g}  {elapsed:.0f} s elapsed, ≤{left:.0f} s left")
        self._stream.write(("\r" + line) if self._tty else (line + "\n"))
        self._stream.flush()

    def close(self) -> None:
        if self._tty:
            self._stream.write("\n")
            self._stream.flush()


class Tuner:
    """L-BFGS-B over log10 of the knobs; every candidate scored once, batches in parallel."""

    def __init__(self, problem: Problem, jobs: int, max_evals: int, progress: Progress | None = None) -> None:
        self.problem = problem
        self.jobs = max(1, jobs)
        self.max_evals = max_evals
        self.progress = progress
        self.evals = 0
        self.best_x = np.log10([k.start for k in problem.knobs])
        self.best_f = math.inf
        self.history: list[float] = []  # best objective after each batch
        self._pool: ProcessPoolExecutor | None = None
        self._cache: dict[tuple[float, ...], float] = {}

    def __enter__(self) -> Tuner:
        global _PROBLEM
        x0 = self.best_x.copy()
        self.start_f = _worker_objective_local(self.problem, x0)  # compiles the kernels before forking
        self._note(x0, self.start_f)
        if self.jobs > 1:
            _PROBLEM = self.problem
            ctx = multiprocessing.get_context("fork")
            self._pool = ProcessPoolExecutor(self.jobs, mp_context=ctx, initializer=_worker_init)
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=exc[0] is None, cancel_futures=True)
            self._pool = None

    def evaluate(self, xs: list[np.ndarray]) -> list[float]:
        """Objectives of a batch of candidates (in parallel with jobs > 1; repeats are not rescored)."""
        if self.evals >= self.max_evals:
            raise _BudgetSpentError
        fs = [self._cache.get(_key(x), math.nan) for x in xs]
        todo = [i for i, f in enumerate(fs) if math.isnan(f)]
        if self._pool is None:
            for i in todo:
                fs[i] = _worker_objective_local(self.problem, xs[i])
                self._note(xs[i], fs[i])
        else:
            futures = {self._pool.submit(_worker_objective, xs[i]): i for i in todo}
            for fut in as_completed(futures):
                i = futures[fut]
                fs[i] = fut.result()
                self._note(xs[i], fs[i])
        self.history.append(self.best_f)
        return fs

    def _note(self, x: np.ndarray, f: float) -> None:
        self.evals += 1
        self._cache[_key(x)] = f
        if f < self.best_f:
            self.best_f, self.best_x = f, np.array(x, dtype=float)
        if self.progress is not None:
            self.progress.update(self.evals, self.best_f)

    def _fun_and_grad(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        lo, hi = self._bounds()
        xs = [np.array(x, dtype=float)]
        steps = []
        for i in range(x.size):
            h = GRADIENT_STEP if x[i] + GRADIENT_STEP <= hi[i] else -GRADIENT_STEP
            xi = np.array(x, dtype=float)
            xi[i] += h
            xs.append(xi)
            steps.append(h)
        fs = self.evaluate(xs)
        grad = np.array([(fs[i + 1] - fs[0]) / steps[i] for i in range(x.size)])
        return fs[0], grad

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        ks = self.problem.knobs
        return np.log10([k.lower for k in ks]), np.log10([k.upper for k in ks])

    def run(self) -> str:
        """Minimise; returns how it ended. The best candidate is in best_x / best_f."""
        from scipy.optimize import minimize

        lo, hi = self._bounds()
        x0 = np.clip(self.best_x, lo, hi)
        try:
            res = minimize(self._fun_and_grad, x0, jac=True, method="L-BFGS-B",
                           bounds=list(zip(lo, hi, strict=True)),
                           options={"maxiter": 1000, "ftol": 1e-6, "gtol": 1e-5})
        except _BudgetSpentError:
            return f"evaluation budget ({self.max_evals}) spent"
        return f"L-BFGS-B: {res.message}"


def _key(x: np.ndarray) -> tuple[float, ...]:
    return tuple(float(v) for v in np.round(x, 12))


def _worker_objective_local(problem: Problem, x: np.ndarray) -> float:
    return score(problem, x).objective


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
    parser.add_argument("--max-evals", type=int, default=300, help="replays of the bag set, at most")
    parser.add_argument("--decades", type=float, default=3.0,
                        help="default bounds: this many decades either side of each start value")
    parser.add_argument("--scale-start", default=None, metavar="Q_FACTOR,R_FACTOR",
                        help="multiply the start's process noise by Q_FACTOR and every input's variance "
                        "scale by R_FACTOR first (a deliberately bad start, e.g. 100,0.01)")
    parser.add_argument("--bound", action="append", default=[], metavar="NAME=LO:HI",
                        help="bounds of one fitted parameter, e.g. odom0_variance_scale=0.1:100.0")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
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
    knobs = make_knobs(values, start_config, args.decades, parse_bounds(args.bound))
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
