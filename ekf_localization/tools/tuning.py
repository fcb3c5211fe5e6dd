"""ekf_tune's problem: the fitted parameters (knobs), the objectives and how a candidate is scored.

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
input part's mean per update summed. The staged search over the knobs is
:mod:`ekf_localization.tools.tune_search`; docs/ekf_tune.md has the details and the measured
figures.

The command line (:mod:`ekf_localization.tools.ekf_tune`) reads the bags and writes the tuned
YAML; :mod:`ekf_localization.tools.tune_report` the report. Both import this module, which
imports neither.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.measurements import FIELD_NAMES, N_FIELDS
from ekf_localization.models.registry import MODELS
from ekf_localization.ros.ekf_node_settings import EkfNodeSettings
from ekf_localization.ros.ekf_parameters import parse_ekf_settings
from ekf_localization.ros.parameters import ParameterError
from ekf_localization.tools.consistency import InnovationLog, negative_log_likelihood, pose_nees
from ekf_localization.tools.evaluation import Trajectory, rmse
from ekf_localization.tools.replay import ReplayInput, replay

PROG = "ekf_tune"
INFEASIBLE = 1e3  # objective of a candidate whose replay diverged or failed (finite: L-BFGS-B needs it)
NEES_PENALTY_WEIGHT = 4.0  # per (log of the factor outside the band)²
# truth objective: each input's NIS per dimension stays within this factor of the inputs' common
# (geometric mean) level, else NEES_PENALTY_WEIGHT · (log of the factor beyond)² per input. Without it
# the RMSE fit on a 20 s bag that starts at a known pose switched the camera off (pose0 scale ×3e5,
# NIS 0.0009): dead reckoning drifts less than the camera's 3-9 cm noise in 20 s.
NIS_SPREAD_TOLERANCE = 1.5
TIMING_DECADES = 1.0  # default bounds of time constants and the latency (with --fit-timing)
DEFAULT_DECADES = 6.0  # default bounds: this many decades either side of each start value
VARIANCE_LIMITS = (1e-15, 1e6)  # absolute limits of any fitted variance or factor
_FIELD_UNIT = {**dict.fromkeys(range(0, 3), "m"), **dict.fromkeys(range(3, 6), "rad"),
               **dict.fromkeys(range(6, 9), "m/s"), **dict.fromkeys(range(9, 12), "rad/s"),
               **dict.fromkeys(range(12, 15), "m/s²")}


class UsageError(Exception):
    """Bad input to the tool: printed as one line, exit status 2."""


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

    def settings_at(self, x: np.ndarray) -> EkfNodeSettings:
        """The node's settings (its Localizer config and output rate) with the knobs at ``x``."""
        return parse_ekf_settings(self.values_at(x), MODELS)

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
        settings = problem.settings_at(x)
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
                res = replay(bag.replay_input, settings, innovation_listener=log)
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
