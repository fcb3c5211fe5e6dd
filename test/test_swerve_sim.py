"""The simulated swerve robot: its limits (steering rate, drive acceleration, the floor's grip),
its module states read back into the body twist, its parameters, and the closed loop over DDS
(``ekf_demo --drive swerve`` on a short path)."""

from __future__ import annotations

import dataclasses
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from helpers.ros_helpers import REPO, allocate_domain

from ekf_localization.core.joint_states import EncoderInputConfig
from ekf_localization.core.measurements import JointStateMeasurement
from ekf_localization.core.swerve_states import SwerveSpeeds
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.models.swerve import SwerveKinematics, module_vectors
from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml
from ekf_localization.tools import bag_io
from sim_robot.ros.sim_params import parse_parameters
from sim_robot.world.swerve_drive import SwerveDriveConfig
from sim_robot.world.wheel_encoder_sensor import WheelEncoderConfig, WheelEncoderReading
from sim_robot.world.world import World, WorldConfig

MS = 1_000_000


def world(**swerve) -> World:
    cfg = WorldConfig(drive="swerve", swerve=SwerveDriveConfig(**swerve), pose_variance_rate=(0.0, 0.0, 0.0),
                      velocity_variance_per_step=(0.0, 0.0, 0.0),
                      wheel_encoders=WheelEncoderConfig(enabled=True, resolution=0.0))
    w = World(cfg, 1, seed=3)
    w.reset([0.0, 0.0, 0.0])
    return w


def test_a_step_ramps_at_the_drive_limit_and_reaches_the_command():
    w = world()
    cfg = w.config.swerve
    w.set_command([1.0, 0.0, 0.0])
    w.advance(100 * MS)
    assert w.truth[0, 3] == pytest.approx(0.1 * cfg.drive_acceleration_limit * cfg.wheel_radius, rel=0.02)
    w.advance(400 * MS)
    np.testing.assert_allclose(w.truth[0, 3:], [1.0, 0.0, 0.0], atol=1e-9)
    assert np.max(w.swerve.slip) < 1e-9


def test_modules_steer_at_most_at_the_steering_rate():
    w = world()
    w.set_command([0.0, 1.0, 0.0])  # from rest at angle 0: a quarter turn
    w.advance(50 * MS)
    np.testing.assert_allclose(w.swerve.angles, 0.05 * 12.0, atol=1e-9)
    w.advance(500 * MS)
    np.testing.assert_allclose(w.swerve.angles, math.pi / 2, atol=1e-9)
    np.testing.assert_allclose(w.truth[0, 3:], [0.0, 1.0, 0.0], atol=1e-6)


def test_a_module_slips_when_asked_for_more_than_the_floor_gives():
    """Wheels that accelerate at 10 m/s² on a floor that gives 3 m/s²: the body follows at the
    floor's 3 m/s², the wheels run ahead (slip); with grip to spare there is none."""
    w = world(drive_acceleration_limit=10.0 / 0.0508, traction_limit=3.0)
    w.set_command([2.0, 0.0, 0.0])
    w.advance(100 * MS)
    assert w.truth[0, 3] == pytest.approx(0.3, abs=0.01)
    assert np.all(w.swerve.slip > 0.5)
    w.advance(2000 * MS)
    assert np.max(w.swerve.slip) < 1e-9
    assert w.truth[0, 3] == pytest.approx(2.0)


def test_swerve_takes_twists_not_wheel_speeds():
    with pytest.raises(ValueError, match="twist"):
        world().set_wheel_command(np.zeros(4))


def test_module_states_read_back_to_the_body_twist():
    """The encoders' drive joints (gear and coupling ratios) and steer angles, through the jointN
    swerve tracker and the modules' least-squares fit: the truth twist, across a turn."""
    w = world()
    sw = w.config.swerve
    names = tuple(f"m{i}_drive" for i in range(4)) + tuple(f"m{i}_steer" for i in range(4))
    cfg = EncoderInputConfig(names=names[:4], geometry="swerve", steer_names=names[4:],
                             module_positions=tuple(sw.kinematics.positions.ravel()),
                             wheel_radius=sw.wheel_radius,
                             drive_gear_ratio=sw.drive_gear_ratio, coupling_ratio=sw.coupling_ratio)
    tracker = SwerveSpeeds(cfg)
    fit = np.linalg.pinv(SwerveKinematics(cfg.module_positions).module_rows)
    w.set_command([0.8, 0.3, 1.5])
    w.advance(600 * MS)  # steady: modules settled
    checked = 0
    for _ in range(20):
        for r in w.advance(20 * MS):
            if isinstance(r, WheelEncoderReading):
                q = np.concatenate([r.positions[0], r.steer_angles[0]])
                js = JointStateMeasurement(r.stamp_ns, names, q, np.array([]))
                sample, reason = tracker.update(js)
                assert reason is None
                if sample is not None:
                    np.testing.assert_allclose(fit @ module_vectors(sample.speeds, sample.angles),
                                               [0.8, 0.3, 1.5], atol=1e-6)
                    checked += 1
    assert checked > 10


