"""The IMU's yaw-rate scale and bias: the simulator's miscalibrated gyro and ekf_node's correction."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.fusion_scenario import config, fuse, make_scenario

from ekf_localization.core.measurements import ImuMeasurement
from ekf_localization.inputs.imu import corrected_yaw_rate
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError
from sim_robot.ros.sim_params import parse_parameters
from sim_robot.world.imu_sensor import ImuConfig, ImuSensor

SCALE, BIAS = 1.02, 0.01  # rad/s


def _imu(stamp: int, rate: float, var: float) -> ImuMeasurement:
    no = -np.eye(3)
    return ImuMeasurement(stamp, "base_link", np.zeros(3), no, np.array([0.0, 0.0, rate]),
                          np.diag([1e-6, 1e-6, var]), np.zeros(3), no)


def test_the_simulated_gyro_reports_scale_times_truth_plus_bias() -> None:
    world, _ = parse_parameters({"imu.yaw_rate_scale": SCALE, "imu.yaw_rate_bias": BIAS})
    assert (world.imu.yaw_rate_scale, world.imu.yaw_rate_bias) == (SCALE, BIAS)
    rates = np.array([-1.0, 0.0, 0.5, 2.0])
    # the same noise stream with and without the miscalibration: the difference is exact
    good = ImuSensor(ImuConfig(), 4, np.random.default_rng(1)).sample(0, np.zeros(4), rates, np.zeros((4, 2)))
    bad = ImuSensor(world.imu, 4, np.random.default_rng(1)).sample(0, np.zeros(4), rates, np.zeros((4, 2)))
    np.testing.assert_allclose(bad.yaw_rate - good.yaw_rate, (SCALE - 1.0) * rates + BIAS, atol=1e-15)
    np.testing.assert_array_equal(bad.yaw, good.yaw)  # the IMU's own heading is not affected


@pytest.mark.parametrize(("name", "value"), [
    ("imu.yaw_rate_scale", 0.0), ("imu.yaw_rate_scale", -1.0), ("imu.yaw_rate_scale", math.nan),
    ("imu.yaw_rate_bias", math.inf)])
def test_bad_simulator_values_name_the_parameter(name: str, value: float) -> None:
    with pytest.raises(ParameterError, match=f"'{name}'"):
        parse_parameters({name: value})


def _ekf(**imu) -> dict:
    return {"odom0": "odometry/dead_wheels", "odom0_config": fuse(6, 7, 11), "imu0": "imu/data",
            "imu0_config": fuse(11), **imu}


@pytest.mark.parametrize(("name", "value", "form"), [
    ("imu0_yaw_rate_scale", 0.0, "> 0"), ("imu0_yaw_rate_scale", -1.02, "> 0"),
    ("imu0_yaw_rate_scale", math.inf, "> 0"), ("imu0_yaw_rate_scale", math.nan, "> 0"),
    ("imu0_yaw_rate_bias", math.nan, "finite"), ("imu0_yaw_rate_bias", -math.inf, "finite")])
def test_bad_ekf_values_name_the_parameter(name: str, value: float, form: str) -> None:
    with pytest.raises(ParameterError) as info:
        parse_ekf_config(_ekf(**{name: value}), MODELS)
    assert info.value.name == name and form in str(info.value)


def test_the_correction_inverts_the_miscalibration_and_its_variance() -> None:
    m = corrected_yaw_rate(_imu(0, SCALE * 0.7 + BIAS, SCALE ** 2 * 4e-4), SCALE, BIAS)
    assert m.angular_velocity[2] == pytest.approx(0.7, abs=1e-15)
    assert m.angular_velocity_covariance[2, 2] == pytest.approx(4e-4, rel=1e-15)
    assert m.angular_velocity_covariance[0, 0] == 1e-6  # the other axes as given


def test_a_calibrated_filter_fed_the_miscalibrated_gyro_equals_a_default_one_fed_the_truth() -> None:
    """Same stream: the corrected yaw rate and variance are what the default filter gets, so
    every estimate matches (to rounding); the uncorrected filter is off by the bias."""
    scn = make_scenario(duration_s=2.0, seed=5)
    cal = make_localizer(config(imu0_yaw_rate_scale=SCALE, imu0_yaw_rate_bias=BIAS))
    ref = make_localizer(config())
    raw = make_localizer(config())
    for arrival, source, j in scn.events():
        item = scn.item(source, j)
        if source == "cmd_vel":
            for loc in (cal, ref, raw):
                loc.add_control(item, arrival)
            continue
        bad = item
        if source == "imu0":
            w, var = item.angular_velocity[2], item.angular_velocity_covariance[2, 2]
            bad = _imu(item.stamp_ns, SCALE * w + BIAS, SCALE ** 2 * var)
        cal.add_measurement(source, bad, arrival)
        raw.add_measurement(source, bad, arrival)
        ref.add_measurement(source, item, arrival)
    t = int(scn.t_ns[-1])  # the newest stamp: later, the velocity is the command's prediction
    a, b, c = cal.estimate_at(t), ref.estimate_at(t), raw.estimate_at(t)
    np.testing.assert_allclose(a.state, b.state, atol=1e-9)
    np.testing.assert_allclose(a.covariance, b.covariance, atol=1e-12)
    # vyaw: the uncorrected filter follows the gyro's error, (SCALE - 1)·w + BIAS, in part
    assert abs(c.state[5] - b.state[5]) > 0.5 * BIAS
