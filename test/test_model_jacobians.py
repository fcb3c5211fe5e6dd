"""Every analytic Jacobian against central finite differences, at many random states.

States include headings right next to ±π (where an unwrapped angle difference would be
off by 2π) and the wrapped residuals are differenced as angles. Also checks the models'
sign conventions and the seed corrections (range² and bearing rows of seed 001).
"""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest

from ekf_localization.core.angles import wrap_angles
from ekf_localization.models import differential, mecanum
from ekf_localization.models.drive_response import DriveResponse
from ekf_localization.models.mecanum import MecanumKinematics, MecanumModel
from ekf_localization.models.sensors import dead_wheels
from ekf_localization.models.sensors.camera import pose_measurement
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry
from seed_experiments.models import linear_kf2d, unicycle

EPS = 1e-6
N_STATES = 64
NEAR_PI = np.array([math.pi - 1e-9, -math.pi + 1e-9, math.pi - 1e-4, -math.pi + 1e-4, math.pi, 0.0])


def random_states(rng: np.random.Generator, n: int, angle_index: int, scale: float = 3.0) -> np.ndarray:
    """N_STATES random states; the heading of the first rows sits at or next to ±π."""
    X = rng.uniform(-scale, scale, size=(N_STATES, n))
    X[:, angle_index] = rng.uniform(-math.pi, math.pi, N_STATES)
    X[: len(NEAR_PI), angle_index] = NEAR_PI
    return X


def central_difference(fun, X: np.ndarray, angle_out: np.ndarray) -> np.ndarray:
    """(N, m, n) Jacobian of a batched fun (N, n) -> (N, m); angle outputs differenced wrapped."""
    N, n = X.shape
    J = []
    for j in range(n):
        e = np.zeros(n)
        e[j] = EPS
        d = fun(X + e) - fun(X - e)
        d = np.where(angle_out, wrap_angles(d), d)
        J.append(d / (2.0 * EPS))
    return np.stack(J, axis=2)


def assert_jacobian(analytic: np.ndarray, numeric: np.ndarray) -> None:
    analytic = np.broadcast_to(analytic, numeric.shape)
    scale = 1.0 + np.abs(numeric)
    err = np.max(np.abs(analytic - numeric) / scale)
    assert err < 1e-6, f"max relative Jacobian error {err:.2e}"


# --- process models -------------------------------------------------------------------------
KIN = MecanumKinematics(wheel_radius=0.048, half_length=0.17, half_width=0.2)
DRIVE = DriveResponse(time_constant_s=[0.03, 0.0, 0.02], acceleration_limit=[2.9, 2.9, 8.3],
                      deceleration_limit=[4.0, 4.0, 10.0], velocity_variance=[1e-4, 1e-4, 1e-3])
