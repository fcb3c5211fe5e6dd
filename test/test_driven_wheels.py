"""The drive's own wheel encoders as sensor_msgs/JointState (no ROS): the jointN geometries mecanum
and differential, the noise at the predicted speed with quantisation, and the units guard."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from ekf_localization.core.joint_states import EncoderInputConfig, EncoderSample, UnitsGuard
from ekf_localization.core.measurements import (
    REJECT_ENCODER_JUMP,
    REJECT_JOINT_MISSING,
    JointStateMeasurement,
)
from ekf_localization.inputs.joint import driven_rows
from ekf_localization.models import differential, mecanum
from ekf_localization.models.mecanum import MecanumKinematics
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError

R, L, LT = 0.048, 0.168, 0.2  # wheel radius, half wheelbase, half track (m)
MECANUM = ("wheel_rl", "wheel_rr", "wheel_fl", "wheel_fr")
DIFF = ("wheel_left", "wheel_right")
MS = 1_000_000


def js(t_ns, positions, names, velocities=()):
    return JointStateMeasurement(t_ns, tuple(names), np.asarray(positions, float),
                                 np.asarray(velocities, float))


def params(geometry="mecanum", names=MECANUM, **extra):
    p = {"history_length": 1.0, "max_measurement_age": 2.0,
         "process_noise_covariance": list((np.eye(15) * 0.5).ravel()),
         "joint0": "joint_states", "joint0_geometry": geometry, "joint0_names": list(names),
         "joint0_wheel_radius": R, "joint0_half_wheelbase": L, "joint0_half_track": LT}
    p.update(extra)
    return p


def localizer(**kw):
    return make_localizer(parse_ekf_config(params(**kw), MODELS))


def wheel_rates(geometry: str, twist) -> np.ndarray:
    """The wheels' rad/s for a body twist [vx vy vyaw], from the models' own kinematics."""
    if geometry == "mecanum":
        return MecanumKinematics(R, L, LT).twist_to_wheels(np.asarray(twist, float))
    return differential.tank_kinematics(R, LT)[0] @ np.asarray(twist, float)


# --- the rows H ------------------------------------------------------------------------------------

@pytest.mark.parametrize("spec, geometry, cols", [
    (mecanum.SPEC, "mecanum", [3, 4, 5]), (mecanum.SPEC, "differential", [3, 4, 5]),
    (differential.SPEC, "differential", [2, None, 4]),
    (differential.TANK_SPEC, "differential", [2, None, 4])])
def test_driven_wheel_rows_are_the_kinematics_derivative(spec, geometry, cols):
    """H against central differences of the inverse kinematics on the state's body twist."""
    H = spec.driven_wheel_rows(geometry, R, L, LT)
    n = len(spec.state_fields)

    def h(s):
        return wheel_rates(geometry, [0.0 if c is None else s[c] for c in cols])

    s = np.random.default_rng(2).normal(size=n)
    eps = 1e-6
    fd = np.column_stack([(h(s + eps * e) - h(s - eps * e)) / (2 * eps) for e in np.eye(n)])
    np.testing.assert_allclose(H, fd, atol=1e-8)
    np.testing.assert_allclose(H @ s, h(s), atol=1e-12)


def test_the_strafe_scale_rows_are_the_derivative_of_the_wheels_of_a_short_strafe():
    """A robot that strafes σ × eq. 23's turns its wheels as eq. 23 says for ẏ/σ: the handler's rows
    against central differences of that; σ = 1 is the model's rows exactly."""
    spec, n = mecanum.SPEC, len(mecanum.SPEC.state_fields)
    cfg = EncoderInputConfig(names=MECANUM, geometry="mecanum", wheel_radius=R, half_wheelbase=L,
                             half_track=LT, strafe_scale=0.9)
    H = driven_rows(spec, cfg)

    def h(s):
        return R * wheel_rates("mecanum", [s[3], s[4] / 0.9, s[5]])

    s = np.random.default_rng(3).normal(size=n)
    eps = 1e-6
    fd = np.column_stack([(h(s + eps * e) - h(s - eps * e)) / (2 * eps) for e in np.eye(n)])
    np.testing.assert_allclose(H, fd, atol=1e-8)
    one = driven_rows(spec, replace(cfg, strafe_scale=1.0))
    np.testing.assert_array_equal(one, R * spec.driven_wheel_rows("mecanum", R, L, LT))


def test_a_short_strafe_is_fused_as_the_robots_lateral_velocity():
    loc = localizer(joint0_strafe_scale=0.9)
    twist = np.array([0.2, -0.3, 0.4])
    rates = wheel_rates("mecanum", twist / [1.0, 0.9, 1.0])  # the wheels turn for ẏ/σ
    for k in range(80):
        assert not loc.add_measurement("joint0", js(k * 20 * MS, rates * k * 0.02, MECANUM)).rejected
    np.testing.assert_allclose(loc.committed().state[3:6], twist, atol=2e-3)


