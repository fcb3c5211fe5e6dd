"""Swerve modules as a jointN geometry (no ROS): the kinematics against finite differences and a
round trip, the fused rows against the explicit weighted least-squares fit, a reversed module,
coaxial coupling, and degenerate layouts refused naming the parameter."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest
from helpers.ros_helpers import REPO, node_command

from ekf_localization.core.ekf import ExtendedKalmanFilter
from ekf_localization.core.linear import LinearMeasurement, select_rows
from ekf_localization.core.measurements import REJECT_NOT_PROVIDED, REJECT_SLIP, JointStateMeasurement
from ekf_localization.core.swerve_states import SwerveSample
from ekf_localization.models.mecanum import MecanumModel
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.models.swerve import SwerveKinematics, layout_problem, module_vectors, wls_twist
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError

R_WHEEL = 0.0508
POS = [0.29, 0.29, 0.29, -0.29, -0.29, 0.29, -0.29, -0.29]  # FL, FR, RL, RR (m)
DRIVE = ("fl_drive", "fr_drive", "rl_drive", "rr_drive")
STEER = ("fl_steer", "fr_steer", "rl_steer", "rr_steer")
MS = 1_000_000


def params(**extra):
    p = {"history_length": 1.0, "max_measurement_age": 2.0,
         "process_noise_covariance": list((np.eye(15) * 0.5).ravel()),
         "joint0": "joint_states", "joint0_geometry": "swerve", "joint0_names": list(DRIVE),
         "joint0_steer_names": list(STEER), "joint0_module_positions": POS,
         "joint0_wheel_radius": R_WHEEL}
    p.update(extra)
    return p


def localizer(**kw):
    return make_localizer(parse_ekf_config(params(**kw), MODELS))


def handler(loc):
    return loc._handlers["joint0"]


def js(t_ns, positions, velocities=()):
    return JointStateMeasurement(t_ns, DRIVE + STEER, np.asarray(positions, float),
                                 np.asarray(velocities, float))


# --- kinematics -----------------------------------------------------------------------------------

def test_module_rows_are_the_derivative_of_the_module_velocities():
    """A (2N, 3) and the handler's H against central differences of the module velocity vectors
    computed from (speed, angle) of each module."""
    kin = SwerveKinematics(POS)
    loc = localizer()
    H = handler(loc).H

    def h(state):  # the mecanum state [x y yaw vx vy vyaw]
        speeds, angles = kin.twist_to_modules(state[3:6])
        return module_vectors(speeds, angles)

    s = np.random.default_rng(4).normal(size=6)
    eps = 1e-6
    fd = np.column_stack([(h(s + eps * e) - h(s - eps * e)) / (2 * eps) for e in np.eye(6)])
    np.testing.assert_allclose(H, fd, atol=1e-8)
    np.testing.assert_allclose(H @ s, h(s), atol=1e-12)
    np.testing.assert_allclose(kin.module_rows, H[:, 3:6])


def test_round_trip_twist_modules_twist():
    kin = SwerveKinematics(POS)
    rng = np.random.default_rng(5)
    for twist in rng.normal(size=(20, 3)):
        speeds, angles = kin.twist_to_modules(twist, current_angles=rng.uniform(-math.pi, math.pi, 4))
        u = module_vectors(speeds, angles)
        v, C = wls_twist(kin.module_rows, u, np.eye(8) * 1e-4)
        np.testing.assert_allclose(v, twist, atol=1e-12)
        assert np.all(np.abs(speeds) <= np.hypot(*kin.twist_to_vectors(twist).T) + 1e-12)


def test_module_speeds_turn_by_at_most_a_quarter_turn():
    kin = SwerveKinematics(POS)
    speeds, angles = kin.twist_to_modules([1.0, 0.0, 0.0], current_angles=np.full(4, math.pi - 0.1))
    np.testing.assert_allclose(speeds, -1.0)
    np.testing.assert_allclose(np.abs(angles), math.pi)


def drive_modules(loc, twist, steps=60, dt_ms=20, gear=1.0, coupling=0.0, flip=(), use_velocities=False):
    """Feed the module joints of a constant twist: drive positions integrate the wheel (times the
    gear ratio, plus the coupling of the steer angle); modules in ``flip`` run reversed."""
    kin = SwerveKinematics(POS)
    speeds, angles = kin.twist_to_modules(twist)
    for i in flip:
        speeds[i], angles[i] = -speeds[i], angles[i] + math.pi
    wheel_rate = speeds / R_WHEEL
    results = []
    for k in range(steps):
        t = k * dt_ms / 1000.0
        steer = angles + 0.0 * t
        drive = gear * wheel_rate * t + coupling * steer
        vel = np.concatenate([gear * wheel_rate, np.zeros(4)]) if use_velocities else ()
        results.append(loc.add_measurement("joint0", js(k * dt_ms * MS, np.concatenate([drive, steer]), vel)))
    return results


@pytest.mark.parametrize("gear, coupling", [(1.0, 0.0), (6.75, 50.0 / 14.0)])
def test_round_trip_from_module_joints_to_the_body_twist(gear, coupling):
    loc = localizer(joint0_drive_gear_ratio=gear, joint0_coupling_ratio=coupling)
    twist = np.array([0.8, -0.5, 1.2])
    results = drive_modules(loc, twist, gear=gear, coupling=coupling)
    assert not any(r.rejected for r in results)
    np.testing.assert_allclose(loc.committed().state[3:6], twist, atol=2e-3)
    assert loc.stats["joint0"].applied == 59


def test_coupling_ratio_removes_the_steering_from_the_wheel():
    """A coaxial module steered on the spot: the drive joint turns with the steering, the wheel
    does not roll; with the coupling ratio the fused twist stays at rest."""
    c = 50.0 / 14.0
    loc = localizer(joint0_coupling_ratio=c)
    for k in range(40):
        steer = np.full(4, 0.05 * k)
        assert not loc.add_measurement("joint0", js(k * 20 * MS, np.concatenate([c * steer, steer]))).rejected
    np.testing.assert_allclose(loc.committed().state[3:6], 0.0, atol=1e-3)


def test_a_reversed_module_is_the_same_state():
    """(s, φ) and (−s, φ + π): the same z and R, and the same fused estimate."""
    loc = localizer()
    h = handler(loc)
    kin = SwerveKinematics(POS)
    speeds, angles = kin.twist_to_modules([0.6, 0.3, -0.9])
    state = np.array([0.0, 0.0, 0.0, 0.5, 0.2, -0.8])
    flipped_s, flipped_a = speeds.copy(), angles.copy()
    flipped_s[[0, 2]] *= -1.0
    flipped_a[[0, 2]] += math.pi
    _, z1, R1 = h.update(SwerveSample(0, speeds, angles, 20 * MS), state)
    _, z2, R2 = h.update(SwerveSample(0, flipped_s, flipped_a, 20 * MS), state)
    np.testing.assert_allclose(z1, z2, atol=1e-12)
    np.testing.assert_allclose(R1, R2, atol=1e-15)
    a, b = localizer(), localizer()
    drive_modules(a, [0.6, 0.3, -0.9])
    drive_modules(b, [0.6, 0.3, -0.9], flip=(0, 2))
    np.testing.assert_allclose(a.committed().state, b.committed().state, atol=1e-9)
    np.testing.assert_allclose(a.committed().covariance, b.committed().covariance, atol=1e-12)


def test_fused_rows_equal_the_weighted_least_squares_fit():
    """Fusing the 2N module rows (H, z, R) gives the state and covariance of fusing the explicit WLS
    twist v̂ = (AᵀR⁻¹A)⁻¹AᵀR⁻¹z with covariance (AᵀR⁻¹A)⁻¹ (information form)."""
    loc = localizer(joint0_steer_angle_variance=4e-3, joint0_speed_variance_coeff=0.01)
    h = handler(loc)
    rng = np.random.default_rng(7)
    kin = SwerveKinematics(POS)
    speeds, angles = kin.twist_to_modules([0.9, -0.4, 1.5])
    speeds = speeds + rng.normal(scale=0.05, size=4)  # modules that disagree
    angles = angles + rng.normal(scale=0.05, size=4)
    prior = np.array([0.1, -0.2, 0.3, 0.8, -0.3, 1.4])
    plan, z, R = h.update(SwerveSample(0, speeds, angles, None), prior)
    P0 = np.diag([0.1, 0.1, 0.05, 0.5, 0.5, 0.8]) + 0.01
    rows = ExtendedKalmanFilter(MecanumModel(), prior, P0)
    assert rows.update(plan.model, z, R).accepted
    v, C = wls_twist(h.A, z, R)
    fit = ExtendedKalmanFilter(MecanumModel(), prior, P0)
    assert fit.update(select_rows(6, [3, 4, 5]), v, C).accepted
    np.testing.assert_allclose(rows.x, fit.x, atol=1e-12)
    np.testing.assert_allclose(rows.P, fit.P, atol=1e-12)
    assert isinstance(plan.model, LinearMeasurement) and plan.model.H.shape == (8, 6)


def test_covariance_is_speed_along_and_angle_across_the_module():
    loc = localizer(joint0_steer_angle_variance=1e-2, joint0_speed_variance_coeff=0.0,
                    joint0_speed_variance_floor=1e-4)
    h = handler(loc)
    speeds = np.array([2.0, 2.0, 2.0, 2.0])
    angles = np.array([0.0, math.pi / 2, 0.3, -2.0])
    _, _, R = h.update(SwerveSample(0, speeds, angles, None))
    for i, a in enumerate(angles):
        along = np.array([math.cos(a), math.sin(a)])
        across = np.array([-math.sin(a), math.cos(a)])
        block = R[2 * i:2 * i + 2, 2 * i:2 * i + 2]
        assert along @ block @ along == pytest.approx(1e-4)
        assert across @ block @ across == pytest.approx(4.0 * 1e-2 + 1e-4)


def test_velocities_without_positions_have_no_steer_angle():
    loc = localizer(joint0_use_velocities=True)
    res = loc.add_measurement("joint0", JointStateMeasurement(0, DRIVE + STEER, np.array([]), np.ones(8)))
    assert res.rejected == (("encoders", REJECT_NOT_PROVIDED),)
    results = drive_modules(localizer(joint0_use_velocities=True), [0.4, 0.1, 0.2], use_velocities=True)
    assert not any(r.rejected for r in results)


# --- refused layouts ------------------------------------------------------------------------------

@pytest.mark.parametrize("extra, name", [
    ({"joint0_module_positions": [0.3, 0.3] * 4}, "joint0_module_positions"),
    ({"joint0_names": ["fl_drive"], "joint0_steer_names": ["fl_steer"],
      "joint0_module_positions": [0.3, 0.3]}, "joint0_names"),
    ({"joint0_module_positions": POS[:6]}, "joint0_module_positions"),
    ({"joint0_steer_names": list(STEER[:3])}, "joint0_steer_names"),
    ({"model": "tank"}, "joint0_geometry"),
])
def test_degenerate_layouts_are_refused_naming_the_parameter(extra, name):
    with pytest.raises(ParameterError) as err:
        parse_ekf_config(params(**extra), MODELS)
    assert err.value.name == name, str(err.value)


def test_layout_problem():
    assert layout_problem(np.reshape(POS, (-1, 2))) is None
    assert "two modules" in layout_problem([[0.3, 0.3]])
    assert "one point" in layout_problem([[0.3, 0.3], [0.3, 0.3]])
    with pytest.raises(ValueError, match="one point"):
        SwerveKinematics([0.1, 0.1, 0.1, 0.1])


@pytest.mark.ros
def test_ekf_node_refuses_a_degenerate_layout_with_exit_2(ros_domain, tmp_path):
    """All modules at one point: one line naming joint0_module_positions, exit code 2."""
    path = tmp_path / "swerve.yaml"
    path.write_text("ekf_node:\n  ros__parameters:\n    joint0: joint_states\n    joint0_geometry: swerve\n"
                    f"    joint0_names: {list(DRIVE)}\n    joint0_steer_names: {list(STEER)}\n"
                    f"    joint0_module_positions: {[0.3, 0.3] * 4}\n")
    res = subprocess.run([*node_command("ekf_node"), "--ros-args", "--params-file", str(path)],
                         capture_output=True, text=True, timeout=60, cwd=str(REPO))
    assert res.returncode == 2, res.stdout + res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in res.stderr + res.stdout, res.stderr
    assert "joint0_module_positions" in lines[0] and "one point" in lines[0], lines[0]


@pytest.mark.parametrize("name", ["ekf_swerve.yaml", "ekf_tank.yaml"])
def test_shipped_drive_configs_build_a_localizer(name):
    from ekf_localization.ros.parameters import parameters_from_yaml

    loc = make_localizer(parse_ekf_config(parameters_from_yaml(REPO / "config" / name, "ekf_node"), MODELS))
    assert loc.stats


def test_a_spinning_module_is_found_by_the_modules_disagreement():
    """slip_detection on a swerve input: the 2N rows' own misfit (χ² with 2N − 3 dof) finds one
    module spinning 1 m/s faster than the body moves it, and its messages are refused."""
    loc = localizer(joint0_slip_detection=True)
    speeds, angles = SwerveKinematics(POS).twist_to_modules(np.array([0.5, 0.0, 0.0]))
    drive = np.zeros(4)
    gripping, spinning = [], []
    for k in range(1, 151):
        extra = np.array([1.0 / R_WHEEL, 0.0, 0.0, 0.0]) if k > 100 else np.zeros(4)
        drive += (speeds / R_WHEEL + extra) * 0.02
        res = loc.add_measurement("joint0", js(k * 20 * MS, np.concatenate([drive, angles])))
        (gripping if k <= 100 else spinning).append(res)
    slips = [sum(r == REJECT_SLIP for _, r in res.rejected) for res in (*gripping, *spinning)]
    assert sum(slips[:100]) == 0 and loc.stats["joint0"].slips == 1
    assert sum(slips[100:]) >= 40  # every message from the third on (slip_persistence 40 ms)