TANK_INV, TANK_FWD = differential.tank_kinematics(0.048, 0.2)
PROCESS_CASES = {
    "mecanum-twist": (MecanumModel(), 3, 2),
    "mecanum-wheels": (MecanumModel(control="wheels", kinematics=KIN), 4, 2),
    "mecanum-no-control": (MecanumModel(velocity_variance_rate=0.1), None, 2),
    "mecanum-drive-lag": (MecanumModel(drive=DriveResponse(time_constant_s=[0.03, 0.05, 0.02])), 3, 2),
    "mecanum-drive-limited": (MecanumModel(drive=DRIVE), 3, 2),
    "mecanum-drive-wheels": (MecanumModel(control="wheels", kinematics=KIN, drive=DRIVE), 4, 2),
    "mecanum-drive-wheel-space": (MecanumModel(drive=DriveResponse(
        wheels_from_twist=KIN.inverse_matrix, wheel_acceleration_limit=60.0, wheel_speed_limit=32.67)), 3, 2),
    "mecanum-drive-wheel-space-lag": (MecanumModel(drive=DriveResponse(
        time_constant_s=[0.03, 0.03, 0.03], wheels_from_twist=KIN.inverse_matrix,
        wheel_acceleration_limit=60.0)), 3, 2),
    "differential-imu": (differential.DifferentialModel(), 1, 3),
    "tank-drive-limited": (differential.DifferentialModel(drive=DRIVE), 2, 3),
    "tank-drive-lag": (differential.DifferentialModel(drive=DriveResponse(time_constant_s=[0.03, 0.0, 0.02])),
                       2, 3),
    "tank-drive-wheel-space": (differential.DifferentialModel(drive=DriveResponse(
        wheels_from_twist=TANK_INV, wheel_acceleration_limit=60.0, wheel_speed_limit=32.67),
        control="wheels", wheels_to_twist=TANK_FWD), 2, 3),
    "tank-drive-no-control": (differential.DifferentialModel(drive=DRIVE), None, 3),
    "differential-no-control": (differential.DifferentialModel(), None, 3),
    "unicycle": (unicycle.UnicycleModel(wheel_radius=0.033, half_axle=0.08), 2, 0),
    "unicycle-no-control": (unicycle.UnicycleModel(wheel_radius=0.033, half_axle=0.08), None, 0),
    "fixed-heading-kf": (unicycle.fixed_heading_model(0.033), 2, None),
    "kf2d": (linear_kf2d.motion_model(), 2, None),
}


@pytest.mark.parametrize("name", list(PROCESS_CASES))
@pytest.mark.parametrize("dt", [0.001, 0.01, 0.25])
def test_process_jacobian_matches_central_differences(name: str, dt: float) -> None:
    model, k, angle = PROCESS_CASES[name]
    rng = np.random.default_rng(zlib.crc32(f"{name}{dt}".encode()))
    X = random_states(rng, model.n, angle if angle is not None else 0)
    U = None if k is None else rng.uniform(-5.0, 5.0, size=(N_STATES, k))
    is_angle = np.asarray(model.x_is_angle)
    numeric = central_difference(lambda Xp: model.f(Xp, U, dt), X, is_angle)
    assert_jacobian(model.jacobian(X, U, dt), numeric)
    if hasattr(model, "f_and_jacobian"):
        Xn, F = model.f_and_jacobian(X, U, dt)
        np.testing.assert_array_equal(Xn, model.f(X, U, dt))
        np.testing.assert_array_equal(F, np.broadcast_to(model.jacobian(X, U, dt), F.shape))


def test_mecanum_process_is_eq_22_to_25() -> None:
    """Body velocity rotated into the field frame (eq. 22); velocity from the command (eq. 25)."""
    model = MecanumModel()
    x = np.array([[1.0, 2.0, math.pi / 2, 3.0, 0.5, 0.2]])
    xn = model.f(x, np.array([[0.1, 0.2, 0.3]]), 0.01)[0]
    np.testing.assert_allclose(xn, [1.0 - 0.01 * 0.5, 2.0 + 0.01 * 3.0, math.pi / 2 + 0.002, 0.1, 0.2, 0.3],
                               atol=1e-15)
    held = model.f(x, None, 0.01)[0]
    np.testing.assert_array_equal(held[3:], x[0, 3:])


def test_mecanum_kinematics_eq_23_signs_and_inverse() -> None:
    M, Minv = KIN.forward_matrix, KIN.inverse_matrix
    np.testing.assert_allclose(M @ Minv, np.eye(3), atol=1e-14)
    twist = np.array([0.4, -0.3, 1.2])
    np.testing.assert_allclose(KIN.wheels_to_twist(KIN.twist_to_wheels(twist)), twist, atol=1e-14)
    forward = KIN.twist_to_wheels([1.0, 0.0, 0.0])
    assert np.all(forward > 0) and np.ptp(forward) == 0.0  # all wheels forward, equally
    left = KIN.twist_to_wheels([0.0, 1.0, 0.0])
    np.testing.assert_array_equal(np.sign(left), [1, -1, -1, 1])  # eq. 24 row 2
    ccw = KIN.twist_to_wheels([0.0, 0.0, 1.0])
    np.testing.assert_array_equal(np.sign(ccw), [-1, 1, -1, 1])  # eq. 24 row 3: left slower


