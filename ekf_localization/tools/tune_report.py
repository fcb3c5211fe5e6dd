"""ekf_tune's report.md: parameters before/after, and per bag the RMSE and consistency before/after."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ekf_localization.ros.ekf_node_settings import EkfNodeSettings
from ekf_localization.tools.consistency import (
    NEES_SAMPLES_PER_SECOND,
    InnovationLog,
    InputInnovations,
    Nees,
    consistency_rows,
    consistency_section,
    pose_nees,
)
from ekf_localization.tools.evaluation import rmse
from ekf_localization.tools.replay import replay
from ekf_localization.tools.tune_search import Tuner
from ekf_localization.tools.tuning import BagData, Problem


@dataclass
class Evaluation:
    """One configuration replayed over one bag."""

    innovations: dict[str, InputInnovations]
    nees: Nees | None
    rmse: dict[str, float] | None


def evaluate(bag: BagData, settings: EkfNodeSettings) -> Evaluation:
    log = InnovationLog()
    res = replay(bag.replay_input, settings, innovation_listener=log)
    traj = res.trajectory()
    if bag.truth is None:
        return Evaluation(log.per_input(), None, None)
    return Evaluation(log.per_input(), pose_nees(traj, bag.truth), rmse(traj, bag.truth))


def _bag_section(label: str, bag: BagData, before: EkfNodeSettings, after: EkfNodeSettings, out: Path,
                 tag: str) -> str:
    b, a = evaluate(bag, before), evaluate(bag, after)
    lines = [f"## {label}: `{bag.path}`", "", "| quantity | start config | tuned |", "|---|---|---|"]
    if b.rmse is not None and a.rmse is not None:
        for key, unit in (("xy", "m"), ("theta", "rad"), ("vx", "m/s"), ("vtheta", "rad/s")):
            lines.append(f"| RMSE {key} ({unit}) | {b.rmse[key]:.4f} | {a.rmse[key]:.4f} |")
    rb, ra = consistency_rows(b.innovations, b.nees), consistency_rows(a.innovations, a.nees)
    # a row's key ends with its update count, which can differ (gating, rewinds): pair by quantity
    after = {key.split(" (")[0]: (key, value) for key, value in ra.items()}
    for key in rb:
        akey, value = after.get(key.split(" (")[0], (key, "-"))
        note = f" ({akey.split(' (', 1)[1]}" if akey != key else ""
        lines.append(f"| mean {key} | {rb[key]} | {value}{note} |")
    lines.append("")
    lines.append(consistency_section(b.innovations, b.nees, out, f"{tag}_start.png",
                                     f"{label}, start config"))
    lines.append(consistency_section(a.innovations, a.nees, out, f"{tag}_tuned.png", f"{label}, tuned"))
    return "\n".join(lines)


def _plot_convergence(out_png: Path, history: list[float]) -> None:
    from ekf_localization.tools.plots import plt, save_figure

    fig, ax = plt.subplots(figsize=(6, 3))
    ax.plot(np.arange(1, len(history) + 1), history, "-o", ms=3)
    ax.set_xlabel("batch of candidates")
    ax.set_ylabel("best objective")
    ax.set_title("ekf_tune convergence")
    save_figure(fig, out_png)


def write_report(out: Path, problem: Problem, tuner: Tuner, holdouts: list[BagData], ended: str,
                 seconds: float, args: argparse.Namespace) -> Path:
    """Write ``out``/report.md and its PNGs."""
    x0 = np.log10([k.start for k in problem.knobs])
    before, after = problem.settings_at(x0), problem.settings_at(tuner.best_x)
    tuned_values = problem.values_at(tuner.best_x)
    objective_text = ("log of the (x, y) RMSE + NEES band penalty + NIS spread penalty (the best "
                      "candidate by it is kept)" if problem.objective == "truth"
                      else "innovation negative log likelihood, Σ over input parts of the part's mean "
                      "(log det S + νᵀS⁻¹ν) per update")
    lines = ["# ekf_tune report", "",
             f"- bags fitted: {', '.join(f'`{b.path}`' for b in problem.bags)}",
             f"- start config: `{args.params}`"
             + (f" with `--scale-start {args.scale_start}` (`start.yaml`)" if args.scale_start else "")
             + "; tuned: `tuned.yaml`",
             f"- objective: {objective_text}",
             "- fit: covariance matching of the input scales, then "
             + ("a coordinate search in decades on the likelihood (each batch of moves in parallel"
                if problem.objective == "likelihood"
                else "scipy L-BFGS-B in log10 space on the RMSE, then one factor on every variance for "
                "the NEES (forward-difference gradients in parallel")
             + f", {tuner.jobs} worker(s))",
             f"- {tuner.evals} evaluations in {seconds:.1f} s; best objective {tuner.best_f:.5g}",
             *(f"- stage {i + 1}: {text}" for i, text in enumerate(tuner.stages)), "",
             "NIS bands: 95% band of the mean of K independent χ²(m) values; NEES: pose (x, y, θ), "
             f"band counting {NEES_SAMPLES_PER_SECOND:g} independent samples per second (docs/ekf_tune.md). "
             "`in`/`OUT`: inside/outside the band.", "",
             "## Parameters", "", "| parameter | unit | start | tuned | tuned/start | bounds |",
             "|---|---|---|---|---|---|"]
    for k in problem.knobs:
        v = k.get(tuned_values)
        lines.append(f"| `{k.name}` | {k.unit} | {k.start:.4g} | {v:.4g} | {v / k.start:.3g} | "
                     f"[{k.lower:.3g}, {k.upper:.3g}] |")
    lines.append("")
    if len(tuner.history) > 1:
        _plot_convergence(out / "convergence.png", tuner.history)
        lines += ["![convergence](convergence.png)", ""]
    for i, bag in enumerate(problem.bags):
        lines.append(_bag_section(f"Fitted bag {i + 1}", bag, before, after, out, f"fit{i + 1}"))
    for i, bag in enumerate(holdouts):
        lines.append(_bag_section(f"Holdout bag {i + 1}", bag, before, after, out, f"holdout{i + 1}"))
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
