"""Tilt compensation maths (core.tilt) and its use in the Localizer, no ROS."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ekf_localization.core.angles import quaternion_to_rpy, rpy_to_quaternion
from ekf_localization.core.joint_states import EncoderSample
from ekf_localization.core.measurements import REJECT_NOT_PROVIDED, ImuMeasurement, JointStateMeasurement
from ekf_localization.core.tilt import (
    TiltHistory,
    TiltSample,
    horizontal_projection,
    project_twist,
    projection_tilt_jacobian,
    vertical_rate,
)
from ekf_localization.inputs.joint import JointHandler
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config

TILTS = [(0.0, 0.0), (0.2, 0.0), (0.0, -0.26), (0.15, 0.3), (-0.4, 0.2)]
MS = 1_000_000


def rotation(roll, pitch, yaw=0.0):
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@pytest.mark.parametrize("roll, pitch", TILTS)
def test_projection_is_the_horizontal_part_of_the_3d_rotation(roll, pitch):
    vb = np.array([0.7, -0.3, 0.0])
    world = rotation(roll, pitch) @ vb
    vh = horizontal_projection(roll, pitch) @ np.array([0.7, -0.3, 0.9])
    np.testing.assert_allclose(vh[:2], world[:2], atol=1e-12)
    assert vertical_rate(vh[0], vh[1], roll, pitch) == pytest.approx(world[2], abs=1e-12)
    # yaw rate of an angular velocity along the body z axis: ZYX rate equation
    assert vh[2] == pytest.approx(0.9 * math.cos(roll) / math.cos(pitch), abs=1e-12)


def test_level_ground_is_the_identity():
    np.testing.assert_array_equal(horizontal_projection(0.0, 0.0), np.eye(3))


@pytest.mark.parametrize("roll, pitch", TILTS)
def test_tilt_jacobian_matches_finite_differences(roll, pitch):
    v = np.array([0.8, -0.4, 1.1])
    J = projection_tilt_jacobian(v, roll, pitch)
    h = 1e-6
    fd = np.column_stack([
        (horizontal_projection(roll + h, pitch) @ v - horizontal_projection(roll - h, pitch) @ v) / (2 * h),
        (horizontal_projection(roll, pitch + h) @ v - horizontal_projection(roll, pitch - h) @ v) / (2 * h)])
    np.testing.assert_allclose(J, fd, atol=1e-8)


def test_rpy_quaternion_round_trip():
    for r, p in TILTS:
        q = rpy_to_quaternion(r, p, 1.2)
        np.testing.assert_allclose(quaternion_to_rpy(*q), (r, p, 1.2), atol=1e-12)


def test_projected_twist_covariance_is_symmetric_positive_definite():
    z = np.array([0.5, 0.2, -0.3])
    R = np.diag([1e-3, 2e-3, 4e-3])
    zp, Rp = project_twist(z, R, np.arange(3), 0.2, -0.3, np.diag([1e-4, 1e-4]))
    np.testing.assert_allclose(zp, horizontal_projection(0.2, -0.3) @ z)
    np.testing.assert_array_equal(Rp, Rp.T)
    assert np.all(np.linalg.eigvalsh(Rp) > 0)
    rows = np.array([0, 2])
    zp2, _ = project_twist(z[rows], R[np.ix_(rows, rows)], rows, 0.2, -0.3, np.zeros((2, 2)))
    np.testing.assert_allclose(zp2, (horizontal_projection(0.2, -0.3) @ [0.5, 0.0, -0.3])[[0, 2]])


def _encoder_input(model: str) -> tuple[JointHandler, int]:
    names = ("l", "r", "a") if model == "mecanum" else ("l", "r")
    params = {"model": model, "joint0": "js", "joint0_names": list(names)}
    cfg = parse_ekf_config(params, MODELS)
    loc = make_localizer(cfg)
    return loc._handlers["joint0"], loc.model.n


@pytest.mark.parametrize("model", ["mecanum", "differential"])
@pytest.mark.parametrize("roll, pitch", TILTS[1:])
def test_tilted_encoder_model_jacobians(model, roll, pitch):
    """h(s) = M·P⁻¹·v_h: H against finite differences in the state, the tilt term against
    finite differences in (roll, pitch)."""
    enc, n = _encoder_input(model)
    tilt = TiltSample(0, roll, pitch, np.diag([1e-4, 2e-4]))
    E = enc.M @ np.array([0.5, -0.2, 0.4])[enc.twist_idx]
    plan, z, R = enc.update(EncoderSample(0, E), tilt)
    H = plan.model.H

    def h(s, r=roll, p=pitch):
        P = horizontal_projection(r, p)[np.ix_(enc.twist_idx, enc.twist_idx)]
        return enc.M @ np.linalg.solve(P, s[enc.cols])

    s = np.random.default_rng(1).normal(size=n)
    eps = 1e-6
    fd = np.column_stack([(h(s + eps * e) - h(s - eps * e)) / (2 * eps) for e in np.eye(n)])
    np.testing.assert_allclose(H, fd, atol=1e-8)
    # the tilt term of R: J Σ Jᵀ with J = ∂h/∂(r, p) at the state whose body twist gives E
    s_true = np.zeros(n)
    v_body = enc.M_inv @ E
    P = horizontal_projection(roll, pitch)[np.ix_(enc.twist_idx, enc.twist_idx)]
    s_true[enc.cols] = P @ v_body
    J = np.column_stack([(h(s_true, roll + eps, pitch) - h(s_true, roll - eps, pitch)) / (2 * eps),
                         (h(s_true, roll, pitch + eps) - h(s_true, roll, pitch - eps)) / (2 * eps)])
    R0 = np.diag(enc.config.variances(E))
    np.testing.assert_allclose(R, R0 + J @ tilt.covariance @ J.T, rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(h(s_true), E, atol=1e-12)


def test_tilt_history_looks_up_the_sample_in_effect():
    th = TiltHistory(keep_ns=100 * MS)
    assert th.at(0) is None
    for k in range(30):
        th.add(TiltSample(k * 10 * MS, 0.01 * k, 0.0, np.eye(2)))
    assert th.at(255 * MS).roll == pytest.approx(0.25)
    assert th.at(0).stamp_ns == min(s.stamp_ns for s in th._samples)  # older than kept: the oldest
    assert len(th) <= 12


def _imu(t_ns, roll, pitch, provided=True):
    cov = np.diag([1e-4, 1e-4, 1e-4])
    if not provided:
        cov = cov.copy()
        cov[0, 0] = -1.0
    return ImuMeasurement(t_ns, "base_link", np.array([roll, pitch, 0.0]), cov, np.zeros(3), np.eye(3),
                          np.zeros(3), np.eye(3))


def _tilt_params(**extra):
    p = {"imu0": "imu", "imu0_config": [False] * 3 + [True, True, False] + [False] * 9,
         "joint0": "js", "joint0_names": ["l", "r", "a"], "joint0_wheel_radius": 0.05,
         "joint0_tilt_compensation": True, "history_length": 1.0,
         "process_noise_covariance": list((np.eye(15) * 0.5).ravel())}
    p.update(extra)
    return p


def test_localizer_projects_encoder_speeds_on_a_slope_and_reports_z_and_tilt():
    pitch = -math.radians(15.0)  # nose up: climbing
    loc = make_localizer(parse_ekf_config(_tilt_params(), MODELS))
    v = 0.5  # along the surface
    for k in range(100):
        t = k * 10 * MS
        loc.add_measurement("imu0", _imu(t, 0.0, pitch))
        q = np.array([v, v, 0.0]) * k * 0.01 / 0.05
        assert not loc.add_measurement("joint0", JointStateMeasurement(t, ("l", "r", "a"), q)).rejected
    est = loc.committed()
    assert est.state[3] == pytest.approx(v * math.cos(pitch), rel=2e-3)  # horizontal speed
    at_last_sample = {f: val for f, val, _ in loc.advance_to(990 * MS).extra}
    out = loc.advance_to(1990 * MS)  # 1 s later, no new tilt sample: z as of the last one
    extra = {f: (val, var) for f, val, var in out.extra}
    assert extra[4][0] == pytest.approx(pitch)
    # climbing at v·sin(15°) from the first tilt sample after the start (10 ms) to the last (990 ms)
    assert at_last_sample[2] == pytest.approx(v * math.sin(-pitch) * 0.98, rel=0.02)
    assert extra[2][0] == at_last_sample[2]
    assert extra[2][1] > 0.0
    assert extra[2][1] > 0.0


def test_unprovided_orientation_is_not_used_for_tilt():
    loc = make_localizer(parse_ekf_config(_tilt_params(), MODELS))
    res = loc.add_measurement("imu0", _imu(0, 0.0, 0.3, provided=False))
    assert ("tilt", REJECT_NOT_PROVIDED) in res.rejected
    assert loc.tilt_at(0) is None
    for k in range(50):
        q = np.array([0.5, 0.5, 0.0]) * k * 0.01 / 0.05
        loc.add_measurement("joint0", JointStateMeasurement(k * 10 * MS, ("l", "r", "a"), q))
    assert loc.committed().state[3] == pytest.approx(0.5, rel=2e-3)  # not projected


def test_without_compensation_the_surface_speed_drives_the_state():
    loc = make_localizer(parse_ekf_config(_tilt_params(joint0_tilt_compensation=False), MODELS))
    for k in range(50):
        t = k * 10 * MS
        loc.add_measurement("imu0", _imu(t, 0.0, -0.26))
        q = np.array([0.5, 0.5, 0.0]) * k * 0.01 / 0.05
        loc.add_measurement("joint0", JointStateMeasurement(t, ("l", "r", "a"), q))
    assert loc.committed().state[3] == pytest.approx(0.5, rel=2e-3)


def test_cmd_vel_and_odometry_twist_are_projected_when_configured():
    params = {"imu0": "imu", "imu0_config": [False] * 3 + [True, True, False] + [False] * 9,
              "twist0": "tw",
              "twist0_config": [False] * 6 + [True, True, False, False, False, True] + [False] * 3,
              "twist0_tilt_compensation": True, "use_control": True, "control_tilt_compensation": True}
    loc = make_localizer(parse_ekf_config(params, MODELS))
    from ekf_localization.core.measurements import ControlCommand, TwistMeasurement

    loc.add_measurement("imu0", _imu(0, 0.1, -0.2))
    C = np.eye(6) * 1e-4
    loc.add_measurement("twist0", TwistMeasurement(MS, "base_link", np.array([0.5, 0.2, 0, 0, 0, 0.3]), C))
    # the twist plan saw the projected velocity
    entry = loc.history[-1]
    (_, z, _), = entry.updates
    np.testing.assert_allclose(z, horizontal_projection(0.1, -0.2) @ [0.5, 0.2, 0.3])
    loc.add_control(ControlCommand(2 * MS, np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])))
    np.testing.assert_allclose(loc.history[-1].command, horizontal_projection(0.1, -0.2) @ [1.0, 0.0, 0.0])


def test_horizontal_projection_takes_arrays_of_tilts() -> None:
    roll, pitch = np.array(TILTS).T
    P = horizontal_projection(roll, pitch)
    assert P.shape == (len(TILTS), 3, 3)
    for k, (r, p) in enumerate(TILTS):
        assert np.array_equal(P[k], horizontal_projection(r, p))
