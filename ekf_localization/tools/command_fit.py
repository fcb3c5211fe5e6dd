"""The command model from a recorded bag: when and how the drive follows cmd_vel.

``ekf_tune --fit-command`` runs it on each bag before the noise fit. Per bag:

- **transport**: each cmd_vel's receipt by the recorder minus its header stamp (median, p95,
  max): how late commands travel. The filter applies a command at its stamp plus
  ``control_latency``, so transport only matters once it nears ``history_length``;
- **effect latency and time constant**: the drive response of the filter's own model
  (``models/drive_response.py``, from the start configuration: wheel geometry, acceleration
  and speed limits) to the recorded commands, each acting from its stamp plus L and, with a
  lag, time constant τ, against the dead wheels' measured twist. (L, τ) minimise the residual
  weighted by the odometry's own covariance (τ > 0 only where it is significant: a
  likelihood-ratio test at 1 %), on a grid (10 ms, then 1 ms about the best for
  the best τ and its neighbours);
- **control noise**: per axis, the residual's variance at that (L, τ) less the odometry's own
  reported variance: how far the drive strays from its response, as the odometry sees it.

Output-error identification (the model runs open loop from the commands alone): it needs a
drive that settles on its command, which every velocity-controlled drive does, and no filter.
The odometry's twist is compared as the instantaneous velocity at its stamp, or as the mean
over the interval since the previous message (``interval_average``: an encoder read out at a
rate); the two differ by half an interval of latency, which the data cannot tell apart, so it
is a setting (``dead_wheels.sampling`` in config/sim.yaml; a real encoder averages).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from ekf_localization.core.command_model import CommandModel
from ekf_localization.core.config import EkfConfig
from ekf_localization.core.units import NS_PER_S, ns_to_seconds, seconds_to_ns, stamp_to_ns
from ekf_localization.models.drive_response import DriveResponse, step_of
from ekf_localization.models.mecanum import drive_response_from_config

SAMPLINGS = ("instantaneous", "interval_average")
MAX_LATENCY_S = 0.2
COARSE_NS = 10_000_000
FINE_NS = 1_000_000
TIME_CONSTANTS_S = (0.0, 0.005, 0.01, 0.02, 0.04, 0.08, 0.16)
LAG_CHI2 = float(chi2.ppf(0.99, 1))  # a lag is kept when it lowers the residual χ² by this much
_TWIST = [0, 1, 5]  # [vx vy wz] of a 6-vector twist / covariance


@dataclass
class BagCommands:
    """The recorded commands and dead-wheel twists of one bag."""

    path: Path
    cmd_stamp_ns: np.ndarray  # (K,) header stamps
    cmd_receipt_ns: np.ndarray  # (K,) the recorder's receipt
    cmd: np.ndarray  # (K, 3) [vx vy wz]
    odom_stamp_ns: np.ndarray  # (M,)
    odom: np.ndarray  # (M, 3) measured body twist [vx vy wz]
    odom_variance: np.ndarray  # (M, 3) its reported variances


@dataclass
class CommandFit:
    """What one bag says about the command model (module docstring)."""

    path: Path
    commands: int
    transport_ms: tuple[float, float, float]  # receipt − stamp: median, p95, max
    latency_s: float
    time_constant_s: float
    residual_variance: np.ndarray  # (3,) about the response, at the fitted (L, τ)
    odometry_variance: np.ndarray  # (3,) mean reported
    control_variance: np.ndarray  # (3,) residual − odometry, at least 0
    cost_by_latency: np.ndarray  # (n, 2): L (s), weighted mean squared residual, at the fitted τ


def read_bag(path: Path | str, cmd_topic: str, odom_topic: str) -> BagCommands:
    """cmd_vel (TwistStamped) and odometry (nav_msgs/Odometry) of a bag."""
    from ekf_localization.tools import bag_io

    cs, cr, cv, os_, ov, ovar = [], [], [], [], [], []
    for m in bag_io.iter_messages(path, [cmd_topic, odom_topic]):
        if m.topic == cmd_topic:
            t = m.msg.twist
            cs.append(stamp_to_ns(m.msg.header.stamp))
            cr.append(m.log_time_ns)
            cv.append((t.linear.x, t.linear.y, t.angular.z))
        else:
            t = m.msg.twist
            os_.append(stamp_to_ns(m.msg.header.stamp))
            ov.append((t.twist.linear.x, t.twist.linear.y, t.twist.angular.z))
            ovar.append(np.asarray(t.covariance, dtype=float).reshape(6, 6)[_TWIST, _TWIST])
    if len(cs) < 2 or len(os_) < 10:
        raise ValueError(f"{path}: {len(cs)} messages on {cmd_topic} and {len(os_)} on {odom_topic}; "
                         "the command fit needs commands and odometry")
    order = np.argsort(cs, kind="stable")
    oorder = np.argsort(os_, kind="stable")
    return BagCommands(Path(path), np.array(cs, np.int64)[order], np.array(cr, np.int64)[order],
                       np.array(cv, float)[order], np.array(os_, np.int64)[oorder],
                       np.array(ov, float)[oorder], np.array(ovar, float)[oorder])


def response(drive: DriveResponse, data: BagCommands, latency_ns: int, timeout_ns: int,
             sampling: str) -> np.ndarray:
    """(M, 3): the drive response to the commands, from rest, at the odometry stamps
    (instantaneous) or averaged over each odometry interval. When each command acts (its stamp
    + latency, until ``timeout_ns`` with no newer one, then at rest) is the filter's own
    ``core/command_model.CommandModel``."""
    step = step_of(drive.params)  # per axis, wheel space or swerve modules
    params = drive.params
    model = CommandModel(latency_ns, timeout_ns, 1, np.zeros(3))
    events = np.concatenate([data.cmd_stamp_ns, data.odom_stamp_ns])
    kinds = np.concatenate([np.arange(data.cmd_stamp_ns.size), -1 - np.arange(data.odom_stamp_ns.size)])
    # in time order; at one time the commands first (in their order), then the readings
    order = np.lexsort((np.arange(events.size), kinds < 0, events))
    command = None
    v = np.zeros(3)
    D = np.zeros(3)  # the displacement of each axis since the start
    t = int(events[order[0]])
    r = [[0.0] * 8 for _ in range(3)]
    at = np.empty((data.odom_stamp_ns.size, 3))
    D_at = np.empty((data.odom_stamp_ns.size, 3))
    for i in order:
        te, k = int(events[i]), int(kinds[i])
        while t < te:  # to te, split where the command in effect changes
            u, change = model.at(command, t)
            end = int(min(te, change))
            step(v, np.zeros(3) if u is None else u, ns_to_seconds(end - t), params, r)
            v = np.array([r[0][0], r[1][0], r[2][0]])
            D += (r[0][1], r[1][1], r[2][1])
            t = end
        if k >= 0:
            command = model.then(command, te, data.cmd[k], True)
        else:
            at[-1 - k] = v
            D_at[-1 - k] = D
    if sampling == "instantaneous":
        return at
    dt = np.diff(data.odom_stamp_ns).astype(float) / NS_PER_S
    mean = np.empty_like(at)
    mean[0] = at[0]
    mean[1:] = np.diff(D_at, axis=0) / np.where(dt > 0.0, dt, np.inf)[:, None]
    mean[1:][dt <= 0.0] = at[1:][dt <= 0.0]
    return mean


def _cost(drive: DriveResponse, data: BagCommands, latency_ns: int, timeout_ns: int,
          sampling: str) -> tuple[float, np.ndarray]:
    """(mean of residual²/variance over readings and axes, residuals (M, 3))."""
    e = data.odom - response(drive, data, latency_ns, timeout_ns, sampling)
    var = np.maximum(data.odom_variance, 1e-12)
    return float(np.mean(e * e / var)), e


def fit_bag(data: BagCommands, config: EkfConfig, sampling: str = "instantaneous",
            max_latency_s: float = MAX_LATENCY_S) -> CommandFit:
    """(L, τ) on the grid, then the control noise at them (module docstring)."""
    if sampling not in SAMPLINGS:
        raise ValueError(f"sampling must be one of {SAMPLINGS}, got {sampling!r}")
    base = drive_response_from_config(config)
    timeout_ns = config.control_timeout_ns
    drives = {tau: dataclasses.replace(base, time_constant_s=np.full(3, tau)) for tau in TIME_CONSTANTS_S}
    coarse = range(0, seconds_to_ns(max_latency_s) + 1, COARSE_NS)
    grid = {(L, tau): _cost(d, data, L, timeout_ns, sampling)[0] for tau, d in drives.items() for L in coarse}

    def refine(tau: float) -> None:
        """L on the fine grid about the best coarse L for ``tau``."""
        L1 = min(coarse, key=lambda L: grid[(L, tau)])
        for L in range(max(0, L1 - COARSE_NS), L1 + COARSE_NS + 1, FINE_NS):
            if (L, tau) not in grid:
                grid[(L, tau)] = _cost(drives[tau], data, L, timeout_ns, sampling)[0]

    # a lag and a latency trade off: refine the best coarse τ and the τ either side of it, and
    # τ = 0; a lag is kept only when it explains the data significantly better, a likelihood-
    # ratio test of the nested model (one parameter more; the cost is a mean of residual²/
    # variance over the readings' axes). Behind an acceleration limit a lag of a few ms changes
    # the response only in its last mm/s and is not identifiable.
    j = TIME_CONSTANTS_S.index(min(grid, key=grid.__getitem__)[1])
    for tau in {0.0, *TIME_CONSTANTS_S[max(0, j - 1):j + 2]}:
        refine(tau)
    L, tau = min(grid, key=grid.__getitem__)
    no_lag = min((k for k in grid if k[1] == 0.0), key=grid.__getitem__)
    if (grid[no_lag] - grid[(L, tau)]) * data.odom.size < LAG_CHI2:
        L, tau = no_lag
    drive = drives[tau]
    costs = np.array(sorted((ns_to_seconds(k[0]), v) for k, v in grid.items() if k[1] == tau))
    _, e = _cost(drive, data, L, timeout_ns, sampling)
    residual = np.var(e, axis=0)
    odo = np.mean(data.odom_variance, axis=0)
    late_ms = (data.cmd_receipt_ns - data.cmd_stamp_ns) / 1e6
    transport = (float(np.median(late_ms)), float(np.percentile(late_ms, 95)), float(late_ms.max()))
    return CommandFit(data.path, int(data.cmd.shape[0]), transport,
                      ns_to_seconds(L), float(tau), residual, odo, np.maximum(residual - odo, 0.0), costs)


def table(fits: list[CommandFit]) -> str:
    """A markdown table, a row per bag and the median."""
    rows = ["| bag | commands | transport ms (median, p95, max) | latency ms | time constant ms "
            "| control variance vx, vy (m/s)², vyaw (rad/s)² |", "|---|---|---|---|---|---|"]
    for f in fits:
        cv = ", ".join(f"{v:.2g}" for v in f.control_variance)
        late = ", ".join(f"{v:.1f}" for v in f.transport_ms)
        rows.append(f"| {f.path} | {f.commands} | {late} | {f.latency_s * 1e3:.0f} "
                    f"| {f.time_constant_s * 1e3:.0f} | {cv} |")
    L, tau = median_timing(fits)
    cv = ", ".join(f"{v:.2g}" for v in np.median([f.control_variance for f in fits], axis=0))
    rows.append(f"| median | | | {L * 1e3:.0f} | {tau * 1e3:.0f} | {cv} |")
    return "\n".join(rows)


def median_timing(fits: list[CommandFit]) -> tuple[float, float]:
    """(latency s, time constant s): the medians over the bags."""
    return (float(np.median([f.latency_s for f in fits])),
            float(np.median([f.time_constant_s for f in fits])))