def test_sim_swerve_yaml_parses_and_a_degenerate_layout_is_refused():
    values = parameters_from_yaml(REPO / "config" / "sim_swerve.yaml", "sim_node")
    cfg, node = parse_parameters(values)
    assert cfg.drive == "swerve" and cfg.swerve.n_modules == 4
    names = node.driven_joint_names
    assert names[0] == "front_left_drive" and names[-1] == "rear_right_steer" and len(names) == 8
    with pytest.raises(ParameterError) as err:
        parse_parameters({**values, "swerve.module_positions": [0.2, 0.2] * 4})
    assert err.value.name == "swerve.module_positions"
    with pytest.raises(ParameterError) as err:
        parse_parameters({**values, "swerve.module_names": ["a", "b"]})
    assert err.value.name == "swerve.module_names"


def test_the_default_world_is_unchanged_by_the_swerve_section():
    assert dataclasses.replace(WorldConfig(), swerve=SwerveDriveConfig()) == WorldConfig()


SHORT_PATH = """name: swerve_short
frame_id: map
closed: false
waypoints:
  - [-0.9144, -0.2032]
  - [-0.4064, -0.2032]
  - [-0.4064,  0.5]
"""


@pytest.mark.ros
def test_swerve_closed_loop_runs_over_dds(tmp_path):
    """ekf_demo --drive swerve on a short path: the nodes run, the EKF fuses the modules, and the
    table has the EKF, the modules' dead reckoning and the live NEES lines."""
    path = tmp_path / "short.yaml"
    path.write_text(SHORT_PATH)
    sim = tmp_path / "sim.yaml"  # --sim-params: the drive's robot with its ground truth at 50 Hz
    sim.write_text((REPO / "config" / "sim_swerve.yaml").read_text().replace(
        "    ground_truth:\n      frequency: 100.0", "    ground_truth:\n      frequency: 50.0"))
    out = tmp_path / "demo"
    # real time, as test_closed_loop: the suite's other worker may run a demo of its own, and a world
    # at --rtf 2 that cannot keep up holds a core at its SCHED_FIFO (docs/under_load.md)
    cmd = [sys.executable, "-m", "ekf_localization.tools.demo", "--drive", "swerve", "--path-file", str(path),
           "--sim-params", str(sim), "--rtf", "1.0", "--seed", "1", "--out", str(out), "--timeout", "90"]
    env = dict(os.environ, ROS_DOMAIN_ID=str(allocate_domain()))
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=REPO, env=env)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    table = (out / "rmse.txt").read_text()
    rows = {line.split("  ")[0]: line.split() for line in table.splitlines()}
    ekf = float(rows["EKF /odometry/filtered"][2])
    assert ekf < 0.05, table  # (x, y) RMSE, m
    assert "dead reckoning (swerve modules)" in rows, table
    assert "NEES live pose mean" in table and "NEES live twist mean" in table
    assert "NIS joint0/encoders mean" in table and "(dimension 8," in table
    # the command guard at size 1e-3 a 0.25 s window: over this ~4 s drive ~0.02 false trips
    # expected, P(2 or more) ~ 2e-4; a swerve response the IMU's yaw rate contradicts at a
    # corner trips it once a corner and leaves the twist lagging
    trips = re.search(r"command guard: (\d+) trips", table)
    assert trips is not None and int(trips.group(1)) <= 1, table
    truth = bag_io.read_odometry(out / "bag", "/ground_truth/odom")
    # the --sim-params file's rate: its 50 Hz grid, and not the drive's 100 Hz one. The demo adds a
    # truth sample at each /clock stamp too (ground_truth.at_clock), which may fall on that grid:
    # those stamps are not counted.
    clock = {stamp_to_ns(m.msg.clock) for m in bag_io.iter_messages(out / "bag", ["/clock"])}
    on_10ms = truth.t_ns[truth.t_ns % (10 * MS) == 0]
    on_20ms = on_10ms[on_10ms % (20 * MS) == 0]
    assert len(on_20ms) >= 0.9 * (truth.t_ns[-1] - truth.t_ns[0]) / (20 * MS)
    off_grid = [t for t in on_10ms if t % (20 * MS) != 0 and int(t) not in clock]
    assert len(off_grid) <= 0.1 * len(on_20ms), off_grid[:10]


@pytest.mark.parametrize("args, needle", [
    (["--drive", "swerve", "--joint-states"], "--drive mecanum"),
    (["--drive", "tank", "--ramp"], "--drive mecanum"),
    (["--sim-params", "/nonexistent/sim.yaml"], "no such file"),
    (["--drive", "hovercraft"], "invalid choice"),
])
def test_demo_refuses_what_a_drive_cannot_run(args, needle, capsys):
    from ekf_localization.tools import demo

    with pytest.raises(SystemExit) as exc:
        demo.main(args)
    assert exc.value.code == 2
    assert needle in capsys.readouterr().err
