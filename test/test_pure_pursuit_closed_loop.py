"""Closed loop without ROS: the follower drives the simulator (perfect localization) along
each preset path, mecanum (holonomic mode) and tank (differential mode).

Writes a plot of path vs driven trajectory to tmp_path (and to $EKF_PLOT_DIR if set).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path as FilePath

import numpy as np
import pytest
from helpers.images import assert_plot_png

from ekf_localization.control.field_path import FieldPath, load_preset
from ekf_localization.control.pure_pursuit import FollowerConfig, PurePursuitFollower
from ekf_localization.core.angles import wrap_angle
from sim_robot.world import world as world_mod
from sim_robot.world.drives import DriveLimits
from sim_robot.world.field import Field

CONTROL_PERIOD_NS = 10_000_000  # 100 Hz, as in the experiments
# goBILDA 312 rpm motors (32.7 rad/s, 1.57 m/s on 96 mm wheels); a wheel acceleration that
# gives about 3 m/s² of robot acceleration
LIMITS = DriveLimits(wheel_speed_limit=32.7, wheel_acceleration_limit=60.0)
HALF_FIELD = 1.8288
ROBOT_HALF_SIZE = 9 * 0.0254
CASES = [("seed000_test_path", "mecanum"), ("seed000_test_path", "tank"),
         ("ftc_cycle", "mecanum"), ("ftc_cycle", "tank")]
FTC_CYCLES = 2


@dataclass
class Run:
    path: FieldPath
    drive: str
    t_s: np.ndarray
    truth: np.ndarray  # (T, 6)
    done_time_s: float | None
    final_pose: np.ndarray
    max_cross_track: float
    max_speed: float
    drift_after_stop: float
    legs_done: int


def drive(path_name: str, drive: str, config: FollowerConfig | None = None) -> Run:
    path = load_preset(path_name, cycles=FTC_CYCLES if path_name == "ftc_cycle" else None)
    field = Field.preset("seed000" if path_name.startswith("seed") else "freight_frenzy")
    cfg = world_mod.WorldConfig(drive=drive, limits=LIMITS, field=field)
    cfg = replace(cfg, camera=replace(cfg.camera, enabled=False), imu=replace(cfg.imu, enabled=False),
                  dead_wheels=replace(cfg.dead_wheels, enabled=False))
    world = world_mod.World(cfg, n_trials=1, seed=7)
    mode = "holonomic" if drive == "mecanum" else "differential"
    follower = PurePursuitFollower(path, replace(config or FollowerConfig(), mode=mode))
    world.reset(np.array(path.start))
    times, states = [], []
    done_t = None
    max_ct = 0.0
    limit_ns = int(60e9)
    while world.t_ns < limit_ns:
        s = world.truth[0]
        times.append(world.t_ns * 1e-9)
        states.append(s.copy())
        cmd = follower.update(float(s[0]), float(s[1]), float(s[2]), world.t_ns)
        max_ct = max(max_ct, follower.cross_track_error)
        if follower.done:
            done_t = world.t_ns * 1e-9
            break
        world.set_command(np.array(cmd))
        world.advance(CONTROL_PERIOD_NS)
    final = world.truth[0].copy()
    # a clean stop: zero command after done, the robot stays put
    world.set_command(np.zeros(3))
    world.advance(500_000_000)
    drift = float(np.hypot(*(world.truth[0, :2] - final[:2])))
    truth = np.array(states)
    speed = np.hypot(truth[:, 3], truth[:, 4])
    return Run(path, drive, np.array(times), truth, done_t, final, max_ct, float(speed.max()), drift,
               follower.leg)


@pytest.fixture(scope="module")
def runs() -> dict[tuple[str, str], Run]:
    return {case: drive(*case) for case in CASES}


@pytest.mark.parametrize("case", CASES, ids=[f"{p}-{d}" for p, d in CASES])
def test_finishes_within_tolerance_and_time(runs, case):
    run = runs[case]
    cfg = FollowerConfig()
    path = run.path
    assert run.done_time_s is not None, "follower never finished"
    # time: the path at max speed plus 60% (acceleration, corners), and per stop 1.5 s to
    # brake and settle plus a half turn at the maximum yaw rate (the tank turns round in place)
    per_stop = 1.5 + math.pi / cfg.max_angular_velocity
    budget = 1.6 * path.length / cfg.max_linear_velocity + per_stop * len(path.stop_s)
    assert run.done_time_s <= budget, (run.done_time_s, budget)
    assert run.legs_done == len(path.stop_s)
    end_x, end_y = path.xs[-1], path.ys[-1]
    pos_err = math.hypot(run.final_pose[0] - end_x, run.final_pose[1] - end_y)
    head_err = abs(wrap_angle(path.stop_heading(len(path.stop_s) - 1) - run.final_pose[2]))
    assert pos_err <= cfg.goal_position_tolerance
    assert head_err <= cfg.goal_heading_tolerance
    # pure pursuit cuts corners and curves (about L²/2R on an arc of radius R): half the lookahead
    assert run.max_cross_track <= 0.5 * cfg.lookahead_distance, run.max_cross_track
    assert run.max_speed <= cfg.max_linear_velocity + 0.1  # + the truth's velocity noise
    assert run.drift_after_stop < 0.01
    # the driven trajectory stays on the field with the robot's footprint
    assert np.all(np.abs(run.truth[:, :2]) <= HALF_FIELD - ROBOT_HALF_SIZE), np.abs(run.truth[:, :2]).max()


def test_plot_path_vs_trajectory(runs, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    fig, axes = plt.subplots(2, 2, figsize=(12, 12), dpi=100)
    for ax, case in zip(axes.ravel(), CASES, strict=True):
        run = runs[case]
        field = Field.preset("seed000" if case[0].startswith("seed") else "freight_frenzy")
        h = field.half_size
        ax.add_patch(Rectangle((-h, -h), 2 * h, 2 * h, fill=False, lw=1.5, color="0.3"))
        _, _, ends = field.image_arrays()
        for e in ends:
            ax.plot(e[:, 0], e[:, 1], color="tab:green", lw=5, solid_capstyle="butt")
        ax.plot([], [], color="tab:green", lw=5, label="wall images")
        pts = run.path.points()
        ax.plot(pts[:, 0], pts[:, 1], "--", color="0.45", lw=1.5, label="path")
        stops = pts[list(run.path.stop_indices)]
        ax.plot(stops[:, 0], stops[:, 1], "D", color="tab:purple", ms=7, mfc="none", label="stop points")
        tr = run.truth
        sc = ax.scatter(tr[:, 0], tr[:, 1], c=np.hypot(tr[:, 3], tr[:, 4]), s=3, cmap="viridis",
                        vmin=0.0, vmax=1.0, zorder=3)
        ax.plot(*tr[0, :2], "o", color="green", ms=8, label="start")
        ax.plot(*run.final_pose[:2], "s", color="red", ms=7, label="end")
        for k in range(0, len(tr), 100):  # heading every second
            ax.annotate("", xy=(tr[k, 0] + 0.12 * math.cos(tr[k, 2]), tr[k, 1] + 0.12 * math.sin(tr[k, 2])),
                        xytext=(tr[k, 0], tr[k, 1]),
                        arrowprops={"arrowstyle": "->", "color": "tab:red", "lw": 1.0})
        mode = "holonomic" if run.drive == "mecanum" else "differential"
        ax.set_title(f"{run.path.name} ({run.path.cycles} cycle{'s' * (run.path.cycles > 1)}), "
                     f"{run.drive} / {mode}\ndone in {run.done_time_s:.2f} s, "
                     f"max cross-track {100 * run.max_cross_track:.1f} cm", fontsize=10)
        ax.set_aspect("equal")
        lo = np.maximum(pts.min(axis=0) - 0.5, -h - 0.05)  # zoom on the path, walls if near
        hi = np.minimum(pts.max(axis=0) + 0.5, h + 0.05)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("x [m] (map)")
        ax.set_ylabel("y [m]")
        ax.legend(loc="best", fontsize=7)
        fig.colorbar(sc, ax=ax, shrink=0.7, label="speed [m/s] (arrows: heading, 1 s apart)")
    fig.suptitle("Pure pursuit, perfect localization: path vs driven trajectory (sim truth)")
    fig.tight_layout()
    outs = [tmp_path / "pure_pursuit_closed_loop.png"]
    if os.environ.get("EKF_PLOT_DIR"):
        outs.append(FilePath(os.environ["EKF_PLOT_DIR"]) / "pure_pursuit_closed_loop.png")
    for out in outs:
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out)
        assert_plot_png(out, 1200, 1200)  # 12 x 12 in at 100 dpi
    plt.close(fig)