def test_mecanum_wheels_on_a_state_without_lateral_velocity_are_refused():
    with pytest.raises(ValueError, match="lateral"):
        differential.SPEC.driven_wheel_rows("mecanum", R, L, LT)
    with pytest.raises(ParameterError) as err:
        parse_ekf_config(params(model="differential"), MODELS)
    assert err.value.name == "joint0_geometry"


# --- round trip: twist -> wheel positions -> fused twist -------------------------------------------

@pytest.mark.parametrize("model, geometry, names, twist, state_twist", [
    ("mecanum", "mecanum", MECANUM, [0.4, -0.3, 0.6], [3, 4, 5]),
    ("mecanum", "differential", DIFF, [0.5, 0.0, -0.7], [3, 4, 5]),
    ("differential", "differential", DIFF, [0.5, 0.0, 0.8], [2, None, 4]),
])
def test_round_trip_from_wheel_positions_to_the_body_twist(model, geometry, names, twist, state_twist):
    loc = localizer(model=model, geometry=geometry, names=names)
    rates = wheel_rates(geometry, twist)
    arm = ("arm_joint", "intake")  # other joints in the same message are ignored
    for k in range(80):
        t = k * 0.02
        msg = js(k * 20 * MS, [*(rates * t), 3.0 * k, math.nan], (*names, *arm))
        assert not loc.add_measurement("joint0", msg).rejected
    est = loc.committed().state
    got = [0.0 if c is None else est[c] for c in state_twist]
    np.testing.assert_allclose(got, twist, atol=2e-3)
    assert loc.stats["joint0"].applied == 79  # the first message is the positions' baseline


def test_velocities_used_when_configured_and_directions_flip_mirrored_wheels():
    twist = np.array([0.3, 0.2, -0.4])
    rates = wheel_rates("mecanum", twist)
    signs = np.array([1.0, -1.0, 1.0, -1.0])  # the right side's motors mounted mirrored
    loc = localizer(joint0_use_velocities=True, joint0_directions=list(signs))
    for k in range(60):
        # positions are garbage: the velocities are used when both are present
        msg = js(k * 20 * MS, np.full(4, 1e3 * k), MECANUM, velocities=rates * signs)
        assert not loc.add_measurement("joint0", msg).rejected
    np.testing.assert_allclose(loc.committed().state[3:6], twist, atol=2e-3)


def test_a_message_with_velocities_and_no_positions_is_fused_from_its_velocities():
    twist = np.array([0.3, 0.2, -0.4])
    rates = wheel_rates("mecanum", twist)
    loc = localizer()  # use_velocities false: positions when there are any
    for k in range(60):
        msg = js(k * 20 * MS, np.zeros(0), MECANUM, velocities=rates)
        assert not loc.add_measurement("joint0", msg).rejected
    np.testing.assert_allclose(loc.committed().state[3:6], twist, atol=2e-3)


def test_a_message_lacking_a_named_wheel_is_rejected_with_its_reason():
    loc = localizer()
    res = loc.add_measurement("joint0", js(0, [0.0, 0.0, 0.0], MECANUM[:3]))
    assert res.rejected == (("encoders", REJECT_JOINT_MISSING),)


def test_a_message_with_none_of_the_wheels_is_ignored_and_not_a_fault():
    """An arm's joints on the same topic, in messages of their own: neither fused nor refused."""
    loc = localizer()
    for k in range(20):
        res = loc.add_measurement("joint0", js(k * 20 * MS, [0.1, 0.2], ("arm_lift", "arm_wrist")))
        assert res.rejected == () and res.applied == ()
    assert loc.stats["joint0"].rejected_total == 0 and loc.stats["joint0"].fault is None


@pytest.mark.parametrize("name, value", [
    ("joint0_names", list(MECANUM[:3])), ("joint0_half_wheelbase", 0.0), ("joint0_geometry", "hovercraft"),
    ("joint0_directions", [1.0, -1.0]), ("joint0_directions", [1.0, 2.0, 1.0, 1.0]),
    ("joint0_position_resolution", -0.1), ("joint0_strafe_scale", 0.0), ("joint0_strafe_scale", math.inf),
    ("joint0_strafe_scale", 0.9)])
def test_bad_driven_wheel_parameters_name_the_parameter(name, value):
    wheels = ("differential", DIFF) if value == 0.9 else ("mecanum", MECANUM)  # 0.9: not mecanum
    with pytest.raises(ParameterError) as err:
        parse_ekf_config(params(*wheels, **{name: value}), MODELS)
    assert err.value.name == name