# --- measurement models ---------------------------------------------------------------------
GEOM = DeadWheelGeometry(half_track=0.18, lateral_offset=0.1)
TARGETS = [(3.0, -1.5), (-2.0, 0.0), (0.0, 4.0)]


def measurement_cases():
    yield "camera-pose", pose_measurement(), 6, 2
    yield "dead-wheel-encoders", dead_wheels.encoder_measurement(GEOM), 6, 2
    yield "dead-wheel-twist", dead_wheels.twist_measurement(), 6, 2
    yield "mecanum-heading", mecanum.heading_measurement(), 6, 2
    yield "mecanum-yaw-rate", mecanum.yaw_rate_measurement(), 6, 2
    yield "diff-heading", differential.heading_measurement(), 5, 3
    yield "diff-yaw-rate", differential.yaw_rate_measurement(), 5, 3
    yield "diff-twist", differential.twist_measurement(), 5, 3
    yield "diff-pose", differential.pose_measurement(), 5, 3
    yield "diff-tracks", differential.track_speed_measurement(0.31, 0.29), 5, 3
    for t in TARGETS:
        yield f"diff-range2-{t}", differential.range_squared_measurement(t), 5, 3
        yield f"diff-bearing-{t}", differential.bearing_measurement(t), 5, 3
    yield "unicycle-position", unicycle.position_measurement(), 5, 0
    yield "unicycle-pose", unicycle.pose_measurement(), 5, 0
    yield "kf2d-position", linear_kf2d.position_measurement(), 2, None


MEASUREMENT_CASES = list(measurement_cases())


@pytest.mark.parametrize("name,meas,n,angle", MEASUREMENT_CASES, ids=[c[0] for c in MEASUREMENT_CASES])
def test_measurement_jacobian_matches_central_differences(name, meas, n, angle) -> None:
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    X = random_states(rng, n, angle if angle is not None else 0)
    if "bearing" in name:  # put some robots so that the target is right behind them (bearing ±π)
        t = meas.target
        X[:8, 0] = t[0] + 2.0
        X[:8, 1] = t[1] + np.array([1e-9, -1e-9, 1e-5, -1e-5, 0.0, 1e-3, -1e-3, 0.5])
    numeric = central_difference(meas.h, X, np.asarray(meas.z_is_angle))
    assert_jacobian(meas.jacobian(X), numeric)


def test_range_squared_row_is_the_corrected_one() -> None:
    """Seed 001 prints [2x, 2y, 0, 0, 0]; the derivative of (x − x_t)² + (y − y_t)² is 2(x − x_t)."""
    meas = differential.range_squared_measurement((3.0, -1.5))
    x = np.array([[1.0, 2.0, 0.5, 0.3, 0.1]])
    np.testing.assert_allclose(meas.jacobian(x)[0, 0], [2 * (1.0 - 3.0), 2 * (2.0 + 1.5), 0, 0, 0])
    assert meas.h(x)[0, 0] == pytest.approx(4.0 + 12.25)


def test_bearing_is_seen_from_the_robot() -> None:
    """A target on the robot's left is at +π/2 (CCW); the seed's formula is off by π."""
    meas = differential.bearing_measurement((0.0, 1.0))
    robot = np.array([[0.0, 0.0, 0.0, 0.0, 0.0]])
    assert meas.h(robot)[0, 0] == pytest.approx(math.pi / 2)
    robot[0, 3] = math.pi / 2  # now facing the target
    assert meas.h(robot)[0, 0] == pytest.approx(0.0)
    rng = np.random.default_rng(1)
    X = random_states(rng, 5, 3)
    t = meas.target
    seed_version = np.arctan2(X[:, 1] - t[1], X[:, 0] - t[0]) - X[:, 3]
    np.testing.assert_allclose(wrap_angles(meas.h(X)[:, 0] - seed_version - math.pi), 0.0, atol=1e-12)
    assert np.all(np.abs(meas.h(X)) <= math.pi)


