"""Filter consistency from a replay: NIS per input, NEES against ground truth, their χ² bands.

* **NIS** (normalised innovation squared) of an update is νᵀS⁻¹ν with ν = z - h(x⁻) and
  S = H P⁻ Hᵀ + R. For a consistent filter it is χ²-distributed with m (the update's
  dimension) degrees of freedom and the innovations are white, so the mean over K updates
  lies in [χ²₀.₀₂₅(Km)/K, χ²₀.₉₇₅(Km)/K] with 95% probability (Bar-Shalom, Li, Kirubarajan,
  *Estimation with Applications to Tracking and Navigation*, sec. 5.4).
* **NEES** (normalised estimation error squared) of the (x, y, θ) pose against ground truth,
  3 degrees of freedom. Errors at 50 Hz are strongly correlated: the mean of N outputs has
  the variance of the mean of N_eff = N / τ independent χ²(3) values (τ = 1 + 2 Σ ρ_k, the
  integrated autocorrelation), and its band is that of N_eff samples. N_eff is
  :data:`NEES_SAMPLES_PER_SECOND` per second of bag, measured from the spread of the mean over
  20 seeds of the demo world (docs/ekf_tune.md, "Consistency bands"): 0.3/s, i.e. 6 samples
  and [1.37, 5.26] for 20 s.
* **Innovation likelihood** Σ (log det S + νᵀS⁻¹ν) over all updates: the negative log
  likelihood of the innovations up to constants, the objective for tuning without truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.chi2_bands import mean_chi2_band
from ekf_localization.core.localizer import Innovation
from ekf_localization.core.units import ns_to_seconds
from ekf_localization.tools.evaluation import Trajectory, interpolate

NEES_DOF = 3  # x, y, θ
NEES_SAMPLES_PER_SECOND = 0.3  # independent NEES samples per second (docs/ekf_tune.md: how it is measured)


class InnovationLog:
    """A Localizer ``innovation_listener`` that keeps the final innovation of every update.

    After a rewind the Localizer re-applies newer entries and reports them again; the entry
    sequence number and part identify the update, and the last report replaces earlier ones.
    """

    def __init__(self) -> None:
        self._latest: dict[tuple[int, str], Innovation] = {}

    def __call__(self, innovation: Innovation) -> None:
        self._latest[(innovation.seq, innovation.part)] = innovation

    def __len__(self) -> int:
        return len(self._latest)

    def per_input(self) -> dict[str, InputInnovations]:
        """Innovations grouped by "<input> <part>" (e.g. "odom0 twist"), in stamp order."""
        groups: dict[str, list[Innovation]] = {}
        for inn in self._latest.values():
            groups.setdefault(f"{inn.source} {inn.part}", []).append(inn)
        out = {}
        for label in sorted(groups):
            items = sorted(groups[label], key=lambda i: (i.stamp_ns, i.seq))
            nu = np.array([i.nu for i in items])
            S = np.array([i.S for i in items])
            sign, logdet = np.linalg.slogdet(S)
            nis = np.einsum("ki,ki->k", nu, np.linalg.solve(S, nu[..., None])[..., 0])
            logdet = np.where(sign > 0, logdet, np.nan)
            out[label] = InputInnovations(np.array([i.stamp_ns for i in items], dtype=np.int64), nis,
                                          logdet, np.array([i.accepted for i in items]), nu.shape[1])
        return out


@dataclass(frozen=True)
class InputInnovations:
    """One input part's updates: stamps, NIS, log det S, accepted flags, dimension m."""

    t_ns: np.ndarray
    nis: np.ndarray
    logdet: np.ndarray
    accepted: np.ndarray
    dim: int

    @property
    def mean_nis(self) -> float:
        return float(np.mean(self.nis)) if self.nis.size else float("nan")

    @property
    def band(self) -> tuple[float, float]:
        return mean_chi2_band(self.dim, self.nis.size)


