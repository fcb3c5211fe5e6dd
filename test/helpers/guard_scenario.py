"""The blocked and the frozen robot (issue 34), ROS-free: truth and the messages config/ekf.yaml's
inputs and cmd_vel get, in stamp order (test_command_guard.py runs them through a Localizer,
test_command_guard_dds.py through ekf_node over DDS).

The robot starts at rest at localizer_scenario.START, heading START[2], and drives straight.
Its speed ramps toward the commanded one at the simulator's 2.88 m/s² (config/sim.yaml: wheel
acceleration 60 rad/s² x 0.048 m) while it follows its commands.

* ``blocked``: 0-2 s at rest (cmd 0, camera 30 Hz); 2-4 s cmd_vel 0.5 m/s but the wheels are
  blocked (dead wheels and IMU read 0, no camera image); 4-6 s the drive follows again.
* ``frozen``: 0-2 s at rest; 2-3 s driving at the commanded 0.5 m/s; 3-5 s the robot and its
  sensors are silent (the robot stands) while cmd_vel keeps arriving; 5-7 s the sensors
  return and the robot follows the command again from rest.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.measurements import ControlCommand
from helpers.localizer_scenario import START, T0, camera, imu, odometry

SEC = 1_000_000_000
MS = 1_000_000
ACCEL = 2.88  # m/s²
SPEED = 0.5  # m/s commanded
LATENCY_S = 0.02  # the drive acts 20 ms after a command's stamp (config/sim.yaml cmd_vel_latency)


@dataclass(frozen=True)
class Phase:
    start_s: float
    command: float  # commanded vx
    follows: bool  # the robot's speed ramps toward the command (else it stands)
    sensors: bool  # dead wheels and IMU publish
    camera: bool


SCENARIOS = {
    "blocked": (Phase(0.0, 0.0, True, True, True), Phase(2.0, SPEED, False, True, False),
                Phase(4.0, SPEED, True, True, True), Phase(6.0, SPEED, True, True, True)),
    "frozen": (Phase(0.0, 0.0, True, True, True), Phase(2.0, SPEED, True, True, True),
               Phase(3.0, SPEED, False, False, False), Phase(5.0, SPEED, True, True, True),
               Phase(7.0, SPEED, True, True, True)),
}
EVENT_S = {"blocked": 2.0, "frozen": 3.0}  # when the fault starts
RECOVER_S = {"blocked": 4.0, "frozen": 5.0}  # when it ends


@dataclass(frozen=True)
class Event:
    source: str  # odom0, imu0, pose0, cmd_vel
    measurement: object
    now_ns: int


def phase_at(name: str, t_s: float) -> Phase:
    phases = SCENARIOS[name]
    return [p for p in phases[:-1] if p.start_s <= t_s][-1]


def truths(name: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamps ns, [x y yaw v] per ms) of the truth over the scenario."""
    end = SCENARIOS[name][-1].start_s
    n = int(end * 1000) + 1
    t = T0 + np.arange(n, dtype=np.int64) * MS
    out = np.zeros((n, 4))
    s = v = 0.0
    for k in range(n):
        p, q = phase_at(name, k / 1000.0), phase_at(name, max(0.0, k / 1000.0 - LATENCY_S))
        if p.follows:
            v += float(np.clip(q.command - v, -ACCEL * 1e-3, ACCEL * 1e-3))
        else:
            v = 0.0
        out[k] = (START[0] + s * math.cos(START[2]), START[1] + s * math.sin(START[2]), START[2], v)
        s += v * 1e-3
    return t, out


def truth_at(truth: tuple[np.ndarray, np.ndarray], t_ns: int) -> np.ndarray:
    t, x = truth
    k = int(np.clip(round((t_ns - t[0]) / MS), 0, len(t) - 1))
    return x[k]


def events(name: str, seed: int = 0) -> Iterator[Event]:
    """Every message of the scenario, in stamp order: odom0 and imu0 at 100 Hz, pose0 at 33 Hz,
    cmd_vel at 50 Hz, each received at its stamp."""
    rng = np.random.default_rng(seed)
    truth = truths(name)
    end = SCENARIOS[name][-1].start_s
    for k in range(int(end * 100)):
        t = T0 + k * 10 * MS
        p = phase_at(name, k / 100.0)
        x, y, yaw, v = truth_at(truth, t)
        if k % 2 == 0:
            yield Event("cmd_vel", ControlCommand(t, np.array([p.command, 0, 0, 0, 0, 0.0])), t)
        if p.sensors:
            yield Event("odom0", odometry(t, v + rng.normal(0, 0.01), rng.normal(0, 0.01),
                                          rng.normal(0, 0.03)), t)
            yield Event("imu0", imu(t, yaw + rng.normal(0, 0.01), rng.normal(0, 0.01)), t)
        if p.camera and k % 3 == 0:
            yield Event("pose0", camera(t, x + rng.normal(0, 0.02), y + rng.normal(0, 0.02),
                                        yaw + rng.normal(0, 0.03)), t)
