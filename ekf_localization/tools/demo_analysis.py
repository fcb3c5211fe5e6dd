"""The closed-loop demo's analysis of its bag: the RMSE table of /odometry/filtered against the
ground truth, next to dead reckoning and the same bag replayed without cmd_vel; the live NEES
and each input's NIS; the plots and report (what ``ekf_demo`` prints and writes)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ekf_localization.control.field_path import config_dir
from ekf_localization.core.units import ns_to_seconds
from ekf_localization.tools import demo_images

TOPIC_TRUTH = "/ground_truth/odom"
TOPIC_FILTERED = "/odometry/filtered"
TOPIC_DEAD_WHEELS = "/odometry/dead_wheels"
TOPIC_CAMERA = "/camera/pose"
TOPIC_PATH = "/pure_pursuit/path"
EKF_PARAMS = "ekf_params.yaml"  # written into the output directory, next to the bag
EKF_TWIST_PARAMS = "ekf_params_twist.yaml"  # --joint-states: the twist input's parameters, same start
TILT_IMU_CONFIG = [False, False, False, True, True, True, False, False, False,
                   False, False, True, False, False, False]


def tilt_overrides(joint_states: bool, compensate: bool = True) -> dict:
    """ekf_node parameters for --ramp: the tilt source and the dead-wheel input's compensation."""
    flag = "joint0_tilt_compensation" if joint_states else "odom0_tilt_compensation"
    return {"imu0_config": TILT_IMU_CONFIG, flag: compensate}


def ramp_entry_ns(truth, sim_yaml: Path) -> int | None:
    """Stamp of the first ground-truth pose inside the ramp region of ``sim_yaml`` (None: never)."""
    from ekf_localization.ros.parameters import parameters_from_yaml

    p = parameters_from_yaml(sim_yaml, "sim_node")
    x, y = truth.states[:, 0], truth.states[:, 1]
    inside = (x > p["ramp.x_min"]) & (x < p["ramp.x_max"]) & (y > p["ramp.y_min"]) & (y < p["ramp.y_max"])
    return int(truth.t_ns[np.argmax(inside)]) if inside.any() else None


_TRUTH_COLUMN = {0: 0, 1: 1, 5: 2, 6: 3, 7: 4, 11: 5}  # robot_localization field -> [x y θ vx vy ω]
WITHOUT_CMD_VEL_ROW = "replay: without cmd_vel (use_control false)"


def consistency_lines(result, truth) -> list[str]:
    """``NEES mean ...`` of the replayed run (6 states, against the truth) and ``NIS <input>
    mean ...`` per fused input part (its dimension in brackets)."""
    from ekf_localization.core.angles import wrap_angles
    from ekf_localization.tools.evaluation import interpolate

    ests = [e for e in result.estimates if truth.t_ns[0] <= e.stamp_ns <= truth.t_ns[-1]]
    lines = []
    if ests:
        t = np.array([e.stamp_ns for e in ests], dtype=np.int64)
        fields = list(ests[0].state_fields)  # the model's state (the tank's has no vy) in the truth's columns
        err = np.array([e.state for e in ests]) - interpolate(truth, t)[:, [_TRUTH_COLUMN[f] for f in fields]]
        yaw = fields.index(5)
        err[:, yaw] = wrap_angles(err[:, yaw])
        P = np.array([e.covariance for e in ests])
        nees = np.einsum("ki,ki->k", err, np.linalg.solve(P, err[:, :, None])[..., 0])
        n = len(fields)
        lines.append(f"NEES mean {nees.mean():.2f} ({n} states, {len(ests)} estimates; chi2({n}) mean {n})")
    for key, (total, count, dim) in sorted(result.localizer.nis.items()):
        lines.append(f"NIS {key} mean {total / max(count, 1):.2f} (dimension {dim}, {count} updates)")
    return lines


def odometry_gap(dead, min_gap_ns: int = 100_000_000) -> tuple[int, int] | None:
    """The longest silence of the dead-wheel odometry, if longer than ``min_gap_ns``."""
    d = np.diff(dead.t_ns)
    if len(d) == 0 or d.max() < min_gap_ns:
        return None
    i = int(np.argmax(d))
    return int(dead.t_ns[i]), int(dead.t_ns[i + 1])


def window_error(traj, truth, window: tuple[int, int]) -> float:
    """RMS (x, y) error of ``traj`` at its samples inside ``window``."""
    from ekf_localization.tools.evaluation import errors

    t, e = errors(traj, truth)
    sel = (t > window[0]) & (t < window[1])
    return float(np.sqrt(np.mean(e[sel, 0] ** 2 + e[sel, 1] ** 2))) if sel.any() else math.nan