def negative_log_likelihood(innovations: dict[str, InputInnovations]) -> tuple[float, int]:
    """(Σ log det S + νᵀS⁻¹ν over every update, number of updates)."""
    total = 0.0
    count = 0
    for inn in innovations.values():
        total += float(np.sum(inn.logdet + inn.nis))
        count += inn.nis.size
    return total, count


@dataclass(frozen=True)
class Nees:
    """Pose NEES (x, y, θ) of an estimate against truth, per estimate stamp."""

    t_ns: np.ndarray
    nees: np.ndarray
    duration_s: float

    @property
    def mean(self) -> float:
        return float(np.mean(self.nees)) if self.nees.size else float("nan")

    @property
    def band(self) -> tuple[float, float]:
        return mean_chi2_band(NEES_DOF, max(1.0, self.duration_s * NEES_SAMPLES_PER_SECOND))


def pose_nees(estimate: Trajectory, truth: Trajectory) -> Nees:
    """NEES of the (x, y, θ) estimate with its covariance, over the truth's time span."""
    if len(truth) == 0 or len(estimate) == 0 or estimate.covariances is None:
        return Nees(np.zeros(0, np.int64), np.zeros(0), 0.0)
    keep = (estimate.t_ns >= truth.t_ns[0]) & (estimate.t_ns <= truth.t_ns[-1])
    t = estimate.t_ns[keep]
    ref = interpolate(truth, t)
    e = estimate.states[keep, :3] - ref[:, :3]
    e[:, 2] = wrap_angles(e[:, 2])
    P = np.asarray(estimate.covariances)[keep]
    with np.errstate(all="ignore"):
        nees = np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])
    span = ns_to_seconds(t[-1] - t[0]) if t.size > 1 else 0.0
    return Nees(t, nees, span)


def live_nees(bag: Path | str, estimate_topic: str, truth_topic: str,
              at_truth_samples: bool = False) -> tuple[Nees, Nees]:
    """(pose NEES of x, y, θ; twist NEES of vx, vy, vyaw) of the recorded ``estimate_topic``
    (nav_msgs/Odometry, e.g. ekf_node's /odometry/filtered) with the covariances it published,
    against the recorded truth: what ekf_node said live, not a replay. χ²(3) each.

    ``at_truth_samples``: only the estimates stamped at a truth sample (sim_node's
    ``ground_truth.at_clock`` publishes one at every /clock stamp, where ekf_node's outputs are
    stamped). Otherwise the truth is interpolated linearly, which is wrong for the velocity
    across a command's onset: the drive's ramp starts there, and a 100 Hz truth interpolated
    across it is off by up to the ramp of the 10 ms interval."""
    from ekf_localization.tools import bag_io

    truth = bag_io.read_odometry(bag, truth_topic)
    ts, xs, pose_cov, twist_cov = [], [], [], []
    idx = np.ix_([0, 1, 5], [0, 1, 5])
    for m in bag_io.iter_messages(bag, [estimate_topic]):
        t, x, _c = bag_io.odometry_state(m.msg)
        ts.append(t)
        xs.append(x)
        pose_cov.append(np.asarray(m.msg.pose.covariance, dtype=float).reshape(6, 6)[idx])
        twist_cov.append(np.asarray(m.msg.twist.covariance, dtype=float).reshape(6, 6)[idx])
    empty = Nees(np.zeros(0, np.int64), np.zeros(0), 0.0)
    if not ts or len(truth) == 0:
        return empty, empty
    t = np.array(ts, dtype=np.int64)
    keep = (t >= truth.t_ns[0]) & (t <= truth.t_ns[-1])
    if at_truth_samples:
        keep &= np.isin(t, truth.t_ns)
    t = t[keep]
    e = np.array(xs)[keep] - interpolate(truth, t)
    e[:, 2] = wrap_angles(e[:, 2])
    span = ns_to_seconds(t[-1] - t[0]) if t.size > 1 else 0.0
    out = []
    for cols, cov in (((0, 1, 2), pose_cov), ((3, 4, 5), twist_cov)):
        ec = e[:, cols]
        P = np.array(cov)[keep]
        with np.errstate(all="ignore"):
            out.append(Nees(t, np.einsum("ki,ki->k", ec, np.linalg.solve(P, ec[..., None])[..., 0]), span))
    return out[0], out[1]


