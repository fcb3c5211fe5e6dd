"""Driving over a ramp (no ROS): the simulator's 3D truth, and the EKF with vs without tilt compensation.

The robot drives straight across a charge-station-like ramp with its dead wheels (as
JointState) and the IMU (yaw, yaw rate, roll, pitch); no camera, so nothing else corrects
the position. The same seed is run with the ramp and on level ground: the difference of the
final position errors is the error the ramp crossing adds.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers.ros_helpers import REPO

from ekf_localization.core.measurements import ImuMeasurement, JointStateMeasurement
from ekf_localization.core.tilt import horizontal_projection
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.models.sensors.dead_wheels import EncoderNoise
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import parameters_from_yaml
from sim_robot.world.camera_sensor import CameraConfig
from sim_robot.world.dead_wheel_sensor import DeadWheelConfig, DeadWheelReading
from sim_robot.world.imu_sensor import ImuReading
from sim_robot.world.ramp import Ramp
from sim_robot.world.world import TruthReading, World, WorldConfig

RAMP = Ramp(True, x_min=0.0, x_max=1.4, y_min=-1.5, y_max=0.5, slope=math.radians(15.0), flat_top_length=0.4)
START = np.array([-0.6, -0.5, 0.0])
SPEED = 0.6  # m/s along the surface
NAMES = ("left_pod", "right_pod", "lateral_pod")
BIG = 1e6
EXACT = dict(pose_variance_rate=(0.0, 0.0, 0.0), velocity_variance_per_step=(0.0, 0.0, 0.0),
             dead_wheels=DeadWheelConfig(noise=EncoderNoise(0.0, 1e-18)))
EPS = np.finfo(float).eps


def test_truth_moves_in_3d_and_the_encoders_measure_along_the_surface():
    world = World(WorldConfig(ramp=RAMP, camera=CameraConfig(enabled=False), **EXACT))
    world.reset(START)
    world.set_command((SPEED, 0.0, 0.0))
    world.advance(500_000_000)  # at speed, before the ramp
    wheels, samples = [], []
    for _ in range(350):
        for r in world.advance(10_000_000):
            if isinstance(r, DeadWheelReading):
                wheels.append(float(np.mean(r.distances[0, :2])))  # E_L, E_R: along the surface
            if isinstance(r, TruthReading):
                samples.append((r.truth[0, 0], *r.attitude[0]))
    x, z, roll, pitch = np.array(samples).T
    assert x[0] < RAMP.x_min and x[-1] > RAMP.x_max
    climbing = (x > RAMP.x_min + 0.05) & (x < RAMP.x_min + RAMP.run - 0.05)
    top = (x > RAMP.x_min + RAMP.run + 0.05) & (x < RAMP.x_max - RAMP.run - 0.05)
    descending = (x > RAMP.x_max - RAMP.run + 0.05) & (x < RAMP.x_max - 0.05)
    assert climbing.any() and top.any() and descending.any()
    np.testing.assert_allclose(pitch[climbing], -RAMP.slope, atol=1e-9)  # nose up
    np.testing.assert_allclose(pitch[descending], RAMP.slope, atol=1e-9)
    np.testing.assert_allclose(z[top], RAMP.height, atol=1e-9)
    np.testing.assert_allclose(z[climbing], (x[climbing] - RAMP.x_min) * math.tan(RAMP.slope), atol=1e-9)
    np.testing.assert_allclose(roll, 0.0, atol=1e-12)  # heading along the slope
    # horizontal travel = distance along the surface minus the slopes' extra length
    surface = wheels[-1] - wheels[0]
    excess = 2 * RAMP.run * (1 / math.cos(RAMP.slope) - 1)
    assert x[-1] - x[0] == pytest.approx(surface - excess, abs=2e-3)
    assert surface - (x[-1] - x[0]) > 0.8 * excess


def test_attitude_puts_the_body_z_axis_on_the_surface_normal():
    """At any heading ψ, R = Rz(ψ)·Ry(p)·Rx(r) of Ramp.attitude maps the body z axis to the
    surface normal (−∂z/∂x, 0, 1)/‖·‖; z is the trapezoid (climb, top, descent, 0 off the ramp)."""
    k, run = math.tan(RAMP.slope), RAMP.run  # climb on [0, 0.5], top to 0.9, descent to 1.4
    x = np.array([-0.1, 0.2, 0.45, 0.7, 1.2, 1.5, 0.2])
    y = np.array([0.0, -1.0, 0.0, 0.3, -0.2, 0.0, 0.6])  # the last one beside the ramp
    psi = np.linspace(-3.0, 3.0, x.size)
    z, roll, pitch = RAMP.attitude(np.column_stack([x, y, psi])).T
    # x − x_min, x_max − x: the inputs' rounding (≤ 2.2e-16 absolute) over 0.2, then one product
    heights = [0.0, 0.2 * k, 0.45 * k, run * k, 0.2 * k, 0.0, 0.0]
    np.testing.assert_allclose(z, heights, rtol=8 * EPS, atol=0.0)
    gradient = np.array([0.0, k, k, 0.0, -k, 0.0, 0.0])
    cr, sr, cp, sp, c, s = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(psi), np.sin(psi)
    body_z = np.column_stack([c * sp * cr + s * sr, s * sp * cr - c * sr, cp * cr])  # R's third column
    normal = np.column_stack([-gradient, np.zeros_like(x), np.ones_like(x)])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    np.testing.assert_allclose(body_z, normal, rtol=0.0, atol=16 * EPS)  # a few roundings of unit terms


def test_on_a_slope_the_pose_moves_by_the_horizontal_part_of_the_body_velocity():
    """One tick on the climb, heading diagonally (roll and pitch): eq. 22 with core.tilt's
    P(roll, pitch)·[vx vy wz]; one rounding of each pose component apart (4 ulps allowed)."""
    world = World(WorldConfig(ramp=RAMP, camera=CameraConfig(enabled=False), **EXACT))
    world.reset([0.2, -0.5, 0.6])
    world.set_command((0.5, 0.2, 0.3))
    world.step()  # the velocity is the command's; the pose moves from the next tick on
    before, attitude = world.truth[0], world.attitude[0]
    assert abs(attitude[1]) > 0.05 and abs(attitude[2]) > 0.05
    world.step()
    h = horizontal_projection(attitude[1], attitude[2]) @ before[3:]
    c, s, dt = math.cos(before[2]), math.sin(before[2]), 1e-3
    expected = before[:3] + dt * np.array([h[0] * c - h[1] * s, h[0] * s + h[1] * c, h[2]])
    np.testing.assert_allclose(world.truth[0, :3], expected, rtol=0.0, atol=4 * EPS * np.abs(expected).max())


def _config(tilt: bool):
    yaml_values = parameters_from_yaml(REPO / "config" / "ekf_joint_states.yaml", "ekf_node")
    values = {k: v for k, v in yaml_values.items() if not k.startswith("pose0")}
    values["imu0_config"] = [False, False, False, True, True, True, False, False, False,
                             False, False, True, False, False, False]
    values["joint0_tilt_compensation"] = tilt
    values["initial_state"] = [float(START[0]), float(START[1]), 0.0, 0.0, 0.0, float(START[2])] + [0.0] * 9
    return parse_ekf_config(values, MODELS)


def _imu(r: ImuReading) -> ImuMeasurement:
    tv = r.tilt_variance
    return ImuMeasurement(r.stamp_ns, "base_link", np.array([r.tilt[0, 0], r.tilt[0, 1], r.yaw[0]]),
                          np.diag([tv, tv, r.yaw_variance]), np.array([0.0, 0.0, r.yaw_rate[0]]),
                          np.diag([BIG, BIG, r.yaw_rate_variance]), np.zeros(3), np.eye(3))


def crossing(ramp: Ramp, seed: int) -> dict[str, tuple[np.ndarray, float]]:
    """Final (x, y) error and the largest published z, with and without compensation."""
    world = World(WorldConfig(ramp=ramp, camera=CameraConfig(enabled=False)), seed=seed)
    world.reset(START)
    world.set_command((SPEED, 0.0, 0.0))
    wr = world.config.dead_wheels.wheel_radius
    locs = {"with": make_localizer(_config(True)), "without": make_localizer(_config(False))}
    z_max = dict.fromkeys(locs, 0.0)
    for _ in range(400):  # 4 s: from x = -0.6 m across the ramp to about x = 1.7 m
        for r in world.advance(10_000_000):
            for loc in locs.values():
                if isinstance(r, DeadWheelReading):
                    js = JointStateMeasurement(r.stamp_ns, NAMES, r.distances[0] / wr)
                    assert not loc.add_measurement("joint0", js, r.stamp_ns).rejected
                elif isinstance(r, ImuReading):
                    loc.add_measurement("imu0", _imu(r), r.stamp_ns)
        for k, loc in locs.items():
            est = loc.advance_to(world.t_ns)
            if est is not None and est.extra:
                z_max[k] = max(z_max[k], dict((f, v) for f, v, _ in est.extra)[2])
    truth = world.truth[0]
    return {k: (loc.estimate_at(world.t_ns).state[:2] - truth[:2], z_max[k]) for k, loc in locs.items()}


@pytest.mark.parametrize("seed", [3, 4])
def test_tilt_compensation_removes_the_error_the_ramp_adds(seed: int, record_property) -> None:
    ramp = crossing(RAMP, seed)
    flat = crossing(dataclasses.replace(RAMP, enabled=False), seed)
    added = {k: float(np.linalg.norm(ramp[k][0] - flat[k][0])) for k in ramp}
    expected = 2 * RAMP.run * (1 / math.cos(RAMP.slope) - 1)  # the slopes' extra length
    print(f"\nseed {seed}: position error added by the ramp: without compensation "
          f"{added['without'] * 100:.2f} cm (slope excess {expected * 100:.2f} cm), "
          f"with {added['with'] * 100:.2f} cm; "
          f"ratio {added['without'] / added['with']:.1f}; published z max {ramp['with'][1]:.3f} m "
          f"(ramp height {RAMP.height:.3f} m)")
    record_property("added_without_m", float(added["without"]))
    record_property("added_with_m", float(added["with"]))
    assert added["without"] == pytest.approx(expected, rel=0.25)
    assert added["with"] * 5.0 <= added["without"]
    assert ramp["with"][1] == pytest.approx(RAMP.height, rel=0.1)
