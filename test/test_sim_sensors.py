"""Simulated sensors: dead wheels (eq. 29-32), camera (70° FOV, eq. 32), IMU."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers.sim_world import MS, TINY, assert_variance, noiseless

from ekf_localization.core.angles import wrap_angles
from ekf_localization.models.sensors.camera import CameraNoise
from ekf_localization.models.sensors.dead_wheels import EncoderNoise
from sim_robot.world.camera_sensor import CameraConfig, CameraReading, CameraSensor, image_visibility
from sim_robot.world.dead_wheel_sensor import DeadWheelConfig, DeadWheelReading
from sim_robot.world.field import Field, FieldImage
from sim_robot.world.imu_sensor import ImuConfig, ImuReading
from sim_robot.world.world import World, WorldConfig

W, D = 0.17, 0.1  # WorldConfig() dead-wheel geometry
FOV = math.radians(70.0)


def first(readings, kind):
    return next(r for r in readings if isinstance(r, kind))


def run_constant(cfg: WorldConfig, twist, n_trials: int = 1, pose=(0.0, 0.0, 0.0), duration_ms: int = 100,
                 seed: int = 0):
    w = World(cfg, n_trials=n_trials, seed=seed)
    w.reset(np.asarray(pose, dtype=float))
    w.set_command(np.asarray(twist, dtype=float))
    return w, w.advance(duration_ms * MS)


# -- dead wheels ---------------------------------------------------------------------------
@pytest.mark.parametrize("sampling", ["instantaneous", "interval_average"])
@pytest.mark.parametrize(("twist", "expected"), [
    ((0.7, 0.0, 0.0), (0.7, 0.7, 0.0)),  # pure forward: E_L = E_R = vx
    ((0.0, -0.4, 0.0), (0.0, 0.0, -0.4)),  # pure strafe: E_a = vy
    ((0.0, 0.0, 1.3), (-W * 1.3, W * 1.3, -D * 1.3)),  # pure rotation: eq. 30
])
def test_encoders_match_eq_29_30(sampling, twist, expected):
    cfg = noiseless(WorldConfig())
    cfg = dataclasses.replace(cfg, dead_wheels=dataclasses.replace(cfg.dead_wheels, sampling=sampling))
    _, out = run_constant(cfg, twist)
    dw = [r for r in out if isinstance(r, DeadWheelReading)]
    np.testing.assert_allclose(dw[-1].encoders[0], expected, atol=1e-12)
    np.testing.assert_allclose(dw[-1].twist[0], twist, atol=1e-12)  # eq. 29 inverts eq. 30


def test_encoder_noise_matches_eq_32():
    cfg = noiseless(WorldConfig.seed000_inches())  # truth exact, encoder noise from R below
    cfg = dataclasses.replace(cfg, dead_wheels=dataclasses.replace(
        cfg.dead_wheels, noise=EncoderNoise(0.002, 0.001)))
    twist = (30.0, -10.0, 1.5)
    n = 20_000
    _, out = run_constant(cfg, twist, n_trials=n, duration_ms=10)
    r = first(out, DeadWheelReading)
    E_true = cfg.dead_wheels.geometry.encoders_from_twist @ np.array(twist)
    for j, name in enumerate(["E_L", "E_R", "E_a"]):
        assert_variance(r.encoders[:, j] - E_true[j], 0.002 * E_true[j] ** 2 + 0.001, name)
    np.testing.assert_allclose(r.encoder_variances, 0.002 * r.encoders**2 + 0.001)
    # twist covariance = eq. 29 applied to the diagonal encoder covariance
    M = cfg.dead_wheels.geometry.twist_from_encoders
    np.testing.assert_allclose(r.twist_cov[0], M @ np.diag(r.encoder_variances[0]) @ M.T, rtol=1e-12)


def test_integrated_pose_follows_the_truth_with_growing_covariance():
    cfg = noiseless(WorldConfig())
    # interval averages see exactly the truth's displacement (its first tick moves with v = 0)
    cfg = dataclasses.replace(
        cfg, dead_wheels=dataclasses.replace(cfg.dead_wheels, sampling="interval_average"))
    w, out = run_constant(cfg, (0.8, 0.2, 0.9), pose=(0.3, -0.4, 1.0), duration_ms=2000)
    dws = [r for r in out if isinstance(r, DeadWheelReading)]
    assert len(dws) == 200
    assert abs(dws[-1].pose[0, 2] - w.truth[0, 2]) < 1e-9
    # truth: Euler steps at 1 kHz; odometry: exact arcs at 100 Hz -> differ by O(Δt)
    np.testing.assert_allclose(dws[-1].pose[0, :2], w.truth[0, :2], atol=2e-3)
    cfg_noisy = WorldConfig()
    _, out = run_constant(cfg_noisy, (0.8, 0.2, 0.9), duration_ms=500)
    traces = [np.trace(r.pose_cov[0]) for r in out if isinstance(r, DeadWheelReading)]
    assert all(b > a for a, b in zip(traces, traces[1:], strict=False))
    last = [r for r in out if isinstance(r, DeadWheelReading)][-1].pose_cov[0]
    np.testing.assert_array_equal(last, last.T)
    assert np.all(np.linalg.eigvalsh(last) > 0.0)


def test_pose_integration_can_be_disabled():
    cfg = dataclasses.replace(WorldConfig(), dead_wheels=DeadWheelConfig(integrate_pose=False))
    _, out = run_constant(cfg, (0.5, 0.0, 0.0), duration_ms=20)
    r = first(out, DeadWheelReading)
    assert r.pose is None and r.pose_cov is None


# -- camera --------------------------------------------------------------------------------
IMAGE_W = 0.254
ONE_IMAGE = Field(3.6576, (FieldImage(0.0, 0.0, 0.0, IMAGE_W, "test"),))  # at the origin, facing +x


def _camera_aiming(edge: float, margin: float, distance: float = 1.0, lateral: float = 0.3) -> np.ndarray:
    """A camera in front of the image, turned so that the image's outermost end point on the
    ``edge`` side (+1 left/CCW, -1 right) sits at bearing ``edge·(FOV/2 − margin)``."""
    cam = np.array([distance, lateral])
    to_centre = math.atan2(-lateral, -distance)
    ends = [np.array([0.0, s * IMAGE_W / 2]) for s in (1.0, -1.0)]
    bearings = [math.atan2(*(e - cam)[::-1]) - to_centre for e in ends]  # relative, no wrap issue here
    outer = max(bearings) if edge > 0 else min(bearings)
    yaw = to_centre + outer - edge * (FOV / 2 - margin)
    return np.array([[cam[0], cam[1], yaw]])


@pytest.mark.parametrize("edge", [1.0, -1.0])
def test_camera_sees_the_image_exactly_when_fully_inside_the_fov(edge):
    for margin, expected in [(1e-9, True), (-1e-9, False), (0.2, True), (-0.2, False)]:
        vis, _ = image_visibility(_camera_aiming(edge, margin), ONE_IMAGE, FOV, math.inf)
        assert bool(vis[0, 0]) is expected, f"margin {margin}"


def test_camera_visibility_range_and_back_side():
    pose = np.array([[1.5, 0.0, math.pi]])  # looking straight at the image from 1.5 m
    assert image_visibility(pose, ONE_IMAGE, FOV, 1.5 * (1 + 1e-12))[0][0, 0]
    assert not image_visibility(pose, ONE_IMAGE, FOV, 1.5 * (1 - 1e-12))[0][0, 0]
    behind = np.array([[-1.5, 0.0, 0.0]])  # looking at the back of the image
    assert not image_visibility(behind, ONE_IMAGE, FOV, math.inf)[0][0, 0]
    too_close = np.array([[0.1, 0.0, math.pi]])  # the 25 cm image spans > 70° from 10 cm
    assert not image_visibility(too_close, ONE_IMAGE, FOV, math.inf)[0][0, 0]
    np.testing.assert_allclose(image_visibility(pose, ONE_IMAGE, FOV, math.inf)[1], [[1.5]])


def test_camera_picks_the_nearest_visible_image_and_reports_nan_when_none():
    cfg = dataclasses.replace(noiseless(WorldConfig()).camera, period_ns=10 * MS)
    field = Field(3.6576, (FieldImage(0.0, 0.5, 0.0, IMAGE_W, "far"),
                           FieldImage(0.0, -0.1, 0.0, IMAGE_W, "near")))
    cam = CameraSensor(cfg, field, 3, np.random.default_rng(0))
    poses = np.array([[1.0, 0.0, math.pi], [1.0, 0.0, 0.0], [1.0, 2.0, math.pi]])
    r = cam.capture(5 * MS, poses)
    assert list(r.visible) == [True, False, False]
    assert r.image_index[0] == 1 and list(r.image_index[1:]) == [-1, -1]
    np.testing.assert_allclose(r.pose[0], poses[0], atol=1e-12)
    assert r.distance[0] == pytest.approx(math.hypot(1.0, 0.1))
    assert np.all(np.isnan(r.pose[1:])) and np.all(np.isnan(r.cov[1:]))


def test_camera_mount_sets_the_view_not_the_measured_pose_and_an_empty_field_sees_nothing():
    """From a camera mounted at [x y yaw] in base_link, d and the field of view are the camera's
    (the mount rotated by the robot's heading), the measured pose is the robot's."""
    mount = (0.2, -0.1, 0.3)
    cfg = dataclasses.replace(noiseless(WorldConfig()).camera, mount_pose=mount)
    robot = np.array([[1.5, 0.4, math.pi - 0.3]])  # the camera looks along -x at the image
    c, s = math.cos(robot[0, 2]), math.sin(robot[0, 2])
    camera = [1.5 + c * mount[0] - s * mount[1], 0.4 + s * mount[0] + c * mount[1]]
    r = CameraSensor(cfg, ONE_IMAGE, 1, np.random.default_rng(0)).capture(0, robot)
    assert r.visible[0] and r.image_index[0] == 0
    assert r.distance[0] == pytest.approx(math.hypot(*camera), rel=4 * np.finfo(float).eps)
    np.testing.assert_allclose(r.pose, robot, rtol=0.0, atol=1e-140)  # noise std sqrt(TINY)·d
    empty = CameraSensor(cfg, Field(3.6576, ()), 2, np.random.default_rng(0)).capture(0, np.zeros((2, 3)))
    assert not empty.visible.any() and list(empty.image_index) == [-1, -1]
    assert np.all(np.isnan(empty.pose)) and np.all(np.isnan(empty.distance))


def test_camera_noise_matches_a_d2_plus_b():
    a_p, b_p, a_y, b_y = 0.004, 1e-4, 0.02, 5e-4
    cfg = CameraConfig(position_noise=CameraNoise(a_p, b_p), yaw_noise=CameraNoise(a_y, b_y))
    n = 20_000
    cam = CameraSensor(cfg, ONE_IMAGE, n, np.random.default_rng(7))
    d = 1.2
    truth = np.tile([d, 0.0, math.pi], (n, 1))
    r = cam.capture(0, truth)
    assert r.visible.all()
    err = r.pose - truth
    err[:, 2] = wrap_angles(err[:, 2])
    assert_variance(err[:, 0], a_p * d * d + b_p, "x")
    assert_variance(err[:, 1], a_p * d * d + b_p, "y")
    assert_variance(err[:, 2], a_y * d * d + b_y, "yaw")
    np.testing.assert_allclose(r.cov[0], np.diag([a_p * d * d + b_p] * 2 + [a_y * d * d + b_y]))
    assert np.all((r.pose[:, 2] > -math.pi) & (r.pose[:, 2] <= math.pi))


def test_camera_outliers_at_the_configured_rate():
    p = 0.2
    cfg = CameraConfig(position_noise=CameraNoise(0.0, TINY), yaw_noise=CameraNoise(0.0, TINY),
                       outlier_probability=p, outlier_position_std=0.5, outlier_yaw_std=0.3)
    n = 20_000
    cam = CameraSensor(cfg, ONE_IMAGE, n, np.random.default_rng(8))
    truth = np.tile([1.0, 0.0, math.pi], (n, 1))
    r = cam.capture(0, truth)
    k = int(r.outlier.sum())
    assert abs(k - n * p) <= 5.0 * math.sqrt(n * p * (1 - p))
    err = r.pose - truth
    assert np.all(np.abs(err[~r.outlier]) < 1e-100)
    assert_variance(err[r.outlier, 0], 0.25, "outlier x")
    np.testing.assert_allclose(r.cov[r.outlier][:, 0, 0], TINY)  # nominal covariance reported


def test_camera_latency_and_stamp_in_world():
    cfg = dataclasses.replace(WorldConfig(), camera=CameraConfig(period_ns=50 * MS, latency_ns=30 * MS))
    _, out = run_constant(cfg, (0.0, 0.0, 0.0), pose=(0.0, 0.0, 0.5 * math.pi), duration_ms=200)
    cams = [r for r in out if isinstance(r, CameraReading)]
    assert [(c.stamp_ns, c.arrival_ns) for c in cams] == [(50 * MS, 80 * MS), (100 * MS, 130 * MS),
                                                          (150 * MS, 180 * MS)]


# -- IMU -----------------------------------------------------------------------------------
def test_imu_noise_and_centripetal_acceleration():
    imu = ImuConfig(period_ns=10 * MS, yaw_variance=4e-4, yaw_rate_variance=9e-4, accel_variance=0.04)
    cfg = dataclasses.replace(noiseless(WorldConfig()), imu=imu)
    n = 20_000
    twist = (0.8, 0.0, 0.5)
    w, out = run_constant(cfg, twist, n_trials=n, duration_ms=20)
    start, r = [x for x in out if isinstance(x, ImuReading)]  # r: the second period, at steady speed
    truth = w.truth
    # the first period holds the step from rest: its mean, 0.8 m/s over 10 ms, not one tick's 800
    assert float(np.mean(start.accel[:, 0])) == pytest.approx(80.0, abs=0.01)
    yaw_err = wrap_angles(r.yaw - truth[:, 2])
    assert_variance(yaw_err, 4e-4, "yaw")
    assert_variance(r.yaw_rate - truth[:, 5], 9e-4, "yaw rate")
    # steady circle: body acceleration is centripetal, [-wz·vy, wz·vx] = [0, 0.4]
    np.testing.assert_allclose(w.truth_accel, np.tile([0.0, 0.4], (n, 1)), atol=1e-9)
    assert_variance(r.accel[:, 0] - 0.0, 0.04, "ax")
    assert_variance(r.accel[:, 1] - 0.4, 0.04, "ay")
    assert (r.yaw_variance, r.yaw_rate_variance, r.accel_variance) == (4e-4, 9e-4, 0.04)
