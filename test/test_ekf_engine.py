"""The generic EKF engine: maths against a plain-numpy reference, invariants, rejections.

Covers angle wrapping, integer-nanosecond time, Joseph-form updates that stay symmetric
positive definite under adversarial inputs, Mahalanobis gating, rejection of non-finite
or invalid inputs with the right status, partial updates, and the exactness of the
linear case (seed 004's Kalman filter).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ekf_localization.core.angles import quaternion_to_yaw, wrap_angle, wrap_angles, yaw_to_quaternion
from ekf_localization.core.ekf import (
    STATUS_BAD_R,
    STATUS_GATED,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_S_NOT_PD,
    STATUS_SKIPPED,
    STATUS_TEXT,
    ExtendedKalmanFilter,
    UpdateResult,
    dt_seconds,
)
from ekf_localization.core.linalg import is_positive_definite
from ekf_localization.core.linear import LinearMeasurement, select_rows, stack_measurements
from ekf_localization.models import differential
from ekf_localization.models.mecanum import MecanumModel
from ekf_localization.models.sensors import dead_wheels
from ekf_localization.models.sensors.camera import pose_measurement
from seed_experiments.models import linear_kf2d

DT_NS = 10_000_000
GEOM = dead_wheels.DeadWheelGeometry(half_track=0.18, lateral_offset=0.1)
FULL = stack_measurements(pose_measurement(), dead_wheels.encoder_measurement(GEOM))  # seed 000 eq. 31


def spd(rng: np.random.Generator, n: int, cond: float = 10.0) -> np.ndarray:
    """A random symmetric positive definite matrix with the given condition number."""
    Qm, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (Qm * np.geomspace(1.0, 1.0 / cond, n)) @ Qm.T


def assert_spd(P: np.ndarray) -> None:
    assert np.all(np.isfinite(P))
    np.testing.assert_array_equal(P, np.swapaxes(P, -1, -2))
    np.linalg.cholesky(P)  # raises if not positive definite


# --- angles and time ----------------------------------------------------------------------------
def test_wrap_is_half_open_and_the_two_implementations_agree() -> None:
    a = np.concatenate([[math.pi, -math.pi, 3 * math.pi, -3 * math.pi, 2 * math.pi, 0.0, -0.0, 1e-300,
                         -1e-17, math.pi + 1e-15, -math.pi - 1e-15, 1e6, -1e6],
                        np.random.default_rng(0).uniform(-50, 50, 500)])
    w = wrap_angles(a)
    assert np.all((w > -math.pi) & (w <= math.pi))
    assert wrap_angle(math.pi) == math.pi and wrap_angle(-math.pi) == math.pi
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-9)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-9)
    for v, wv in zip(a, w, strict=True):
        assert wrap_angle(float(v)) == wv
    assert math.isnan(wrap_angle(math.nan)) and math.isnan(wrap_angle(math.inf))


def test_quaternion_yaw_round_trip_and_bad_quaternions() -> None:
    for yaw in np.linspace(-math.pi + 1e-9, math.pi, 41):
        q = yaw_to_quaternion(float(yaw))
        assert quaternion_to_yaw(*q) == pytest.approx(yaw, abs=1e-12)
        assert quaternion_to_yaw(*(3.0 * np.array(q))) == pytest.approx(yaw, abs=1e-12)  # not normalised
    assert quaternion_to_yaw(*yaw_to_quaternion(-math.pi)) == pytest.approx(math.pi)
    assert math.isnan(quaternion_to_yaw(0.0, 0.0, 0.0, 0.0))
    assert math.isnan(quaternion_to_yaw(0.0, 0.0, math.nan, 1.0))


def test_dt_must_be_integer_nanoseconds() -> None:
    assert dt_seconds(1_500_000_000) == 1.5
    assert dt_seconds(np.int64(10_000_000)) == 0.01
    # a stamp difference far from 0 keeps nanosecond precision (float seconds would not)
    t0, t1 = 1_700_000_000_123_456_789, 1_700_000_000_123_457_789
    assert dt_seconds(t1 - t0) == 1e-6
    for bad in (0.01, 1e7, True, "10", None):
        with pytest.raises(TypeError):
            dt_seconds(bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="negative"):
        dt_seconds(-1)
    ekf = ExtendedKalmanFilter(MecanumModel(), np.zeros(6), np.eye(6))
    with pytest.raises(TypeError):
        ekf.predict(0.01)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        ekf.predict(-DT_NS)
    x, P = ekf.x.copy(), ekf.P.copy()
    assert ekf.predict(0, np.ones(3)) is True  # dt = 0: nothing happens
    np.testing.assert_array_equal(ekf.x, x)
    np.testing.assert_array_equal(ekf.P, P)


# --- maths against a plain numpy reference ------------------------------------------------------
def reference_ekf_step(x, P, f, F, Q, z, h, H, R, z_is_angle, x_is_angle):
    """Textbook EKF (seed 000 eq. 9-12, Joseph form), numpy with an explicit inverse."""
    x = f.copy()
    x = np.where(x_is_angle, wrap_angles(x), x)
    P = F @ P @ F.T + Q
    hx = h(x)
    Hx = H(x)
    y = z - hx
    y = np.where(z_is_angle, wrap_angles(y), y)
    S = Hx @ P @ Hx.T + R
    K = P @ Hx.T @ np.linalg.inv(S)
    x = x + K @ y
    x = np.where(x_is_angle, wrap_angles(x), x)
    A = np.eye(len(x)) - K @ Hx
    P = A @ P @ A.T + K @ R @ K.T
    return x, P


def test_mecanum_filter_matches_numpy_reference() -> None:
    rng = np.random.default_rng(3)
    model = MecanumModel(pose_variance_rate=[1e-3, 1e-3, 1e-3], velocity_variance_per_step=[0.05, 0.05, 0.1])
    x0 = np.array([0.5, -0.2, 3.1, 0.0, 0.0, 0.0])
    ekf = ExtendedKalmanFilter(model, x0, np.eye(6) * 0.1)
    x, P = x0.copy(), np.eye(6) * 0.1
    H = FULL.H
    headings = []
    for k in range(400):
        u = np.array([0.8, 0.3 * math.sin(k / 30), 1.5])
        z = H @ x + rng.normal(size=6) * 0.05
        z[2] = wrap_angle(z[2] + 0.02)
        R = np.diag(rng.uniform(0.001, 0.01, 6))
        assert ekf.predict(DT_NS, u)
        res = ekf.update(FULL, z, R)
        assert res.accepted, res.reason
        f = model.f(x[None], u[None], 0.01)[0]
        F = model.jacobian(x[None], u[None], 0.01)[0]
        Q = model.noise(None, u[None], 0.01)[0]
        x, P = reference_ekf_step(x, P, f, F, Q, z, lambda s: H @ s, lambda s: H, R,
                                  FULL.z_is_angle, model.x_is_angle)
        np.testing.assert_allclose(ekf.x, x, rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(ekf.P, P, rtol=1e-8, atol=1e-13)
        headings.append(ekf.x[2])
    assert np.max(np.abs(np.diff(headings))) > math.pi  # the heading crossed ±π (and was wrapped)


def test_differential_filter_with_range_and_bearing_matches_numpy_reference() -> None:
    rng = np.random.default_rng(4)
    model = differential.DifferentialModel()
    target = (4.0, 2.0)
    rb = [differential.range_squared_measurement(target), differential.bearing_measurement(target)]
    x0 = np.array([0.0, 0.0, 1.0, 0.3, 0.2])
    ekf = ExtendedKalmanFilter(model, x0, np.eye(5) * 0.05)
    x, P = x0.copy(), np.eye(5) * 0.05
    for k in range(200):
        a = np.array([0.5 * math.cos(k / 20)])
        assert ekf.predict(DT_NS, a)
        meas = rb[k % 2]
        z = meas.h(x[None])[0] + rng.normal(size=1) * 0.02
        R = np.array([[4e-4]])
        assert ekf.update(meas, z, R).accepted
        f = model.f(x[None], a[None], 0.01)[0]
        F = model.jacobian(x[None], a[None], 0.01)[0]
        Q = model.noise(None, a[None], 0.01)[0]
        x, P = reference_ekf_step(x, P, f, F, Q, z, lambda s, m=meas: m.h(s[None])[0],
                                  lambda s, m=meas: m.jacobian(s[None])[0], R, meas.z_is_angle,
                                  model.x_is_angle)
        np.testing.assert_allclose(ekf.x, x, rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(ekf.P, P, rtol=1e-8, atol=1e-13)


def test_linear_model_is_exactly_the_kalman_filter_of_seed_004() -> None:
    """8 Hz motion, 1 Hz fix z = diag(1, 2)[x y], noise given as standard deviations."""
    rng = np.random.default_rng(6)
    model = linear_kf2d.motion_model()
    meas = linear_kf2d.position_measurement()
    R = linear_kf2d.measurement_covariance()
    np.testing.assert_allclose(np.diag(R), [0.05**2, 0.075**2])
    np.testing.assert_allclose(model.noise(None, np.zeros((1, 2)), 0.125)[0], np.diag([0.1**2, 0.15**2]))
    P0 = np.eye(2) * 1e-9
    kf = ExtendedKalmanFilter(model, np.zeros(2), P0)
    x, P = np.zeros(2), P0.copy()
    dt = linear_kf2d.MOTION_PERIOD_NS / 1e9
    B = 0.5 * linear_kf2d.WHEEL_RADIUS * np.ones((2, 2))
    Q = np.diag([0.1**2, 0.15**2])
    Hm = linear_kf2d.MEASUREMENT_MATRIX
    truth = np.zeros(2)
    u = np.array([1.0, 1.0])  # u_r, u_l in rad/s: 0.1 m/s
    steps_per_fix = linear_kf2d.MEASUREMENT_PERIOD_NS // linear_kf2d.MOTION_PERIOD_NS
    assert steps_per_fix == 8
    for k in range(1, 8 * 30 + 1):
        truth = truth + dt * B @ u + rng.normal(size=2) * [0.1, 0.15]
        assert kf.predict(linear_kf2d.MOTION_PERIOD_NS, u)
        x = x + dt * B @ u  # x' = A x + B u, A = I (seed 000 eq. 7, 9)
        P = P + Q
        if k % steps_per_fix == 0:
            z = Hm @ truth + rng.normal(size=2) * [0.05, 0.075]
            assert kf.update(meas, z, R).accepted
            S = Hm @ P @ Hm.T + R  # eq. 10-12 (Joseph form for the covariance)
            K = P @ Hm.T @ np.linalg.inv(S)
            x = x + K @ (z - Hm @ x)
            A = np.eye(2) - K @ Hm
            P = A @ P @ A.T + K @ R @ K.T
        np.testing.assert_allclose(kf.x, x, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(kf.P, P, rtol=1e-11, atol=1e-15)


def test_twist_measurement_is_equivalent_to_the_three_encoders() -> None:
    """Encoders -> body twist with the covariance propagated exactly carries the same information."""
    rng = np.random.default_rng(8)
    noise = dead_wheels.EncoderNoise(0.002, 0.001)
    model = MecanumModel()
    P0 = spd(rng, 6)
    a = ExtendedKalmanFilter(model, np.zeros(6), P0)
    b = ExtendedKalmanFilter(model, np.zeros(6), P0)
    enc, tw = dead_wheels.encoder_measurement(GEOM), dead_wheels.twist_measurement()
    for _ in range(30):
        u = rng.normal(size=3)
        a.predict(DT_NS, u)
        b.predict(DT_NS, u)
        E = GEOM.encoders_from_twist @ u + rng.normal(size=3) * 0.05
        C = noise.covariance(E)
        twist, twist_cov = dead_wheels.encoders_to_twist(GEOM, E, C)
        assert a.update(enc, E, C).accepted and b.update(tw, twist, twist_cov).accepted
        np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(a.P, b.P, rtol=1e-8, atol=1e-13)


def test_heading_residual_is_wrapped_across_pi() -> None:
    model = MecanumModel()
    ekf = ExtendedKalmanFilter(model, np.array([0, 0, math.pi - 0.01, 0, 0, 0]), np.eye(6) * 0.01)
    res = ekf.update(select_rows(6, [2], angle_rows=(2,)), np.array([-math.pi + 0.01]), np.array([[0.01]]))
    assert res.accepted
    assert res.mahalanobis == pytest.approx(0.02 / math.sqrt(0.02), rel=1e-9)  # |y| = 0.02, not 2π - 0.02
    assert abs(wrap_angle(ekf.x[2] - math.pi)) < 1e-12  # half-way: exactly at ±π, wrapped into (-π, π]
    assert -math.pi < ekf.x[2] <= math.pi


# --- invariants under adversarial inputs ------------------------------------------------------
@pytest.mark.parametrize("case", ["ill-conditioned", "huge-variances", "tiny-R", "exact-measurement",
                                  "correlated-R"])
def test_covariance_stays_symmetric_positive_definite(case: str) -> None:
    rng = np.random.default_rng(9)
    N = 64
    model = MecanumModel(pose_variance_rate=0.0, velocity_variance_per_step=0.0)  # Q = 0: nothing helps P
    cond = {"ill-conditioned": 1e12}.get(case, 100.0)
    scale = {"huge-variances": 1e12}.get(case, 1.0)
    P0 = np.stack([spd(rng, 6, cond) * scale for _ in range(N)])
    X0 = rng.normal(size=(N, 6))
    filters = [ExtendedKalmanFilter(model, X0[i], P0[i]) for i in range(N)]
    for _ in range(40):
        U = rng.normal(size=(N, 3))
        assert all(f.predict(DT_NS, U[i]) for i, f in enumerate(filters))
        assert_spd(np.stack([f.P for f in filters]))
        if case == "tiny-R":
            R = np.eye(6) * 1e-15
        elif case == "exact-measurement":
            R = np.zeros((6, 6))
        elif case == "correlated-R":
            R = np.stack([spd(rng, 6, 1e6) * 1e-3 for _ in range(N)])
        else:
            R = np.diag(rng.uniform(1e-4, 1e-1, 6))
        X = np.stack([f.x for f in filters])
        Z = FULL.h(X) + rng.normal(size=(N, 6)) * 0.01
        results = [f.update(FULL, Z[i], R if R.ndim == 2 else R[i]) for i, f in enumerate(filters)]
        assert all(r.accepted for r in results), [r.reason for r in results]
        X = np.stack([f.x for f in filters])
        assert all(math.isfinite(r.mahalanobis) for r in results) and np.all(np.isfinite(X))
        assert_spd(np.stack([f.P for f in filters]))
    if case == "exact-measurement":  # the measured components are now known (up to min_variance lifts)
        np.testing.assert_allclose(FULL.h(X), np.where(FULL.z_is_angle, wrap_angles(Z), Z), atol=1e-6)


def test_min_variance_lifts_a_singular_prediction() -> None:
    model = MecanumModel(pose_variance_rate=0.0, velocity_variance_per_step=0.0)
    ekf = ExtendedKalmanFilter(model, np.zeros(6), np.eye(6), min_variance=1e-9)
    assert ekf.predict(DT_NS, np.ones(3))  # F has zero velocity rows and Q = 0: F P Fᵀ is singular
    assert_spd(ekf.P)
    assert np.all(np.diag(ekf.P)[3:] >= 1e-9)
    assert np.diag(ekf.P)[3] < 1e-6
    with pytest.raises(ValueError, match="min_variance"):
        ExtendedKalmanFilter(model, np.zeros(6), np.eye(6), min_variance=0.0)


def test_positive_definite_check() -> None:
    assert is_positive_definite(np.eye(3))
    assert not is_positive_definite(np.array([[1.0, 2.0], [2.0, 1.0]]))
    assert not is_positive_definite(np.array([[1.0, 0.0], [0.0, math.nan]]))
    assert not is_positive_definite(np.zeros((2, 2)))


# --- gating and rejections ---------------------------------------------------------------------
def test_gate_rejects_outliers_and_reports_the_distance() -> None:
    model = MecanumModel()
    meas = select_rows(6, [0])
    ekf = ExtendedKalmanFilter(model, np.zeros(6), np.eye(6))  # S = 1 + 0.01 for x
    x, P = ekf.x.copy(), ekf.P.copy()
    far = np.array([10.0 * math.sqrt(1.01)])  # exactly 10 sigmas
    res = ekf.update(meas, far, np.array([[0.01]]), gate_sigmas=9.99)
    assert res.status == STATUS_GATED and not res.accepted and res.reason == "rejected by Mahalanobis gate"
    assert res.mahalanobis == pytest.approx(10.0, rel=1e-12)
    np.testing.assert_array_equal(ekf.x, x)
    np.testing.assert_array_equal(ekf.P, P)
    res = ekf.update(meas, far, np.array([[0.01]]), gate_sigmas=10.01)
    assert res.accepted and res.mahalanobis == pytest.approx(10.0, rel=1e-12)
    for bad in (0.0, -3.0, math.nan):
        with pytest.raises(ValueError, match="gate_sigmas"):
            ekf.update(meas, far, np.array([[0.01]]), gate_sigmas=bad)


@pytest.mark.parametrize("case,status", [
    ("nan-z", STATUS_NONFINITE), ("inf-z", STATUS_NONFINITE), ("nan-R", STATUS_NONFINITE),
    ("negative-variance", STATUS_BAD_R), ("asymmetric-R", STATUS_BAD_R), ("indefinite-R", STATUS_BAD_R),
    ("singular-S", STATUS_S_NOT_PD), ("nothing-selected", STATUS_SKIPPED),
    ("robot-on-target", STATUS_NONFINITE),
])
def test_bad_measurements_are_rejected_with_a_reason(case: str, status: int) -> None:
    model = differential.DifferentialModel()
    ekf = ExtendedKalmanFilter(model, np.array([1.0, 2.0, 0.5, 0.1, 0.0]), np.eye(5) * 0.1)
    meas = differential.track_speed_measurement(0.3, 0.3)
    z, R, mask = np.array([0.5, 0.5]), np.eye(2) * 0.01, None
    if case == "nan-z":
        z[1] = math.nan
    elif case == "inf-z":
        z[0] = -math.inf
    elif case == "nan-R":
        R[0, 1] = R[1, 0] = math.nan
    elif case == "negative-variance":
        R[1, 1] = -0.01
    elif case == "asymmetric-R":
        R[0, 1] = 0.001
    elif case == "indefinite-R":
        R = np.array([[0.01, 0.02], [0.02, 0.01]])
    elif case == "singular-S":
        meas = LinearMeasurement(np.zeros((2, 5)))
        R = np.zeros((2, 2))
    elif case == "nothing-selected":
        mask = np.array([False, False])
    elif case == "robot-on-target":
        meas, z, R = differential.bearing_measurement((1.0, 2.0)), np.array([0.3]), np.array([[0.01]])
    x, P = ekf.x.copy(), ekf.P.copy()
    res = ekf.update(meas, z, R, mask=mask)
    assert res.status == status and not res.accepted
    assert res.reason == STATUS_TEXT[status]
    np.testing.assert_array_equal(ekf.x, x)
    np.testing.assert_array_equal(ekf.P, P)


def test_invalid_components_can_be_left_out_by_the_mask() -> None:
    """A partial update equals the update with the reduced measurement model, bit for bit."""
    rng = np.random.default_rng(10)
    model = MecanumModel()
    P0 = spd(rng, 6)
    x0 = rng.normal(size=6)
    keep = np.array([True, False, True, True, False, True])
    z = FULL.h(x0[None])[0] + rng.normal(size=6) * 0.1
    z[[1, 4]] = [math.nan, math.inf]  # invalid components, masked out
    R = spd(rng, 6) * 0.01
    R[1, :] = R[:, 1] = math.nan
    full = ExtendedKalmanFilter(model, x0, P0)
    reduced = ExtendedKalmanFilter(model, x0, P0)
    res = full.update(FULL, z, R, mask=keep)
    small = LinearMeasurement(FULL.H[keep], FULL.z_is_angle[keep])
    res_small = reduced.update(small, z[keep], R[np.ix_(keep, keep)])
    assert res.accepted and res_small.accepted
    assert res.mahalanobis == pytest.approx(res_small.mahalanobis, rel=1e-13)
    np.testing.assert_allclose(full.x, reduced.x, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(full.P, reduced.P, rtol=1e-13, atol=1e-15)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning",  # the overflows are the point
                            "ignore:invalid value encountered:RuntimeWarning")
def test_non_finite_prediction_is_rejected_and_the_state_kept() -> None:
    ekf = ExtendedKalmanFilter(MecanumModel(), np.zeros(6), np.eye(6))
    x, P = ekf.x.copy(), ekf.P.copy()
    assert ekf.predict(DT_NS, np.array([math.nan, 0.0, 0.0])) is False
    np.testing.assert_array_equal(ekf.x, x)
    np.testing.assert_array_equal(ekf.P, P)
    ekf.set_state(np.array([0, 0, 0, 1e308, 1e308, 0]), np.eye(6))
    assert ekf.predict(10**18) is False  # x + dt·v overflows
    assert np.all(np.isfinite(ekf.x)) and np.all(np.isfinite(ekf.P))
    assert ekf.predict(DT_NS, np.zeros(3)) is False  # F P Fᵀ overflows (F holds dt·v ~ 1e306)
    ekf.set_state(np.zeros(6), np.eye(6))
    assert ekf.predict(DT_NS, np.zeros(3)) is True


def test_inputs_with_wrong_shapes_or_values_raise_clear_errors() -> None:
    model = MecanumModel()
    with pytest.raises(ValueError, match="positive definite"):
        ExtendedKalmanFilter(model, np.zeros(6), -np.eye(6))
    with pytest.raises(ValueError, match="symmetric"):
        ExtendedKalmanFilter(model, np.zeros(6), np.eye(6) + np.triu(np.ones((6, 6)), 1))
    with pytest.raises(ValueError, match="finite"):
        ExtendedKalmanFilter(model, np.full(6, math.nan), np.eye(6))
    with pytest.raises(ValueError):
        ExtendedKalmanFilter(model, np.zeros(5), np.eye(5))
    ekf = ExtendedKalmanFilter(model, np.zeros(6), np.eye(6))
    with pytest.raises(ValueError, match="control"):
        ekf.predict(DT_NS, np.zeros(4))
    with pytest.raises(ValueError, match="z must be"):
        ekf.update(FULL, np.zeros(5), np.eye(6))
    with pytest.raises(ValueError, match="R"):
        ekf.update(FULL, np.zeros(6), np.eye(5))
    with pytest.raises(ValueError, match="mask"):
        ekf.update(FULL, np.zeros(6), np.eye(6), mask=np.ones(5, dtype=bool))
    with pytest.raises(ValueError, match="positive definite"):
        ekf.set_state(np.zeros(6), np.zeros((6, 6)))
    with pytest.raises(ValueError, match="finite"):
        ekf.set_state(np.full(6, math.inf), np.eye(6))


def test_set_state_wraps_angles_and_x_p_are_live_views() -> None:
    ekf = ExtendedKalmanFilter(MecanumModel(), np.array([0, 0, 3 * math.pi, 0, 0, 0]), np.eye(6))
    assert ekf.x[2] == pytest.approx(math.pi)
    view_x, view_P = ekf.x, ekf.P
    ekf.set_state(np.array([1, 2, -4.0, 0, 0, 0]), np.eye(6) * 2)
    assert view_x[0] == 1.0 and view_x[2] == pytest.approx(-4.0 + 2 * math.pi)
    assert view_P[0, 0] == 2.0
    ekf.predict(DT_NS, np.array([1.0, 0.0, 0.0]))
    assert view_x[3] == 1.0  # same memory as the filter's state


def test_update_result_fields() -> None:
    r = UpdateResult(STATUS_OK, 1.5)
    assert r.accepted and r.reason == "ok" and r.mahalanobis == 1.5
    status, mahalanobis, y, S = UpdateResult(STATUS_GATED, 4.0)
    assert status == STATUS_GATED and mahalanobis == 4.0 and y is None and S is None
    assert set(STATUS_TEXT) == {0, 1, 2, 3, 4, 5, 6}


def test_update_reports_the_innovation_and_its_covariance() -> None:
    """y = z - H x and S = H P Hᵀ + R (eq. 10), also for a gated update, and d² = yᵀ S⁻¹ y."""
    model = MecanumModel()
    P0 = np.diag([0.1, 0.2, 0.05, 0.3, 0.3, 0.1])
    meas = select_rows(6, [0, 1, 2], angle_rows=(2,))
    z, R = np.array([0.3, -0.2, 3.1]), np.diag([0.01, 0.01, 0.02])
    x0 = np.array([0.0, 0.0, -3.1, 0.0, 0.0, 0.0])
    for gate, status in ((math.inf, STATUS_OK), (0.5, STATUS_GATED)):
        ekf = ExtendedKalmanFilter(model, x0, P0)
        res = ekf.update(meas, z, R, gate_sigmas=gate)
        assert res.status == status
        np.testing.assert_allclose(res.y, [0.3, -0.2, wrap_angle(6.2)], rtol=1e-12)
        np.testing.assert_allclose(res.S, P0[:3, :3] + R, rtol=1e-12)
        assert res.mahalanobis ** 2 == pytest.approx(res.y @ np.linalg.solve(res.S, res.y), rel=1e-12)
