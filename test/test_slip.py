"""Slip and collision detection for driven wheels (inputs/slip.py, no ROS): the redundant-row
fit and its χ², the false-alarm bound, and a synthetic slip and push through the Localizer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ekf_localization.core.measurements import REJECT_SLIP, ImuMeasurement, JointStateMeasurement
from ekf_localization.inputs.slip import SlipSettings, expected_false_alarms, twist_fit
from ekf_localization.models import mecanum
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError

R, L, LT = 0.048, 0.168, 0.18  # wheel radius, half wheelbase, half track (m)
WHEELS = ("rl", "rr", "fl", "fr")
MS = 1_000_000
Q = 2.0 * math.pi / 537.7  # encoder resolution, rad
H_MEC = R * mecanum.SPEC.driven_wheel_rows("mecanum", R, L, LT)[:, [3, 4, 5]]  # surface m/s <- [vx vy w]


def params(**extra) -> dict:
    p = {"history_length": 0.5, "max_measurement_age": 2.0,
         "process_noise_covariance": list((np.eye(15) * 0.05).ravel()),
         "joint0": "joint_states", "joint0_geometry": "mecanum", "joint0_names": list(WHEELS),
         "joint0_wheel_radius": R, "joint0_half_wheelbase": L, "joint0_half_track": LT,
         "joint0_position_resolution": Q, "joint0_speed_variance_coeff": 0.0,
         "joint0_speed_variance_floor": 1e-6, "joint0_slip_detection": True,
         "imu0": "imu", "imu0_config": [False] * 5 + [True] + [False] * 5 + [True] + [False] * 3}
    p.update(extra)
    return p


def test_fit_of_consistent_wheels_has_no_residual_and_one_spare_row() -> None:
    v = np.array([0.6, -0.3, 1.2])
    Rm = np.diag([1e-4, 2e-4, 1e-4, 3e-4])
    fit, C, c2, dof = twist_fit(H_MEC, H_MEC @ v, Rm)
    assert dof == 1 and c2 == pytest.approx(0.0, abs=1e-18)
    np.testing.assert_allclose(fit, v, atol=1e-12)
    np.testing.assert_allclose(C, np.linalg.inv(H_MEC.T @ np.linalg.inv(Rm) @ H_MEC), rtol=1e-9)
    z = H_MEC @ v
    z[0] += 0.1  # one wheel 10 cm/s fast: the redundant row breaks
    assert twist_fit(H_MEC, z, Rm)[2] > 5.0


def test_differential_rows_have_no_spare_row() -> None:
    H = R * mecanum.SPEC.driven_wheel_rows("differential", R, L, LT)[:, [3, 5]]
    assert twist_fit(H, np.array([0.3, 0.5]), np.eye(2) * 1e-4)[3] == 0


def test_the_disagreement_test_fails_at_its_false_alarm_probability() -> None:
    """Without slip the residual χ²(1) exceeds the bound with the configured tail probability."""
    s = SlipSettings(false_alarm_probability=0.01)
    rng = np.random.default_rng(5)
    Rm = np.diag([1e-4, 2e-4, 1.5e-4, 1e-4])
    n = 20000
    fails = sum(twist_fit(H_MEC, H_MEC @ rng.normal(0, 1, 3) + rng.normal(0, 1, 4) * np.sqrt(np.diag(Rm)),
                          Rm)[2] > s.bound(1) for _ in range(n))
    assert abs(fails / n - 0.01) < 4 * math.sqrt(0.01 * 0.99 / n)


def test_expected_false_alarms_over_the_demo_drives_are_below_a_tenth() -> None:
    """The shipped bounds (config/ekf_driven_wheels.yaml): eight drives of at most 40 s, wheels
    at 50 Hz, camera at 20 Hz behind a 5-sigma gate on 3 components."""
    from scipy.special import chdtrc

    s = SlipSettings()
    e = expected_false_alarms(s, 8 * 40.0, 50.0, camera_fixes=8 * 40 * 20, gate_tail=chdtrc(3, 25.0))
    assert e["total"] < 0.1
    assert e["acceleration"] == pytest.approx(8 * 40.0 / 0.1 * 1e-5)
    loose = expected_false_alarms(SlipSettings(false_alarm_probability=1e-2, persistence_ns=0), 320.0, 50.0)
    assert loose["total"] > 10.0  # the bound's tail matters: the test of the test


class Drive:
    """A robot driving a constant body twist; wheel positions and IMU records of it."""

    def __init__(self, loc, v=(0.5, 0.2, 0.3)) -> None:
        self.loc, self.v = loc, np.asarray(v, float)
        self.t = 0
        self.wheels = np.zeros(4)
        self.yaw = 0.0

    def run(self, seconds: float, wheel_extra=(0.0, 0.0, 0.0, 0.0), push=(0.0, 0.0)) -> list:
        """Advance in 10 ms steps: an IMU record each step, a wheel record every 20 ms. ``wheel_extra``
        adds to the wheels' surface speeds (a spinning wheel), ``push`` to the IMU's acceleration."""
        out = []
        for _ in range(round(seconds * 100)):
            self.t += 10 * MS
            speeds = H_MEC @ self.v + np.asarray(wheel_extra)
            self.wheels += speeds / R * 0.01
            self.yaw += self.v[2] * 0.01
            vx, vy, w = self.v
            acc = np.array([-w * vy + push[0], w * vx + push[1], 0.0])
            imu = ImuMeasurement(self.t, "base_link", np.array([0.0, 0.0, self.yaw]), np.eye(3) * 1e-4,
                                 np.array([0.0, 0.0, w]), np.eye(3) * 1e-4, acc, np.eye(3) * 0.01)
            out.append(self.loc.add_measurement("imu0", imu))
            if self.t % (20 * MS) == 0:
                pos = np.floor(self.wheels / Q) * Q
                out.append(self.loc.add_measurement("joint0", JointStateMeasurement(self.t, WHEELS, pos)))
        return out


def _slip_rejections(results) -> int:
    return sum(r == REJECT_SLIP for res in results for _, r in res.rejected)


def test_a_spinning_wheel_is_found_refused_and_widens_the_pose() -> None:
    loc = make_localizer(parse_ekf_config(params(), MODELS))
    drive = Drive(loc)
    assert _slip_rejections(drive.run(3.0)) == 0 and loc.stats["joint0"].slips == 0
    P_before = loc.estimate_at(drive.t).covariance[0, 0]
    slipping = drive.run(0.3, wheel_extra=(0.4, 0.0, 0.0, 0.0))
    assert loc.stats["joint0"].slips == 1
    assert _slip_rejections(slipping) >= 5
    assert loc.stats["joint0"].rejected[REJECT_SLIP] >= 5
    assert loc.estimate_at(drive.t).covariance[0, 0] > P_before + 0.2  # slip_pose_variance 0.25
    after = drive.run(1.0)  # gripping again: accepted after slip_hold
    assert _slip_rejections(after[-20:]) == 0 and loc.stats["joint0"].slips == 1


def test_a_push_the_wheels_do_not_feel_is_found_by_the_imu_acceleration() -> None:
    loc = make_localizer(parse_ekf_config(params(), MODELS))
    drive = Drive(loc)
    drive.run(3.0)
    assert loc.stats["joint0"].slips == 0
    drive.run(0.15, push=(0.0, 15.0))  # the wheels keep their speeds
    assert loc.stats["joint0"].slips == 1


def test_slip_detection_is_off_by_default_and_refused_on_dead_wheels() -> None:
    p = params()
    del p["joint0_slip_detection"]
    loc = make_localizer(parse_ekf_config(p, MODELS))
    drive = Drive(loc)
    drive.run(1.0)
    assert _slip_rejections(drive.run(0.3, wheel_extra=(0.4, 0.0, 0.0, 0.0))) == 0
    dead = params(joint0_geometry="dead_wheels", joint0_names=["l", "r", "a"])
    with pytest.raises(ParameterError, match="joint0_slip_detection"):
        parse_ekf_config(dead, MODELS)


def test_a_sideways_push_on_a_tank_is_found() -> None:
    """The differential model has no vy: its wheels (no spare row) say it does not slide, so the
    IMU's lateral acceleration beyond ω·v is a push."""
    p = params(model="differential", joint0_geometry="differential", joint0_names=["l", "r"],
               joint0_half_track=0.2)
    for k in ("joint0_half_wheelbase",):
        del p[k]
    loc = make_localizer(parse_ekf_config(p, MODELS))
    H = R * MODELS["differential"].driven_wheel_rows("differential", R, 0.0, 0.2)
    v, w = 0.5, 0.3
    speeds = H[:, [2, 4]] @ np.array([v, w])
    t, wheels, yaw = 0, np.zeros(2), 0.0
    for k in range(400):
        t += 10 * MS
        wheels += speeds / R * 0.01
        yaw += w * 0.01
        push = 15.0 if k >= 300 else 0.0
        loc.add_measurement("imu0", ImuMeasurement(
            t, "base_link", np.array([0.0, 0.0, yaw]), np.eye(3) * 1e-4, np.array([0.0, 0.0, w]),
            np.eye(3) * 1e-4, np.array([0.0, w * v + push, 0.0]), np.eye(3) * 0.01))
        if t % (20 * MS) == 0:
            loc.add_measurement("joint0", JointStateMeasurement(t, ("l", "r"), np.floor(wheels / Q) * Q))
        if k == 299:
            assert loc.stats["joint0"].slips == 0
    assert loc.stats["joint0"].slips == 1


