"""sim_node parameter validation and the shipped YAML files (no ROS)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from ekf_localization.ros.parameters import ParameterError
from ekf_localization.ros.params_match import section_for
from sim_robot.ros.sim_params import (
    POSE_VARIANCE_RATE,
    SIM_PARAMETERS,
    VELOCITY_VARIANCE_PER_TICK,
    parse_parameters,
)
from sim_robot.world.world import WorldConfig

CONFIG = Path(__file__).resolve().parents[1] / "config"


def flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, name + "."))
        else:
            out[name] = v
    return out


def load(name: str) -> dict:
    doc = yaml.safe_load((CONFIG / name).read_text())
    return flatten(section_for(doc, "sim_node"))


@pytest.mark.parametrize(("name", "drive"), [("sim.yaml", "mecanum"), ("sim_tank.yaml", "tank")])
def test_shipped_yaml_files_are_valid(name, drive):
    values = load(name)
    assert set(values) <= set(SIM_PARAMETERS)
    world, node = parse_parameters(values)
    assert world.drive == drive
    assert world.physics_period_ns == 1_000_000
    assert world.dead_wheels.period_ns == 10_000_000
    assert world.camera.latency_ns == 50_000_000
    assert world.camera.field_of_view == pytest.approx(math.radians(70.0))
    assert node.real_time_factor == 1.0 and node.publish_clock is False
    si = WorldConfig()  # the YAML noise is seed 000's, converted exactly to SI ...
    assert world.pose_variance_rate == pytest.approx(POSE_VARIANCE_RATE, rel=1e-12)
    assert world.pose_variance_rate[:2] == pytest.approx(si.pose_variance_rate[:2], rel=1e-12)
    # ... except the heading slip and the truth velocity jitter (seed 000's 0.45 (rad/s)² per
    # 1 ms tick is untrackable)
    assert world.velocity_variance_per_step == pytest.approx(VELOCITY_VARIANCE_PER_TICK, rel=1e-12)
    assert node.odom_dropout_ns is None
    assert world.dead_wheels.noise.variance_floor == pytest.approx(si.dead_wheels.noise.variance_floor)
    assert world.camera.position_noise.distance_variance_coeff == pytest.approx(
        si.camera.position_noise.distance_variance_coeff, rel=1e-12)
    # ... but for the camera's yaw, a fiducial-like 2 deg at 1 m instead of the paper's 2.6 rad
    assert world.camera.yaw_noise.distance_variance_coeff == pytest.approx(0.0012)
    assert world.camera.yaw_noise.variance_floor == pytest.approx(1e-4)


def test_defaults_are_the_seed000_robot():
    world, node = parse_parameters({})
    si = WorldConfig()
    assert world.mecanum == si.mecanum
    assert world.dead_wheels.geometry == si.dead_wheels.geometry
    assert world.pose_variance_rate == POSE_VARIANCE_RATE  # the realistic SI noise of sim.yaml
    assert world.velocity_variance_per_step == VELOCITY_VARIANCE_PER_TICK
    assert node.initial_pose == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(("name", "value", "expected"), [
    ("camera.frequency", 30, "decimal point"),  # an int where a float is required
    ("camera.frequency", 30.0, "whole number of physics ticks"),
    ("dead_wheels.frequency", 1e-300, "whole number of physics ticks"),  # no finite period
    ("imu.yaw_variance", -1.0, "> 0"),
    ("camera.outlier_probability", 1.5, "[0.0, 1.0]"),
    ("drive", "hovercraft", "'mecanum', 'tank'"),
    ("initial_pose", [0.0, 1.0], "3 finite floats"),
    ("initial_pose", [0, 1, 2], "list of floats"),
    ("dead_wheels.sampling", "sometimes", "'instantaneous'"),
    ("camera.field_of_view_deg", 200.0, "(0.0, 180.0)"),
    ("real_time_factor", 2.0, "unless publish_clock"),
    ("seed", 1.5, "an integer"),
    ("publish_clock", "yes", "true or false"),
    ("camera.max_rang", 3.0, "unknown parameter"),
])
def test_bad_values_name_the_parameter_and_the_expected_form(name, value, expected):
    with pytest.raises(ParameterError) as exc:
        parse_parameters({name: value})
    msg = str(exc.value)
    assert f"'{name}'" in msg and expected in msg, msg


def test_all_bad_values_are_reported_at_once():
    with pytest.raises(ParameterError) as exc:
        parse_parameters({"imu.frequency": 50, "tank.half_track": 0.0})
    assert "'imu.frequency'" in str(exc.value) and "'tank.half_track'" in str(exc.value)


def test_custom_field_and_disabled_limits():
    world, _ = parse_parameters({"field.preset": "custom", "field.custom_images": [0.0, 1.8288, -1.5708],
                                 "limits.wheel_speed_limit": 0.0, "real_time_factor": 0.0,
                                 "publish_clock": True})
    assert len(world.field.images) == 1 and world.field.images[0].y == 1.8288
    assert math.isinf(world.limits.wheel_speed_limit)
