"""A ROS-free drive for Localizer tests: truth, the messages config/ekf.yaml's inputs get, the
filter config (``ekf_config``) and a feeder that publishes as ekf_node's timer would (``run``).

The robot drives a circle (0.4 m/s, 0.3 rad/s) in the map frame; dead-wheel twists (odom0,
100 Hz), camera poses (pose0, 30 Hz, map) and IMU yaw and yaw rate (imu0, 100 Hz) carry
seeded noise, and each message arrives at its own stamp (the receiver's clock).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.measurements import ImuMeasurement, OdometryMeasurement, PoseMeasurement
from ekf_localization.core.units import NS_PER_S
from ekf_localization.models.registry import MODELS
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import parameters_from_yaml
from helpers.ros_helpers import REPO

SEC = NS_PER_S
SPEED, YAW_RATE = 0.4, 0.3
START = (0.5, -0.3, 0.2)
T0 = 5 * SEC  # the clock at the start of the drive


def truth_at(t_ns: int) -> np.ndarray:
    """[x y yaw vx vy vyaw] (body velocities) at ``t_ns``."""
    t = (t_ns - T0) / SEC
    yaw = START[2] + YAW_RATE * t
    r = SPEED / YAW_RATE
    x = START[0] + r * (math.sin(yaw) - math.sin(START[2]))
    y = START[1] - r * (math.cos(yaw) - math.cos(START[2]))
    return np.array([x, y, wrap_angle(yaw), SPEED, 0.0, YAW_RATE])


@dataclass(frozen=True)
class Event:
    source: str  # odom0, pose0, imu0
    measurement: object
    now_ns: int


def odometry(t_ns: int, vx: float, vy: float, wz: float) -> OdometryMeasurement:
    return OdometryMeasurement(t_ns, "odom", "base_link", np.zeros(6), np.eye(6),
                               np.array([vx, vy, 0.0, 0.0, 0.0, wz]),
                               np.diag([1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-3]))


def camera(t_ns: int, x: float, y: float, yaw: float) -> PoseMeasurement:
    return PoseMeasurement(t_ns, "map", np.array([x, y, 0.0, 0.0, 0.0, yaw]),
                           np.diag([4e-4, 4e-4, 1e-6, 1e-6, 1e-6, 1e-3]))


def imu(t_ns: int, yaw: float, wz: float) -> ImuMeasurement:
    return ImuMeasurement(t_ns, "base_link", np.array([0.0, 0.0, yaw]), np.diag([1e-3, 1e-3, 1e-3]),
                          np.array([0.0, 0.0, wz]), np.diag([1e-4, 1e-4, 1e-4]),
                          np.zeros(3), -np.eye(3))


def drive(seconds: float, seed: int = 0, start_ns: int = T0) -> Iterator[Event]:
    """Every message of ``seconds`` of driving from ``start_ns``, in stamp order."""
    rng = np.random.default_rng(seed)
    step = 10_000_000
    for k in range(int(seconds * SEC) // step):
        t = start_ns + k * step
        x, y, yaw, vx, vy, wz = truth_at(t)
        yield Event("odom0", odometry(t, vx + rng.normal(0, 0.01), vy + rng.normal(0, 0.01),
                                      wz + rng.normal(0, 0.03)), t)
        yield Event("imu0", imu(t, yaw + rng.normal(0, 0.01), wz + rng.normal(0, 0.01)), t)
        if k % 3 == 0:
            yield Event("pose0", camera(t, x + rng.normal(0, 0.02), y + rng.normal(0, 0.02),
                                        yaw + rng.normal(0, 0.03)), t)


def position_error(est, t_ns: int | None = None) -> float:
    truth = truth_at(est.stamp_ns if t_ns is None else t_ns)
    return float(math.hypot(est.state[0] - truth[0], est.state[1] - truth[1]))


def ekf_config(**overrides):
    values = parameters_from_yaml(REPO / "config" / "ekf.yaml")
    values["initial_state"] = [START[0], START[1], 0.0, 0.0, 0.0, START[2]] + [0.0] * 9
    values.update(overrides)
    return parse_ekf_config(values, MODELS)


def run(loc, events, outputs: list | None = None) -> None:
    """Feed events; publish at 50 Hz of clock time as ekf_node's timer would."""
    next_out = None
    for ev in events:
        if outputs is not None:
            next_out = ev.now_ns if next_out is None else next_out
            while next_out <= ev.now_ns:
                est = loc.advance_to(next_out)
                if est is not None:
                    outputs.append(est)
                next_out += 20_000_000
        if hasattr(ev.measurement, "parts") or isinstance(ev.measurement, PoseMeasurement):
            loc.add_measurement(ev.source, ev.measurement, ev.now_ns)