def test_bad_imu_values_neither_crash_nor_flag() -> None:
    """Non-finite or 'not provided' IMU parts are not references; the estimate stays finite."""
    loc = make_localizer(parse_ekf_config(params(), MODELS))
    drive = Drive(loc)
    drive.run(1.0)
    nan3, big = np.full(3, math.nan), -np.ones((3, 3))  # REP-145: covariance[0] = -1, not provided
    cases = [(nan3, np.eye(3)), (np.full(3, 1e9), big), (np.zeros(3), nan3[:, None] * 0)]
    for k, (acc, cov) in enumerate(cases):
        loc.add_measurement("imu0", ImuMeasurement(drive.t + k + 1, "base_link", np.zeros(3),
                                                   np.eye(3) * 1e-4, np.array([0.0, 0.0, math.inf]),
                                                   np.eye(3), acc, cov))
    drive.run(1.0)
    assert loc.stats["joint0"].slips == 0
    assert loc.estimate_at(drive.t).is_finite()


def test_a_run_of_gated_camera_fixes_is_slip_and_the_next_fix_is_taken() -> None:
    """A displacement that neither the wheels nor the IMU felt: the camera's fixes are gated
    until the third in a row declares slip; the widened pose then takes it and the next ones."""
    from ekf_localization.core.measurements import PoseMeasurement

    p = params(pose0="camera/pose", pose0_config=[True, True, False, False, False, True] + [False] * 9,
               pose0_rejection_threshold=5.0, process_noise_covariance=list((np.eye(15) * 1e-4).ravel()))
    loc = make_localizer(parse_ekf_config(p, MODELS))
    drive = Drive(loc, v=(0.0, 0.0, 0.0))

    def fix(y: float):
        return loc.add_measurement("pose0", PoseMeasurement(drive.t, "odom", np.array([0.0, y, 0, 0, 0, 0]),
                                                            np.eye(6) * 1e-4))

    for _ in range(40):
        drive.run(0.05)
        assert not fix(0.0).rejected
    outcomes = []
    for _ in range(6):
        drive.run(0.05)
        outcomes.append(fix(0.4).rejected)
    # gated twice; the third in a row declares slip before it is fused: the widened pose takes it
    assert all(outcomes[:2]) and not any(outcomes[2:]) and loc.stats["joint0"].slips == 1
    assert loc.estimate_at(drive.t).state[1] == pytest.approx(0.4, abs=0.02)
