"""Dead-wheel encoders as sensor_msgs/JointState (no ROS): speeds, rejections, fusion (seed 000 eq. 29-33)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ekf_localization.core.joint_states import EncoderInputConfig, EncoderSpeeds
from ekf_localization.core.localizer import Localizer
from ekf_localization.core.measurements import (
    REJECT_ARRAY_LENGTHS,
    REJECT_DUPLICATE_NAMES,
    REJECT_ENCODER_JUMP,
    REJECT_JOINT_MISSING,
    REJECT_NONFINITE,
    REJECT_STAMP_NOT_INCREASING,
    JointStateMeasurement,
    TwistMeasurement,
)
from ekf_localization.inputs.joint import ENCODER_PART
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, encoders_to_twist
from ekf_localization.ros.ekf_parameters import parse_ekf_config, parse_ekf_settings
from ekf_localization.ros.parameters import ParameterError

NAMES = ("left_pod", "right_pod", "lateral_pod")
R_WHEEL = 0.024
W, D = 0.17, 0.1
A, B = 0.002, 6.4516e-07
MS = 1_000_000


def js(t_ns, positions, names=NAMES, velocities=()):
    return JointStateMeasurement(t_ns, tuple(names), np.asarray(positions, float),
                                 np.asarray(velocities, float))


def tracker(**kw) -> EncoderSpeeds:
    return EncoderSpeeds(EncoderInputConfig(names=NAMES, wheel_radius=R_WHEEL, **kw))


# --- speeds from JointState ---------------------------------------------------------------------

def test_speed_from_position_difference_over_integer_ns_stamped_at_midpoint():
    enc = tracker()
    assert enc.update(js(1_000_000_007, [0.0, 0.0, 0.0])) == (None, None)  # the baseline
    q = np.array([0.5, -0.25, 0.125])
    sample, reason = enc.update(js(1_010_000_007, q))
    assert reason is None
    assert sample.stamp_ns == 1_005_000_007  # midpoint, exact integer ns
    np.testing.assert_allclose(sample.speeds, R_WHEEL * q / 0.01, rtol=1e-12)


def test_names_in_any_order_and_extra_joints_are_matched_by_name():
    enc = tracker()
    order = ("arm", "lateral_pod", "left_pod", "right_pod")
    enc.update(js(0, [9.0, 0.0, 0.0, 0.0], names=order))
    sample, _ = enc.update(js(20 * MS, [-3.0, 0.3, 0.1, 0.2], names=order))
    np.testing.assert_allclose(sample.speeds, R_WHEEL * np.array([0.1, 0.2, 0.3]) / 0.02, rtol=1e-12)


def test_velocities_used_when_configured_and_present():
    enc = tracker(use_velocities=True)
    sample, reason = enc.update(js(5 * MS, [0.0, 0.0, 0.0], velocities=[10.0, 20.0, -5.0]))
    assert reason is None and sample.stamp_ns == 5 * MS
    np.testing.assert_allclose(sample.speeds, R_WHEEL * np.array([10.0, 20.0, -5.0]))
    # no velocities in the message: position differences
    sample, _ = enc.update(js(15 * MS, [0.1, 0.1, 0.1]))
    np.testing.assert_allclose(sample.speeds, R_WHEEL * 10.0 * np.ones(3), rtol=1e-12)
    # not configured: velocities ignored
    enc = tracker()
    assert enc.update(js(0, [0.0, 0.0, 0.0], velocities=[1.0, 1.0, 1.0])) == (None, None)


def test_encoder_reset_or_wrap_is_rejected_never_a_speed_spike():
    enc = tracker(max_speed=3.0)
    enc.update(js(0, [100.0, 100.0, 0.0]))
    enc.update(js(10 * MS, [100.5, 100.5, 0.0]))
    sample, reason = enc.update(js(20 * MS, [0.0, 100.9, 0.0]))  # left encoder reset to 0
    assert sample is None and reason == REJECT_ENCODER_JUMP
    sample, reason = enc.update(js(30 * MS, [0.4, 101.3, 2 * math.pi - 0.01]))  # lateral wraps at ±π
    assert reason == REJECT_ENCODER_JUMP
    sample, reason = enc.update(js(40 * MS, [0.8, 101.7, 2 * math.pi - 0.01]))  # continues from the new value
    assert reason is None
    np.testing.assert_allclose(sample.speeds, [R_WHEEL * 40.0, R_WHEEL * 40.0, 0.0], atol=1e-9)
    assert enc.jumps == 2


@pytest.mark.parametrize("message, reason", [
    (js(10 * MS, [0.1, 0.1]), REJECT_ARRAY_LENGTHS),
    (js(10 * MS, [0.1, 0.1, 0.1], velocities=[1.0]), REJECT_ARRAY_LENGTHS),
    (js(10 * MS, [0.1, 0.1, 0.1], names=("left_pod", "left_pod", "lateral_pod")), REJECT_DUPLICATE_NAMES),
    (js(10 * MS, [0.1, 0.1, 0.1], names=("left_pod", "right_pod", "other")), REJECT_JOINT_MISSING),
    (js(10 * MS, [0.1, math.nan, 0.1]), REJECT_NONFINITE),
    (js(0, [0.1, 0.1, 0.1]), REJECT_STAMP_NOT_INCREASING),
    (js(-5 * MS, [0.1, 0.1, 0.1]), REJECT_STAMP_NOT_INCREASING),
])
def test_bad_messages_get_a_reason_and_keep_the_baseline(message, reason):
    enc = tracker()
    enc.update(js(0, [0.0, 0.0, 0.0]))
    assert enc.update(message) == (None, reason)
    sample, r = enc.update(js(20 * MS, [0.2, 0.2, 0.2]))  # differenced against the old baseline
    assert r is None
    np.testing.assert_allclose(sample.speeds, R_WHEEL * 10.0 * np.ones(3), rtol=1e-12)


def test_nan_in_an_unused_joint_is_fine():
    enc = tracker()
    names = (*NAMES, "arm")
    enc.update(js(0, [0.0, 0.0, 0.0, math.nan], names=names))
    assert enc.update(js(10 * MS, [0.1, 0.1, 0.1, math.nan], names=names))[1] is None


# --- parameters ----------------------------------------------------------------------------------

def joint_params(**extra):
    p = {"joint0": "joint_states", "joint0_names": list(NAMES), "joint0_wheel_radius": R_WHEEL,
         "joint0_half_spacing": W, "joint0_lateral_offset": D, "joint0_speed_variance_coeff": A,
         "joint0_speed_variance_floor": B}
    p.update(extra)
    return p


def test_joint_parameters_parse():
    cfg = parse_ekf_config(joint_params(joint0_rejection_threshold=5.0), MODELS)
    (inp,) = cfg.inputs
    assert inp.kind == "joint" and inp.topic == "joint_states"
    assert inp.settings.names == NAMES and inp.settings.half_spacing == W
    assert inp.threshold(ENCODER_PART) == 5.0


@pytest.mark.parametrize("name, value", [
    ("joint0_names", ["a", "b"]), ("joint0_names", "left"), ("joint0_names", ["a", "a", "b"]),
    ("joint0_wheel_radius", 0.0), ("joint0_half_spacing", -0.1), ("joint0_speed_variance_floor", 0.0),
    ("joint0_speed_variance_coeff", -1.0), ("joint0_max_speed", math.nan), ("joint0_use_velocities", 1),
    ("joint0_bogus", 1.0),
])
def test_bad_joint_parameters_name_the_parameter(name, value):
    with pytest.raises(ParameterError) as err:
        parse_ekf_config(joint_params(**{name: value}), MODELS)
    assert err.value.name == name


def test_tank_takes_two_names_and_ignores_a_lateral_third():
    settings = parse_ekf_settings(joint_params(model="differential"), MODELS)
    assert settings.config.inputs[0].settings.names == NAMES[:2]
    assert any("lateral_pod" in w for w in settings.warnings)


# --- fusion --------------------------------------------------------------------------------------

def _localizer(params) -> Localizer:
    base = {"history_length": 1.0, "max_measurement_age": 2.0,
            "process_noise_covariance": list((np.eye(15) * 0.5).ravel())}
    base.update(params)
    return make_localizer(parse_ekf_config(base, MODELS))


def _encoder_positions(twist, t_s):
    """Joint positions (rad) after driving body twist [vx vy wz] for t_s seconds (eq. 30)."""
    E = DeadWheelGeometry(W, D).encoders_from_twist @ np.asarray(twist, float)
    return E * t_s / R_WHEEL


def test_joint_input_tracks_the_body_twist_on_the_mecanum_state():
    loc = _localizer(joint_params())
    twist = np.array([0.4, -0.2, 0.5])
    for k in range(60):
        res = loc.add_measurement("joint0", js(k * 10 * MS, _encoder_positions(twist, k * 0.01)))
        assert not res.rejected
    est = loc.committed()
    np.testing.assert_allclose(est.state[3:6], twist, atol=1e-3)
    assert loc.stats["joint0"].applied == 59


def test_joint_input_equals_the_twist_input_with_the_propagated_covariance():
    """Fusing E with R = diag(a·Ê² + b) through eq. 33's H (Ê = H x̂⁻, the predicted speeds) is the
    same update as fusing the body twist M⁻¹E with covariance M⁻¹ R M⁻ᵀ (eq. 29): the covariance
    comes from the encoders."""
    geometry = DeadWheelGeometry(W, D)
    twist_config = [False] * 6 + [True, True, False, False, False, True] + [False] * 3
    twist_params = {"twist0": "odometry/dead_wheels", "twist0_config": twist_config}
    joint = _localizer(joint_params(joint0_use_velocities=True))
    tw = _localizer(twist_params)
    rng = np.random.default_rng(4)
    for k in range(1, 40):
        t = k * 10 * MS
        E = geometry.encoders_from_twist @ np.array([0.6, 0.1, -0.8]) + rng.normal(0, 0.02, 3)
        prior = joint.estimate_at(t)
        Ep = E if prior is None else geometry.encoders_from_twist @ prior.state[3:6]
        joint.add_measurement("joint0", js(t, np.zeros(3), velocities=E / R_WHEEL))
        twist, cov = encoders_to_twist(geometry, E, np.diag(A * Ep * Ep + B))
        C = np.eye(6) * 1e6
        C[np.ix_([0, 1, 5], [0, 1, 5])] = cov
        tw.add_measurement("twist0", TwistMeasurement(t, "base_link", np.r_[twist[:2], 0, 0, 0, twist[2]], C))
    a, b = joint.committed(), tw.committed()
    np.testing.assert_allclose(a.state, b.state, atol=1e-9)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-6, atol=1e-12)


def test_joint_input_on_the_tank_state_uses_the_left_right_rows():
    loc = _localizer(joint_params(model="differential"))
    v, w = 0.5, 0.8  # forward speed, yaw rate
    for k in range(60):
        t = k * 0.01
        q = np.array([v - W * w, v + W * w]) * t / R_WHEEL
        assert not loc.add_measurement("joint0", js(k * 10 * MS, q, names=NAMES[:2])).rejected
    est = loc.committed()
    np.testing.assert_allclose(est.state[[2, 4]], [v, w], atol=1e-3)  # [x y v φ ω]


def test_localizer_counts_every_joint_state_rejection():
    loc = _localizer(joint_params())
    loc.add_measurement("joint0", js(0, [0.0, 0.0, 0.0]))
    loc.add_measurement("joint0", js(10 * MS, [0.0, 0.0]))
    loc.add_measurement("joint0", js(10 * MS, [0.0, 0.0, 0.0], names=("a", "b", NAMES[2])))
    loc.add_measurement("joint0", js(10 * MS, [0.0, math.nan, 0.0]))
    loc.add_measurement("joint0", js(10 * MS, [500.0, 0.0, 0.0]))  # 1200 m/s: a reset
    loc.add_measurement("joint0", js(5 * MS, [500.0, 0.0, 0.0]))
    rej = loc.stats["joint0"].rejected
    assert rej == {REJECT_ARRAY_LENGTHS: 1, REJECT_JOINT_MISSING: 1, REJECT_NONFINITE: 1,
                   REJECT_ENCODER_JUMP: 1, REJECT_STAMP_NOT_INCREASING: 1}
    assert loc.stats["joint0"].received == 6 and loc.stats["joint0"].applied == 0
    # after the jump the next speed is differenced from the new position: no spike
    assert not loc.add_measurement("joint0", js(20 * MS, [500.0, 0.0, 0.0])).rejected
    assert np.all(np.abs(loc.committed().state[3:6]) < 1e-6)