# --- noise: the predicted speed, quantisation over each interval ------------------------------------

def test_speed_term_at_the_predicted_speed_and_quantisation_per_interval():
    loc = localizer(joint0_speed_variance_coeff=0.01, joint0_speed_variance_floor=1e-6,
                    joint0_position_resolution=2 * math.pi / 537.7)
    handler = loc._handlers["joint0"]
    cfg: EncoderInputConfig = handler.config
    state = np.array([0.0, 0.0, 0.0, 0.5, 0.1, 0.3])
    E = np.array([0.0, 0.01, 0.0, 0.02])  # a slow, quantised sample: it must not look certain
    _, z, Rm = handler.update(EncoderSample(0, E, 16 * MS), None, state)
    Ep = handler.H @ state
    q = cfg.wheel_radius * cfg.position_resolution
    expected = 0.01 * Ep * Ep + 1e-6 + q * q / (6 * 0.016 ** 2)
    np.testing.assert_allclose(np.diag(Rm), expected, rtol=1e-12)
    np.testing.assert_array_equal(z, E)
    _, _, R41 = handler.update(EncoderSample(0, E, 41 * MS), None, state)  # a longer interval: less
    assert np.all(np.diag(R41) < np.diag(Rm))
    _, _, Rv = handler.update(EncoderSample(0, E, None), None, state)  # velocities: no quantisation
    np.testing.assert_allclose(np.diag(Rv), 0.01 * Ep * Ep + 1e-6, rtol=1e-12)


# --- the units guard -----------------------------------------------------------------------------

def test_ticks_given_as_radians_raise_a_fault_naming_the_units():
    """537.7 ticks per turn sent as rad: at 0.5 m/s each 20 ms interval moves ~18 rad (~890 rad/s)."""
    loc = localizer()
    ticks_per_rad = 537.7 / (2 * math.pi)
    rates = wheel_rates("mecanum", [0.5, 0.0, 0.0])
    faults = []
    for k in range(60):
        loc.add_measurement("joint0", js(k * 20 * MS, rates * k * 0.02 * ticks_per_rad, MECANUM))
        faults.append(loc.stats["joint0"].fault)
    fault = faults[-1]
    assert fault is not None and fault.startswith("positions must be radians of the wheel; got ~")
    rate = float(fault.split("~")[1].split(" ")[0])
    assert rate == pytest.approx(rates[0] * ticks_per_rad, rel=0.01)
    assert "joint0_max_speed" in fault
    assert faults[:4] == [None] * 4  # too few messages to judge
    assert loc.stats["joint0"].rejected[REJECT_ENCODER_JUMP] == 59


def test_the_guard_clears_when_messages_are_accepted_again_and_ignores_a_single_reset():
    cfg = EncoderInputConfig(names=MECANUM, geometry="mecanum", wheel_radius=R, half_wheelbase=L,
                             half_track=LT)
    guard = UnitsGuard(cfg, "joint0")
    outcomes = [None] * 20 + [REJECT_ENCODER_JUMP] + [None] * 20  # one encoder reset
    assert all(guard.note(k * 20 * MS, r, 900.0) is None for k, r in enumerate(outcomes))
    faults = [guard.note(k * 20 * MS, REJECT_JOINT_MISSING) for k in range(41, 200)]
    # 81 messages since the start: the fault comes with the 41st refusal (the reset among them)
    assert faults[:39] == [None] * 39
    assert faults[39] == (f"51 % of messages refused in 2 s ({REJECT_JOINT_MISSING} 40, "
                          f"{REJECT_ENCODER_JUMP} 1)")
    assert faults[-1] == f"100 % of messages refused in 2 s ({REJECT_JOINT_MISSING} 101)"
    for k in range(200, 300):
        fault = guard.note(k * 20 * MS, None)
    assert fault is None


def test_diagnostics_report_the_fault_as_an_error():
    from diagnostic_msgs.msg import DiagnosticStatus

    from ekf_localization.ros.ekf_diagnostics import EkfDiagnostics

    loc = localizer()
    for k in range(30):
        loc.add_measurement("joint0", js(k * 20 * MS, np.full(4, 20.0 * k), MECANUM), now_ns=k * 20 * MS)
    statuses = EkfDiagnostics(loc, False).statuses("ekf", 0, 30 * 20 * MS, 0, ())
    (st,) = [s for s in statuses if s.name == "ekf: joint0"]
    assert st.level == DiagnosticStatus.ERROR
    assert st.message.startswith("positions must be radians of the wheel; got ~")
