"""The simulated world: truth model (seed 000 eq. 22-26), limits, batching, clock, units."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers.sim_world import MS, assert_variance, noiseless

from ekf_localization.core.units import METRES_PER_INCH
from ekf_localization.models.sensors.camera import CameraNoise
from ekf_localization.models.sensors.dead_wheels import EncoderNoise
from sim_robot.ros.sim_params import parse_parameters
from sim_robot.world.camera_sensor import CameraConfig, CameraReading
from sim_robot.world.dead_wheel_sensor import DeadWheelConfig, DeadWheelReading
from sim_robot.world.drives import DriveLimits, scale_to_speed_limit
from sim_robot.world.imu_sensor import ImuConfig, ImuReading
from sim_robot.world.world import TruthReading, World, WorldConfig

IN = METRES_PER_INCH

def test_defaults_are_seed000_in_si_and_inch_constants_are_exact():
    assert WorldConfig() == WorldConfig.seed000(1.0)
    cfg = WorldConfig.seed000_inches()
    assert cfg.pose_variance_rate == (0.002, 0.002, 0.002)
    assert cfg.velocity_variance_per_step == (0.45, 0.45, 0.45)
    assert cfg.dead_wheels.noise == EncoderNoise(0.002, 0.001)
    assert cfg.camera.position_noise == CameraNoise(0.001, 0.001)
    assert cfg.camera.yaw_noise == CameraNoise(0.001, 0.001)
    assert cfg.camera.field_of_view == pytest.approx(math.radians(70.0))
    assert cfg.field.size == 144.0
    assert cfg.physics_period_ns == 1 * MS


def test_si_world_is_the_inch_world_scaled_exactly():
    """Same seed, same command: every length differs by exactly 0.0254, angles not at all."""
    w_in = World(WorldConfig.seed000_inches(), n_trials=4, seed=11)
    w_si = World(WorldConfig(), n_trials=4, seed=11)
    start_in = np.array([[0.0, 0.0, 1.2], [30.0, -20.0, 1.6], [-36.0, 40.0, 1.5708], [10.0, 60.0, -1.5]])
    start_si = start_in * [IN, IN, 1.0]
    w_in.reset(start_in)
    w_si.reset(start_si)
    cmd_in = np.array([20.0, 5.0, 0.4])
    w_in.set_command(cmd_in)
    w_si.set_command(cmd_in * [IN, IN, 1.0])
    r_in, r_si = w_in.advance(500 * MS), w_si.advance(500 * MS)
    lin = np.array([IN, IN, 1.0, IN, IN, 1.0])
    np.testing.assert_allclose(w_si.truth, w_in.truth * lin, rtol=1e-9, atol=1e-12)
    assert len(r_in) == len(r_si) > 0
    seen = 0
    for a, b in zip(r_in, r_si, strict=True):
        assert type(a) is type(b) and a.stamp_ns == b.stamp_ns
        if isinstance(a, DeadWheelReading):
            np.testing.assert_allclose(b.encoders, a.encoders * IN, rtol=1e-9, atol=1e-15)
            np.testing.assert_allclose(b.encoder_variances, a.encoder_variances * IN**2, rtol=1e-9)
        if isinstance(a, CameraReading):
            np.testing.assert_array_equal(a.visible, b.visible)
            seen += int(a.visible.sum())
            np.testing.assert_allclose(b.pose[a.visible], a.pose[a.visible] * [IN, IN, 1.0], rtol=1e-9)
            np.testing.assert_allclose(b.distance[a.visible], a.distance[a.visible] * IN, rtol=1e-9)
    assert seen > 0, "the camera never saw an image: the comparison would be empty"


def test_truth_follows_eq_22_to_25_without_noise():
    cfg = noiseless(WorldConfig())
    w = World(cfg, seed=0)
    w.reset([0.5, -0.25, 0.3])
    cmd = np.array([0.6, 0.2, 0.5])
    w.set_command(cmd)
    w.step()
    # tick 1: position uses the previous (zero) velocity; velocity = eq. 24 of the wheels
    np.testing.assert_allclose(w.truth[0, :3], [0.5, -0.25, 0.3], atol=1e-15)
    np.testing.assert_allclose(w.truth[0, 3:], cmd, atol=1e-12)
    w.step()
    dt = 1e-3
    c, s = math.cos(0.3), math.sin(0.3)
    expected = [0.5 + dt * (0.6 * c - 0.2 * s), -0.25 + dt * (0.6 * s + 0.2 * c), 0.3 + dt * 0.5]
    np.testing.assert_allclose(w.truth[0, :3], expected, atol=1e-15)
    # steady state: no acceleration except the centripetal term [-wz·vy, wz·vx]
    np.testing.assert_allclose(w.truth_accel[0], [-0.5 * 0.2, 0.5 * 0.6], atol=1e-9)


def test_truth_process_noise_matches_eq_26():
    """One tick from rest: position noise variance 0.002·Δt in², velocity noise 0.45 (in/s)²."""
    n = 20_000
    w = World(WorldConfig.seed000_inches(), n_trials=n, seed=3)
    w.reset(np.zeros(3))
    w.step()
    truth = w.truth
    for j, name in enumerate(["x", "y", "θ"]):
        assert_variance(truth[:, j], 0.002 * 1e-3, f"{name} noise")
    for j, name in enumerate(["vx", "vy", "wz"]):
        assert_variance(truth[:, 3 + j], 0.45, f"{name} noise")


def test_tank_never_moves_sideways():
    w = World(WorldConfig(drive="tank"), n_trials=3, seed=5)
    w.reset(np.zeros(3))
    w.set_command([0.5, 0.7, -0.4])  # vy is ignored
    for _ in range(50):
        w.advance(10 * MS)
        assert np.all(w.truth[:, 4] == 0.0)
    assert w.wheel_speeds.shape == (3, 2)


def test_a_short_strafe_moves_the_body_not_the_wheels():
    """strafe_scale 0.9: vy is 0.9 × eq. 24's from the wheels, which turn as commanded."""
    w, short = (World(noiseless(WorldConfig(strafe_scale=k)), seed=0) for k in (1.0, 0.9))
    for world in (w, short):
        world.reset(np.zeros(3))
        world.set_command([0.2, 0.3, 0.1])
        world.advance(5 * MS)
    np.testing.assert_array_equal(short.wheel_speeds, w.wheel_speeds)
    np.testing.assert_allclose(short.truth[0, 3:], [0.2, 0.27, 0.1], atol=1e-12)
    with pytest.raises(ValueError, match="strafe_scale"):
        WorldConfig(strafe_scale=0.0)
    assert parse_parameters({"mecanum.strafe_scale": 0.9})[0].strafe_scale == 0.9  # --sim-params


