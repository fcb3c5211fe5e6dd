"""Figures a person would rather look at than read: trajectories with covariance ellipses
and errors over time (matplotlib, Agg backend, PNG)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse, Rectangle  # noqa: E402

from ekf_localization.core.linalg import symmetrise  # noqa: E402
from ekf_localization.tools.evaluation import Trajectory  # noqa: E402

CHI2_2DOF_95 = 5.991464547107979  # 95% mass of a 2-D Gaussian inside the ellipse


def save_figure(fig, out_png: Path | str) -> Path:
    """Lay out, write the PNG (creating its folder) and close the figure."""
    fig.tight_layout()
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def covariance_ellipse(mean: np.ndarray, cov: np.ndarray, chi2: float = CHI2_2DOF_95, **kw) -> Ellipse:
    """The ``chi2`` confidence ellipse of a 2-D Gaussian (default 95%)."""
    vals, vecs = np.linalg.eigh(symmetrise(cov))
    vals = np.clip(vals, 0.0, None)
    angle = np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1]))
    w, h = 2.0 * np.sqrt(chi2 * vals[1]), 2.0 * np.sqrt(chi2 * vals[0])
    return Ellipse(xy=(float(mean[0]), float(mean[1])), width=w, height=h, angle=angle, **kw)


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
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"]
    for i, (name, est) in enumerate(estimates.items()):
        c = colors[i % len(colors)]
        ax.plot(est.states[:, 0], est.states[:, 1], color=c, lw=1.3, label=name)
        if i == 0 and est.covariances is not None and len(est) > 1:
            last = None
            for k in range(len(est)):
                t = est.t_ns[k]
                if last is None or t - last >= ellipse_every_s * 1e9:
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


def plot_errors(out_png: Path | str, series: Mapping[str, tuple[np.ndarray, np.ndarray]],
                sigmas: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
                camera_times_s: np.ndarray | None = None, title: str = "Error against ground truth") -> Path:
    """Position error norm and heading error over time for each estimator.

    ``series`` maps a name to (t_s (K,), error (K, 6)); ``sigmas`` optionally maps the same
    name to (t_s, pose std (K, 3)) drawn as a ±2σ band on the heading panel and as 2σ on the
    position panel.
    """
    fig, axes = plt.subplots(2, 1, figsize=(10, 6.5), dpi=110, sharex=True)
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"]
    for i, (name, (t, e)) in enumerate(series.items()):
        c = colors[i % len(colors)]
        axes[0].plot(t, np.hypot(e[:, 0], e[:, 1]), color=c, lw=1.2, label=name)
        axes[1].plot(t, e[:, 2], color=c, lw=1.2, label=name)
        if sigmas and name in sigmas:
            ts, s = sigmas[name]
            axes[0].plot(ts, 2.0 * np.hypot(s[:, 0], s[:, 1]), color=c, lw=0.8, ls=":",
                         label=f"{name} 2σ")
            axes[1].fill_between(ts, -2 * s[:, 2], 2 * s[:, 2], color=c, alpha=0.15)
    if camera_times_s is not None and len(camera_times_s):
        for ax in axes:
            ax.plot(camera_times_s, np.zeros_like(camera_times_s), "|", color="tab:red", ms=8,
                    alpha=0.6)
    axes[0].set_ylabel("position error [m]")
    axes[1].set_ylabel("heading error [rad]")
    axes[1].set_xlabel("time [s]  (red ticks: camera fixes)")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    axes[0].set_title(title)
    return save_figure(fig, out_png)
