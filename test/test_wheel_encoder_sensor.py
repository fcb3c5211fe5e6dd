"""The simulator's driven-wheel encoders (sim_robot.world.wheel_encoder_sensor) and their settings."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers.ros_helpers import REPO

from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml
from sim_robot.ros.sim_params import parse_parameters
from sim_robot.world.camera_sensor import CameraConfig
from sim_robot.world.wheel_encoder_sensor import WheelEncoderConfig, WheelEncoderReading
from sim_robot.world.world import World, WorldConfig


def _run(cfg: WheelEncoderConfig, seconds: float = 5.0, seed: int = 3):
    world = World(dataclasses.replace(WorldConfig(), wheel_encoders=cfg, camera=CameraConfig(enabled=False)),
                  seed=seed)
    world.reset(np.zeros(3))
    world.set_command((0.5, 0.2, 0.7))
    readings = [r for r in world.advance(int(seconds * 1e9)) if isinstance(r, WheelEncoderReading)]
    return world, readings


def test_positions_are_whole_counts_of_the_wheels_angles_at_jittered_intervals():
    cfg = WheelEncoderConfig(enabled=True)
    world, readings = _run(cfg)
    _, exact = _run(dataclasses.replace(cfg, resolution=0.0))
    counts = np.array([r.positions[0] for r in readings]) / cfg.resolution
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    angles = np.array([r.positions[0] for r in exact])  # the same schedule: its own random stream
    assert np.all((angles - counts * cfg.resolution >= -1e-12) & (angles - counts * cfg.resolution
                                                                    < cfg.resolution + 1e-12))
    # the angles are the integral of the wheel speeds (steady after the start)
    w = world.wheel_speeds[0]
    t = np.array([r.stamp_ns for r in exact]) * 1e-9
    late = t > 1.0
    rate = np.diff(angles[late], axis=0) / np.diff(t[late])[:, None]
    np.testing.assert_allclose(rate, np.broadcast_to(w, rate.shape), rtol=1e-9)
    dt_ms = np.diff([r.stamp_ns for r in readings]) / 1e6
    assert dt_ms.min() >= 16 and dt_ms.max() <= 41 and 19 < dt_ms.mean() < 21.5 and dt_ms.std() > 1
    np.testing.assert_allclose(readings[-1].velocities[0], w)


def test_the_truth_does_not_depend_on_the_encoders():
    on, _ = _run(WheelEncoderConfig(enabled=True), 1.0)
    off, _ = _run(WheelEncoderConfig(enabled=False), 1.0)
    np.testing.assert_array_equal(on.truth, off.truth)


def test_sim_parameters_refuse_two_sources_on_joint_states_and_bad_intervals():
    base = parameters_from_yaml(REPO / "config" / "sim.yaml", "sim_node")
    world, node = parse_parameters({**base, "wheel_encoders.publish_joint_states": True})
    assert world.wheel_encoders.enabled and len(node.driven_joint_names) == 4
    assert world.wheel_encoders.resolution == pytest.approx(2 * math.pi / 537.7, rel=1e-4)
    with pytest.raises(ParameterError, match="wheel_encoders.publish_joint_states"):
        parse_parameters({**base, "wheel_encoders.publish_joint_states": True,
                          "dead_wheels.publish_joint_states": True})
    with pytest.raises(ParameterError, match="wheel_encoders"):
        parse_parameters({**base, "wheel_encoders.publish_joint_states": True,
                          "wheel_encoders.max_interval": 0.01})


def test_driven_wheels_config_is_ekf_yaml_but_for_the_wheel_input():
    """config/ekf_driven_wheels.yaml follows config/ekf.yaml but for its input."""
    def rest(name: str) -> dict:
        values = parameters_from_yaml(REPO / "config" / name)
        return {k: v for k, v in values.items() if not k.startswith(("odom0", "joint0"))}

    assert rest("ekf_driven_wheels.yaml") == rest("ekf.yaml")