def test_limits_are_honoured_and_keep_the_direction():
    limits = DriveLimits(wheel_speed_limit=20.0, wheel_acceleration_limit=50.0)
    w = World(noiseless(dataclasses.replace(WorldConfig(), limits=limits)), seed=0)
    w.reset(np.zeros(3))
    cmd = np.array([3.0, 1.0, 2.0])  # needs more than 20 rad/s on some wheel
    w.set_command(cmd)
    target = scale_to_speed_limit(WorldConfig().mecanum.twist_to_wheels(cmd)[None], 20.0)[0]
    target_dir = target / np.linalg.norm(target)
    assert np.max(np.abs(target)) == pytest.approx(20.0)
    prev = w.wheel_speeds[0]
    for _ in range(800):
        w.step()
        now = w.wheel_speeds[0]
        assert np.max(np.abs(now)) <= 20.0 + 1e-9
        assert np.max(np.abs(now - prev)) <= 50.0 * 1e-3 + 1e-12
        np.testing.assert_allclose(now / np.linalg.norm(now), target_dir, atol=1e-12)
        prev = now
    # after 20/50 s = 0.4 s the ramp is over: the twist is the command scaled to the limit
    np.testing.assert_allclose(w.wheel_speeds[0], target, atol=1e-12)
    twist = w.truth[0, 3:]
    np.testing.assert_allclose(twist / np.linalg.norm(twist), cmd / np.linalg.norm(cmd), atol=1e-12)


def test_batched_world_equals_single_trials_without_noise():
    cfg = noiseless(WorldConfig())
    starts = np.array([[0.0, 0.0, 0.0], [1.0, -0.5, 2.0], [-1.2, 1.1, -2.5]])
    cmds = np.array([[0.5, 0.0, 0.2], [0.1, -0.3, 1.0], [-0.4, 0.2, -0.7]])
    batch = World(cfg, n_trials=3, seed=9)
    batch.reset(starts)
    batch.set_command(cmds)
    rb = batch.advance(700 * MS)
    for i in range(3):
        single = World(cfg, n_trials=1, seed=123 + i)
        single.reset(starts[i])
        single.set_command(cmds[i])
        rs = single.advance(700 * MS)
        np.testing.assert_allclose(single.truth[0], batch.truth[i], atol=1e-12)
        assert len(rs) == len(rb)
        for a, b in zip(rs, rb, strict=True):
            assert a.stamp_ns == b.stamp_ns
            if isinstance(a, DeadWheelReading):
                np.testing.assert_allclose(a.encoders[0], b.encoders[i], atol=1e-12)
                np.testing.assert_allclose(a.pose[0], b.pose[i], atol=1e-12)
            if isinstance(a, CameraReading):
                assert a.visible[0] == b.visible[i]


def test_truth_does_not_depend_on_sensors_or_on_how_time_is_split():
    a = World(WorldConfig(), n_trials=2, seed=4)
    cfg_b = dataclasses.replace(WorldConfig(), camera=CameraConfig(enabled=False),
                                dead_wheels=DeadWheelConfig(period_ns=3 * MS))
    b = World(cfg_b, n_trials=2, seed=4)
    for w in (a, b):
        w.reset([0.1, 0.2, 0.3])
        w.set_command([0.4, 0.1, 0.3])
    a.advance(2500 * MS)
    for _ in range(2500):
        b.step()
    np.testing.assert_array_equal(a.truth, b.truth)