def analyse(bag: Path, out: Path, joint_states: bool = False, ramp: bool = False,
            images: bool = False, extra: dict | None = None,
            slip: bool = False, bump_s: float | None = None, cameras: int = 1) -> str:
    """RMSE table and plots from the recorded bag. Returns the printed table. ``extra``: more
    trajectories (row name -> Trajectory), rows and plots after dead reckoning."""
    from ekf_localization.tools import bag_io
    from ekf_localization.tools.consistency import live_nees
    from ekf_localization.tools.evaluation import Trajectory
    from ekf_localization.tools.replay import load_settings, replay
    from ekf_localization.tools.report import write_report

    truth = bag_io.read_odometry(bag, TOPIC_TRUTH)
    ekf = bag_io.read_odometry(bag, TOPIC_FILTERED)
    dead = bag_io.read_odometry(bag, TOPIC_DEAD_WHEELS)
    cam_t, cam_xy = bag_io.read_poses(bag, TOPIC_CAMERA)
    if len(truth) == 0 or len(ekf) == 0:
        raise RuntimeError("bag has no ground truth or no /odometry/filtered")
    estimates = {"EKF /odometry/filtered": ekf}
    if len(dead):
        estimates["dead reckoning (dead wheels)"] = dead
    estimates.update(extra or {})
    plotted = list(estimates)
    # The same bag, offline: the run's own parameters (NEES, NIS), and without cmd_vel.
    shipped = replay(bag, load_settings(out / EKF_PARAMS), "recorded")
    without = replay(bag, load_settings(out / EKF_PARAMS, overrides=["use_control=false"]), "recorded")
    without_traj = without.trajectory()
    estimates[WITHOUT_CMD_VEL_ROW] = without_traj
    lines = consistency_lines(shipped, truth)
    guard = shipped.localizer.command_guard if shipped.localizer is not None else None
    if guard is not None:  # each trip drops the commands until a full window agrees again
        lines.append(f"command guard: {guard.trips} trips, {guard.recoveries} recoveries "
                     "(the bag replayed with the run's parameters)")
    # what ekf_node published, against the truth at the estimates' own stamps (ground_truth.at_clock)
    pose_live, twist_live = live_nees(bag, TOPIC_FILTERED, TOPIC_TRUTH, at_truth_samples=True)
    lines[:0] = [f"NEES live {name} mean {n.mean:.2f} (chi2(3), {n.nees.size} of {len(ekf)} estimates of "
                 f"{TOPIC_FILTERED} with their published covariances, at a truth sample)"
                 for name, n in (("pose", pose_live), ("twist", twist_live))]
    gap = odometry_gap(dead) if len(dead) else None
    if gap is not None:
        a, b = (ns_to_seconds(g - truth.t_ns[0]) for g in gap)
        lines += [f"odometry dropout {a:.2f}-{b:.2f} s: position error RMS {name} "
                  f"{window_error(traj, truth, gap) * 100:.2f} cm"
                  for name, traj in (("with cmd_vel (EKF)", ekf), ("without cmd_vel (replay)", without_traj))]
    if images:
        for camera in range(cameras):
            lines += [demo_images.tag_fix_line(bag, camera),
                      demo_images.tag_fix_nees_line(bag, truth, camera)]
    notes = "\n".join(lines)
    if joint_states:  # the same run, each dead-wheel input alone, offline
        stds = {}
        for label, params in (("joint_states input", out / EKF_PARAMS),
                              ("odometry twist input", out / EKF_TWIST_PARAMS)):
            result = replay(bag, load_settings(params), "recorded")
            estimates[f"replay: {label}"] = result.trajectory()
            stds[label] = mean_velocity_std(result.estimates)
        notes += "\n" + "\n".join(f"mean velocity std, {label}: vx {s[0]:.4f} m/s, vy {s[1]:.4f} m/s, "
                          f"vyaw {s[2]:.4f} rad/s" for label, s in stds.items())
    if slip:  # the EKF checks its driven wheels for slip (inputs/slip.py); a bump: with and without
        from ekf_localization.tools.slip_report import demo_lines

        notes += "\n" + "\n".join(demo_lines(out, bump_s))
    if ramp:  # the same bag replayed with and without tilt compensation; errors from the ramp on
        uncompensated = load_settings(out / EKF_PARAMS, overrides=[
            f"{k}={str(v).lower()}" for k, v in tilt_overrides(joint_states, False).items()
            if k.endswith("_tilt_compensation")])
        tilted = replay(bag, load_settings(out / EKF_PARAMS), "recorded").trajectory()
        flat = replay(bag, uncompensated, "recorded").trajectory()
        estimates["replay: with tilt compensation"] = tilted
        estimates["replay: without tilt compensation"] = flat
        entry = ramp_entry_ns(truth, config_dir() / "sim.yaml")
        if entry is not None:
            after = {"replay with compensation, from the ramp on": tilted,
                     "replay without compensation, from the ramp on": flat}
            for label, traj in after.items():
                keep = traj.t_ns >= entry
                estimates[label] = Trajectory(traj.t_ns[keep], traj.states[keep])
        z = [float(m.msg.pose.pose.position.z) for m in bag_io.iter_messages(bag, [TOPIC_FILTERED])]
        notes += ("\n" if notes else "") + f"/odometry/filtered z: max {max(z, default=0.0):.3f} m " \
            f"(the ramp's top: {ramp_height(config_dir() / 'sim.yaml'):.3f} m)"
    path_xy = None
    for m in bag_io.iter_messages(bag, [TOPIC_PATH]):
        path_xy = np.array([[p.pose.position.x, p.pose.position.y] for p in m.msg.poses])
    table = write_report(out, truth, estimates, plotted, plot_title="Closed loop", path_xy=path_xy,
                         title=f"RMSE against ground truth ({len(ekf)} estimates, {len(cam_t)} camera fixes)",
                         camera_t_ns=cam_t, camera_xy=cam_xy[:, :2] if len(cam_xy) else None)
    return table + "\n" + notes if notes else table


def ramp_height(sim_yaml: Path) -> float:
    from ekf_localization.ros.parameters import parameters_from_yaml

    p = parameters_from_yaml(sim_yaml, "sim_node")
    run = 0.5 * (p["ramp.x_max"] - p["ramp.x_min"] - p["ramp.flat_top_length"])
    return run * math.tan(math.radians(p["ramp.slope_deg"]))


def mean_velocity_std(estimates) -> np.ndarray:
    """Mean standard deviation of vx, vy, vyaw over the estimates (their covariance diagonal)."""
    from ekf_localization.ros.conversions import odometry_arrays

    sig = [np.sqrt(np.clip(np.diag(odometry_arrays(e)[3])[[0, 1, 5]], 0.0, None)) for e in estimates]
    return np.mean(sig, axis=0) if sig else np.full(3, math.nan)