def _fmt_band(value: float, band: tuple[float, float]) -> str:
    inside = band[0] <= value <= band[1]
    return f"{value:.3g} [{band[0]:.3g}, {band[1]:.3g}] {'in' if inside else 'OUT'}"


def consistency_rows(innovations: dict[str, InputInnovations], nees: Nees | None) -> dict[str, str]:
    """{quantity: "mean [band] in/OUT"}: mean NIS per input part, and mean NEES when truth exists."""
    rows = {f"NIS {label} (m={inn.dim}, {inn.nis.size} updates)": _fmt_band(inn.mean_nis, inn.band)
            for label, inn in innovations.items()}
    if nees is not None and nees.nees.size:
        rows[f"NEES pose (x, y, θ; {nees.duration_s:.0f} s)"] = _fmt_band(nees.mean, nees.band)
    return rows


def plot_consistency(out_png: Path | str, innovations: dict[str, InputInnovations], nees: Nees | None,
                     title: str, window_s: float = 1.0) -> Path:
    """NIS over time per input part (each update, and its ``window_s`` moving mean with the band
    of such a mean), plus the pose NEES when truth exists."""
    from ekf_localization.tools.plots import plt, save_figure

    panels = list(innovations.items())
    rows = len(panels) + (1 if nees is not None and nees.nees.size else 0)
    fig, axes = plt.subplots(max(rows, 1), 1, figsize=(9, 2.2 * max(rows, 1)), squeeze=False)
    t0 = min((inn.t_ns[0] for _, inn in panels if inn.t_ns.size), default=0)
    for ax, (label, inn) in zip(axes[:, 0], panels, strict=False):
        _series(ax, ns_to_seconds(inn.t_ns - t0), inn.nis, inn.dim, window_s, f"NIS {label}")
    if rows > len(panels):
        ax = axes[-1, 0]
        _series(ax, ns_to_seconds(nees.t_ns - t0), nees.nees, NEES_DOF, window_s, "NEES pose (x, y, θ)")
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("time (s)")
    return save_figure(fig, out_png)


def _series(ax, t: np.ndarray, values: np.ndarray, dof: int, window_s: float, label: str) -> None:
    ax.semilogy(t, np.clip(values, 1e-6, None), ".", ms=1.5, color="0.7", label="each")
    if t.size > 1:
        rate = t.size / max(t[-1] - t[0], 1e-9)
        w = max(1, int(round(rate * window_s)))
        kernel = np.ones(w) / w
        mean = np.convolve(values, kernel, mode="same")
        ax.semilogy(t, np.clip(mean, 1e-6, None), "-", color="C0", lw=1.2, label=f"{window_s:g} s mean")
        lo, hi = mean_chi2_band(dof, w)
        ax.axhspan(lo, hi, color="C2", alpha=0.2, label=f"95% band of the mean (m={dof})")
    ax.axhline(dof, color="C2", ls="--", lw=0.8)
    ax.set_ylabel(label, fontsize=8)
    ax.legend(loc="upper right", fontsize=6)


def consistency_section(innovations: dict[str, InputInnovations], nees: Nees | None, out_dir: Path,
                        png_name: str, title: str) -> str:
    """A markdown section (table of means against their bands + the over-time figure)."""
    plot_consistency(out_dir / png_name, innovations, nees, title)
    lines = [f"### {title}", "", "| quantity | mean [95% band] |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in consistency_rows(innovations, nees).items()]
    lines += ["", f"![{title}]({png_name})", ""]
    return "\n".join(lines)