def test_integer_clock_and_stamps_never_drift():
    w = World(WorldConfig(), seed=0)
    w.reset(np.zeros(3))
    chunks = [1 * MS, 7 * MS, 10 * MS, 13 * MS, 1000 * MS]
    readings = []
    ticks = 0
    for k in range(60):
        d = chunks[k % len(chunks)]
        readings += w.advance(d)
        ticks += d // MS
        assert isinstance(w.t_ns, int) and w.t_ns == ticks * MS
    for r in readings:
        assert isinstance(r.stamp_ns, int)
    dw = [r.stamp_ns for r in readings if isinstance(r, DeadWheelReading)]
    assert dw == [10 * MS * (k + 1) for k in range(len(dw))]
    assert dw[-1] == w.t_ns - w.t_ns % (10 * MS)
    with pytest.raises(ValueError, match="multiple"):
        w.advance(MS // 2)
    with pytest.raises(TypeError):
        w.advance(0.01)  # float seconds are not a duration


def test_each_sensor_at_its_own_rate_and_camera_latency():
    cfg = dataclasses.replace(
        WorldConfig(), truth_period_ns=20 * MS, imu=ImuConfig(period_ns=1 * MS),
        dead_wheels=DeadWheelConfig(period_ns=10 * MS),
        camera=CameraConfig(period_ns=40 * MS, latency_ns=55_500_000))
    w = World(cfg, seed=0)
    w.reset([0.0, 0.0, 0.5 * math.pi])  # facing the top wall images
    out = w.advance(1000 * MS)
    count = {t: sum(isinstance(r, t) for r in out) for t in (TruthReading, ImuReading, DeadWheelReading)}
    assert count == {TruthReading: 50, ImuReading: 1000, DeadWheelReading: 100}
    cams = [r for r in out if isinstance(r, CameraReading)]
    assert [c.stamp_ns for c in cams] == [40 * MS * (k + 1) for k in range(len(cams))]
    assert all(c.arrival_ns == c.stamp_ns + 55_500_000 for c in cams)
    assert len(cams) == 23  # captures up to 1000 ms whose arrival (+55.5 ms) is within the run
    assert all(c.visible[0] for c in cams)
    # the IMU samples every tick and comes before the camera on the same tick: the IMU
    # reading just before a camera reading gives its delivery time = first tick >= arrival
    for k, r in enumerate(out):
        if isinstance(r, CameraReading):
            prev = out[k - 1]
            assert isinstance(prev, ImuReading)
            assert prev.stamp_ns == -(-r.arrival_ns // MS) * MS


def test_bad_inputs_are_rejected():
    w = World(WorldConfig(), n_trials=2, seed=0)
    with pytest.raises(ValueError, match="finite"):
        w.set_command([np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match="shape"):
        w.reset(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="multiple of physics_period_ns"):
        WorldConfig(imu=ImuConfig(period_ns=1_500_000))
    with pytest.raises(ValueError, match="drive"):
        WorldConfig(drive="hovercraft")


def test_a_command_acts_at_its_stamp_plus_the_latency():
    """sim_node's drive: a command acts from stamp + command_latency_ns, whenever it was given
    (batch boundaries do not matter); one given after that acts at once and is counted late."""
    cfg = dataclasses.replace(noiseless(WorldConfig()), command_latency_ns=20 * MS)
    split = World(cfg, seed=0)
    whole = World(cfg, seed=0)
    split.advance(7 * MS)
    assert split.set_command([0.4, 0.0, 0.0], stamp_ns=3 * MS)  # acts at 23 ms
    whole.set_command([0.4, 0.0, 0.0], stamp_ns=3 * MS)
    split.advance(16 * MS)
    assert split.truth[0, 3] == 0.0  # 23 ms: not yet
    split.advance(1 * MS)
    assert split.truth[0, 3] > 0.0  # the tick from 23 ms on
    split.advance(16 * MS)
    whole.advance(40 * MS)
    np.testing.assert_array_equal(split.truth, whole.truth)
    assert split.late_commands == 0
    assert not split.set_command([0.0, 0.0, 0.0], stamp_ns=5 * MS)  # due at 25 ms, now 40 ms: late
    assert split.late_commands == 1
    split.step()
    assert split.truth[0, 3] < whole.truth[0, 3]
    # later stamps win over queued earlier ones in stamp order
    w = World(cfg, seed=0)
    w.set_command([0.2, 0.0, 0.0], stamp_ns=10 * MS)
    w.set_command([0.1, 0.0, 0.0], stamp_ns=0)
    w.advance(25 * MS)
    v_first = w.truth[0, 3]
    w.advance(20 * MS)
    assert 0.0 < v_first < w.truth[0, 3]
