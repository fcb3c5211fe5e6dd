"""The accuracy report of a run against ground truth: the RMSE table (seed 000 sec. VI A) and
two figures, trajectories with covariance ellipses and errors over time. The demo and
bag_replay both write it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.patches import Rectangle

from ekf_localization.core.units import METRES_PER_INCH, ns_to_seconds, seconds_to_ns
from ekf_localization.tools.evaluation import Trajectory, errors, rmse
from ekf_localization.tools.plots import covariance_ellipse, plt, save_figure

FIELD_HALF_SIZE = 72 * METRES_PER_INCH  # an FTC field is 144 in square
COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple")


def write_report(out: Path, truth: Trajectory, estimates: Mapping[str, Trajectory], plotted: Sequence[str],
                 *, title: str, plot_title: str, path_xy: np.ndarray | None = None,
                 camera_t_ns: np.ndarray | None = None, camera_xy: np.ndarray | None = None) -> str:
    """The RMSE table of every estimate against ``truth`` (rows in the order given), and
    ``out``/trajectory.png and ``out``/errors.png of the ``plotted`` ones; the first of those
    is drawn with its covariance (95% ellipses, 2σ bands). Returns the table."""
    table = format_rmse_table({name: rmse(est, truth) for name, est in estimates.items()}, title=title)
    t0 = truth.t_ns[0]
    shown = {name: estimates[name] for name in plotted}
    plot_trajectories(out / "trajectory.png", truth, shown, path_xy=path_xy, camera_fixes=camera_xy,
                      field_half_size=FIELD_HALF_SIZE, title=f"{plot_title}: truth vs estimates")
    first = shown[plotted[0]]
    sigma = np.sqrt(np.clip(np.diagonal(first.covariances, axis1=1, axis2=2), 0, None))
    series = {}
    for name, est in shown.items():
        t, e = errors(est, truth)
        series[name] = (ns_to_seconds(t - t0), e)
    plot_errors(out / "errors.png", series, sigmas={plotted[0]: (ns_to_seconds(first.t_ns - t0), sigma)},
                camera_times_s=None if camera_t_ns is None else ns_to_seconds(camera_t_ns - t0),
                title=f"{plot_title}: error against ground truth")
    return table


def format_rmse_table(rows: dict[str, dict[str, float]], title: str = "RMSE against ground truth") -> str:
    """A text table: one row per estimator, linear columns in m and in, angles in rad (rad/s)."""
    head = ["estimator", "(x,y) m", "(x,y) in", "x m", "y m", "θ rad", "ẋ m/s", "ẏ m/s", "θ̇ rad/s"]
    lines = [title, ""]
    body = []
    def cell(v: float, digits: int = 4) -> str:
        return f"{v:.{digits}f}" if np.isfinite(v) else "n/a"

    notes = []
    for name, r in rows.items():
        if r.get("excluded"):
            name = f"{name} *"
            notes.append(f"* {r['excluded']} non-finite samples excluded")
        if not np.isfinite(r["xy"]):
            notes.append(f"n/a: no finite sample of '{name}' within the truth's time span")
        body.append([name, cell(r["xy"]), cell(r["xy"] / METRES_PER_INCH, 3), cell(r["x"]), cell(r["y"]),
                     cell(r["theta"]), cell(r["vx"]), cell(r["vy"]), cell(r["vtheta"])])
    widths = [max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(head)]
    lines.append("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)))
    lines.append("  ".join("-" * w for w in widths))
    for b in body:
        lines.append("  ".join(c.ljust(w) for c, w in zip(b, widths, strict=True)))
    if notes:
        lines += ["", *notes]
    return "\n".join(lines)


def plot_trajectories(out_png: Path | str, truth: Trajectory | None,
                      estimates: Mapping[str, Trajectory], path_xy: np.ndarray | None = None,
                      camera_fixes: np.ndarray | None = None, field_half_size: float | None = None,
                      ellipse_every_s: float = 1.0, title: str = "Trajectory",
                      ellipse_scale: float = 1.0) -> Path:
    """Path, truth, estimates (first one with 95% covariance ellipses), camera fixes."""
    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    if field_half_size:
        ax.add_patch(Rectangle((-field_half_size, -field_half_size), 2 * field_half_size,
                               2 * field_half_size, fill=False, lw=1.5, color="0.4"))
    if path_xy is not None and len(path_xy):
        ax.plot(path_xy[:, 0], path_xy[:, 1], "--", color="0.55", lw=1.5, label="path")
    if truth is not None and len(truth):
        ax.plot(truth.states[:, 0], truth.states[:, 1], color="k", lw=2.0, label="ground truth")
    for i, (name, est) in enumerate(estimates.items()):
        c = COLORS[i % len(COLORS)]
        ax.plot(est.states[:, 0], est.states[:, 1], color=c, lw=1.3, label=name)
        if i == 0 and est.covariances is not None and len(est) > 1:
            last = None
            for k in range(len(est)):
                t = est.t_ns[k]
                if last is None or t - last >= seconds_to_ns(ellipse_every_s):
                    cov = np.asarray(est.covariances[k])[:2, :2] * ellipse_scale ** 2
                    ax.add_patch(covariance_ellipse(est.states[k, :2], cov, fill=False, color=c,
                                                    lw=0.9, alpha=0.8))
                    last = t
    if camera_fixes is not None and len(camera_fixes):
        ax.scatter(camera_fixes[:, 0], camera_fixes[:, 1], s=14, marker="x", color="tab:red",
                   alpha=0.7, label="camera fixes", zorder=3)
    if truth is not None and len(truth):
        ax.plot(*truth.states[0, :2], "o", color="green", ms=8, label="start")
        ax.plot(*truth.states[-1, :2], "s", color="red", ms=8, label="end")
    if field_half_size:  # keep the field in view even when an early ellipse is huge
        m = 1.08 * field_half_size
        ax.set_xlim(-m, m)
        ax.set_ylim(-m, m)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (field frame, REP-103)")
    ax.set_ylabel("y [m]")
    note = f" (ellipses: 95%, ×{ellipse_scale:g})" if ellipse_scale != 1.0 else " (ellipses: 95%)"
    ax.set_title(title + note)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return save_figure(fig, out_png)


def _top(values: list[np.ndarray], percentile: float) -> float:
    """1.2 × the largest ``percentile`` of the finite values of each array (0 if none)."""
    finite = [v[np.isfinite(v)] for v in values]
    return 1.2 * max((float(np.percentile(v, percentile)) for v in finite if v.size), default=0.0)


def plot_errors(out_png: Path | str, series: Mapping[str, tuple[np.ndarray, np.ndarray]],
                sigmas: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
                camera_times_s: np.ndarray | None = None, title: str = "Error against ground truth") -> Path:
    """Position error norm and heading error over time for each estimator.

    ``series`` maps a name to (t_s (K,), error (K, 6)); ``sigmas`` optionally maps the same
    name to (t_s, pose std (K, 3)) drawn as a ±2σ band on the heading panel and as 2σ on the
    position panel.
    """
    fig, axes = plt.subplots(2, 1, figsize=(10, 6.5), dpi=110, sharex=True)
    drawn: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])  # |errors| per panel, for the limits
    bands: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])  # 2σ per panel
    for i, (name, (t, e)) in enumerate(series.items()):
        c = COLORS[i % len(COLORS)]
        drawn[0].append(np.hypot(e[:, 0], e[:, 1]))
        drawn[1].append(np.abs(e[:, 2]))
        axes[0].plot(t, drawn[0][-1], color=c, lw=1.2, label=name)
        axes[1].plot(t, e[:, 2], color=c, lw=1.2, label=name)
        if sigmas and name in sigmas:
            ts, s = sigmas[name]
            bands[0].append(2.0 * np.hypot(s[:, 0], s[:, 1]))
            bands[1].append(2.0 * s[:, 2])
            axes[0].plot(ts, bands[0][-1], color=c, lw=0.8, ls=":", label=f"{name} 2σ")
            axes[1].fill_between(ts, -2 * s[:, 2], 2 * s[:, 2], color=c, alpha=0.15)
    # limits: every error, and 2σ as it mostly is; the start-up covariance (metres of σ for a
    # moment) would otherwise flatten every curve
    tops = [max(_top(e, 100.0), _top(b, 90.0)) for e, b in zip(drawn, bands, strict=True)]
    if tops[0] > 0:
        axes[0].set_ylim(0.0, tops[0])
    if tops[1] > 0:
        axes[1].set_ylim(-tops[1], tops[1])
    if camera_times_s is not None and len(camera_times_s):
        for ax in axes:
            ax.plot(camera_times_s, np.zeros_like(camera_times_s), "|", color="tab:red", ms=8,
                    alpha=0.6)
    axes[0].set_ylabel("position error [m]")
    axes[1].set_ylabel("heading error [rad]")
    axes[1].set_xlabel("time [s]" + ("  (red ticks: camera fixes)" if camera_times_s is not None else ""))
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    axes[0].set_title(title)
    return save_figure(fig, out_png)
