"""A deterministic mecanum drive with dead-wheel twist, lagged camera poses, IMU and commands,
and the filter parameters that fuse it (``config``).

Shared by the fusion unit tests and the ekf_node integration tests (whose publisher process,
helpers/ekf_node_feeder.py, imports it). SI units, integer-nanosecond stamps. The truth is
integrated at 1 kHz with eq. 22 of seed 000; its body velocity is the command plus a slow
disturbance (so the command alone is not the truth and the odometry matters).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.measurements import (
    ControlCommand,
    ImuMeasurement,
    OdometryMeasurement,
    PoseMeasurement,
)
from ekf_localization.models.registry import MODELS
from ekf_localization.ros.ekf_parameters import parse_ekf_config

TICK_NS = 1_000_000
MS = 1_000_000


@dataclass
class Scenario:
    t_ns: np.ndarray  # (K,) truth times, every millisecond from start_ns
    truth: np.ndarray  # (K, 6) [x y yaw vx vy wz], body velocities
    command: np.ndarray  # (K, 3) commanded body twist [vx vy wz]
    odom_idx: np.ndarray  # truth indices of odometry samples
    odom: np.ndarray  # (M, 3) measured body twist
    odom_std: np.ndarray  # (3,)
    camera_idx: np.ndarray
    camera: np.ndarray  # (C, 3) measured x y yaw
    camera_std: np.ndarray
    camera_latency_ns: int
    imu_idx: np.ndarray
    imu: np.ndarray  # (I,) measured yaw rate
    imu_std: float
    command_period_ns: int

    def truth_at(self, t_ns: int) -> np.ndarray:
        """Truth at a stamp (nearest millisecond at or before it)."""
        i = int(np.clip((t_ns - self.t_ns[0]) // TICK_NS, 0, len(self.t_ns) - 1))
        return self.truth[i]

    def odometry(self, j: int, frame: str = "odom", child: str = "base_link") -> OdometryMeasurement:
        tw = np.zeros(6)
        tw[[0, 1, 5]] = self.odom[j]
        cov = np.diag(np.r_[self.odom_std[:2] ** 2, 1e-6, 1e-6, 1e-6, self.odom_std[2] ** 2])
        return OdometryMeasurement(int(self.t_ns[self.odom_idx[j]]), frame, child, np.zeros(6),
                                   np.eye(6), tw, cov)

    def camera_pose(self, j: int, frame: str = "map") -> PoseMeasurement:
        p = np.zeros(6)
        p[[0, 1, 5]] = self.camera[j]
        cov = np.diag(np.r_[self.camera_std[:2] ** 2, 1e-6, 1e-6, 1e-6, self.camera_std[2] ** 2])
        return PoseMeasurement(int(self.t_ns[self.camera_idx[j]]), frame, p, cov)

    def imu_sample(self, j: int, frame: str = "base_link") -> ImuMeasurement:
        no = -np.eye(3)  # sensor_msgs/Imu: covariance[0] = -1 means "not provided"
        return ImuMeasurement(int(self.t_ns[self.imu_idx[j]]), frame, np.zeros(3), no,
                              np.array([0.0, 0.0, self.imu[j]]), np.diag([1e-6, 1e-6, self.imu_std ** 2]),
                              np.zeros(3), no)

    def control(self, k: int) -> ControlCommand:
        tw = np.zeros(6)
        tw[[0, 1, 5]] = self.command[k]
        return ControlCommand(int(self.t_ns[k]), tw)

    def events(self, with_control: bool = True) -> list[tuple[int, str, int]]:
        """(arrival ns, source, index) in arrival order; camera poses arrive after their latency.

        Sources: "odom0", "pose0", "imu0", "cmd_vel" (index into the truth arrays).
        """
        ev = [(int(self.t_ns[i]), "odom0", j) for j, i in enumerate(self.odom_idx)]
        lag = self.camera_latency_ns
        ev += [(int(self.t_ns[i]) + lag, "pose0", j) for j, i in enumerate(self.camera_idx)]
        ev += [(int(self.t_ns[i]), "imu0", j) for j, i in enumerate(self.imu_idx)]
        if with_control:
            step = self.command_period_ns // TICK_NS
            ev += [(int(self.t_ns[k]), "cmd_vel", k) for k in range(0, len(self.t_ns), step)]
        order = {"cmd_vel": 0, "imu0": 1, "odom0": 2, "pose0": 3}
        return sorted(ev, key=lambda e: (e[0], order[e[1]], e[2]))

    def item(self, source: str, index: int):
        return {"odom0": self.odometry, "pose0": self.camera_pose, "imu0": self.imu_sample,
                "cmd_vel": self.control}[source](index)


def make_scenario(duration_s: float = 6.0, seed: int = 0, start_ns: int = 5_000_000_000,
                  odom_period_ns: int = 5 * MS, camera_period_ns: int = 100 * MS,
                  camera_latency_ns: int = 80 * MS, imu_period_ns: int = 10 * MS,
                  command_period_ns: int = 20 * MS, odom_bias: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  speed: float = 1.0) -> Scenario:
    rng = np.random.default_rng(seed)
    K = int(round(duration_s * 1000)) + 1
    t = start_ns + TICK_NS * np.arange(K, dtype=np.int64)
    ts = (t - start_ns) / 1e9
    cmd = np.stack([speed * (0.6 + 0.3 * np.sin(0.7 * ts)), speed * 0.3 * np.sin(0.4 * ts + 0.5),
                    0.8 * np.sin(0.5 * ts)], axis=1)
    # the command is held for command_period_ns (what a controller publishing at that rate does)
    step = command_period_ns // TICK_NS
    cmd = cmd[(np.arange(K) // step) * step]
    disturbance = np.stack([0.05 * np.sin(1.3 * ts + 1.0), 0.04 * np.sin(0.9 * ts),
                            0.05 * np.sin(1.1 * ts)], axis=1)
    vel = cmd + disturbance
    truth = np.zeros((K, 6))
    truth[0, :3] = (0.5, -0.3, 0.2)
    truth[:, 3:] = vel
    dt = TICK_NS / 1e9
    for k in range(1, K):  # seed 000 eq. 22 with the previous body velocity
        x, y, th = truth[k - 1, :3]
        vx, vy, wz = truth[k - 1, 3:]
        c, s = np.cos(th), np.sin(th)
        truth[k, 0] = x + dt * (vx * c - vy * s)
        truth[k, 1] = y + dt * (vx * s + vy * c)
        truth[k, 2] = th + dt * wz
    truth[:, 2] = wrap_angles(truth[:, 2])
    odom_idx = np.arange(0, K, odom_period_ns // TICK_NS)[1:]
    odom_std = np.array([0.02, 0.02, 0.03])
    odom = vel[odom_idx] + np.asarray(odom_bias) + rng.normal(0.0, odom_std, (len(odom_idx), 3))
    cam_idx = np.arange(0, K, camera_period_ns // TICK_NS)[1:]
    cam_std = np.array([0.015, 0.015, 0.02])
    cam = truth[cam_idx][:, :3] + rng.normal(0.0, cam_std, (len(cam_idx), 3))
    cam[:, 2] = wrap_angles(cam[:, 2])
    imu_idx = np.arange(0, K, imu_period_ns // TICK_NS)[1:]
    imu_std = 0.01
    imu = vel[imu_idx, 2] + rng.normal(0.0, imu_std, len(imu_idx))
    return Scenario(t, truth, cmd, odom_idx, odom, odom_std, cam_idx, cam, cam_std, camera_latency_ns,
                    imu_idx, imu, imu_std, command_period_ns)


F15 = [False] * 15


def fuse(*fields: int) -> list[bool]:
    v = F15.copy()
    for f in fields:
        v[f] = True
    return v


def process_noise(pose: float = 1e-5, velocity: float = 0.05) -> list[float]:
    d = np.full(15, 0.01)
    d[[0, 1, 5]] = pose
    d[[6, 7, 11]] = velocity
    return [float(x) for x in np.diag(d).ravel()]


def config(**overrides):
    v = {"process_noise_covariance": process_noise(),
         "odom0": "odometry/dead_wheels", "odom0_config": fuse(6, 7, 11),
         "pose0": "camera/pose", "pose0_config": fuse(0, 1, 5), "pose0_rejection_threshold": 6.0,
         "imu0": "imu/data", "imu0_config": fuse(11), "world_frame": "map", "use_control": True,
         "frequency": 50.0, "history_length": 0.5,
         # the odometry here is biased by design, which control_guard rightly reads as a drive
         # not following its commands (test_command_guard.py tests the guard)
         "control_guard": False}
    v.update(overrides)
    return parse_ekf_config(v, MODELS)