def test_bearing_on_the_target_is_nan_not_a_crash() -> None:
    meas = differential.bearing_measurement((1.0, 2.0))
    X = np.array([[1.0, 2.0, 0.0, 0.3, 0.0]])
    with np.errstate(all="ignore"):
        assert np.isnan(meas.h(X)[0, 0])
        assert not np.all(np.isfinite(meas.jacobian(X)))


def test_dead_wheel_geometry_eq_29_30_are_inverse() -> None:
    np.testing.assert_allclose(GEOM.twist_from_encoders @ GEOM.encoders_from_twist, np.eye(3), atol=1e-15)
    # eq. 30 with D > 0: the lateral wheel behind the centre reads ẏ − D θ̇
    E = GEOM.encoders_from_twist @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(E, [-GEOM.half_track, GEOM.half_track, -GEOM.lateral_offset])


def test_encoder_covariance_propagates_exactly_to_the_twist() -> None:
    rng = np.random.default_rng(7)
    noise = dead_wheels.EncoderNoise(speed_variance_coeff=0.002, variance_floor=0.001)
    E = rng.normal(size=(20000, 3)) * 0.5 + np.array([1.0, 1.2, -0.3])
    C = noise.covariance(np.array([1.0, 1.2, -0.3]))
    twist, twist_cov = dead_wheels.encoders_to_twist(GEOM, E, C)
    M = GEOM.twist_from_encoders
    np.testing.assert_allclose(twist, E @ M.T)
    np.testing.assert_allclose(twist_cov, M @ C @ M.T)
    # batched shapes
    tw, tc = dead_wheels.encoders_to_twist(GEOM, E[:4], np.broadcast_to(C, (4, 3, 3)))
    assert tw.shape == (4, 3) and tc.shape == (4, 3, 3)
    np.testing.assert_allclose(tc[2], twist_cov)
    # Monte Carlo: samples of E with covariance C map to samples with covariance twist_cov
    samples = rng.multivariate_normal(np.zeros(3), C, size=200000) @ M.T
    np.testing.assert_allclose(np.cov(samples.T), twist_cov, rtol=0.03, atol=1e-5)


def test_parameter_validation_names_the_parameter() -> None:
    with pytest.raises(ValueError, match="half_track"):
        DeadWheelGeometry(half_track=0.0, lateral_offset=0.1)
    with pytest.raises(ValueError, match="variance_floor"):
        dead_wheels.EncoderNoise(0.002, 0.0)
    with pytest.raises(ValueError, match="wheel_radius"):
        MecanumKinematics(-1.0, 0.2, 0.2)
    with pytest.raises(ValueError, match="pose_variance_rate"):
        MecanumModel(pose_variance_rate=[1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="speed_variance_rate"):
        differential.DifferentialModel(speed_variance_rate=math.nan)
    with pytest.raises(ValueError, match="left_offset"):
        differential.track_speed_measurement(-0.3, 0.3)
    with pytest.raises(ValueError, match="target_xy"):
        differential.bearing_measurement((1.0, math.inf))
    with pytest.raises(ValueError, match="half_axle"):
        unicycle.UnicycleModel(wheel_radius=0.03, half_axle=0.0)
    with pytest.raises(ValueError, match="process_std_per_step"):
        linear_kf2d.motion_model(process_std_per_step=(0.1, -0.2))
    with pytest.raises(ValueError, match="shaped"):
        MecanumModel().f(np.zeros((2, 6)), np.zeros((1, 3)), 0.01)
