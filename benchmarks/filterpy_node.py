"""A minimal EKF node on filterpy: bench_ekf_node's ``filterpy`` peer (run as a script).

    python benchmarks/filterpy_node.py

What any Python filter node has to do for ekf_node's stream, and nothing more: take every
message on ekf_node's topics (config/ekf.yaml's QoS and depths, /tf listened to), read the
fields the shipped config fuses (odometry twist vx vy vyaw, IMU yaw and yaw rate, camera x y
yaw) and the command, predict filterpy's ExtendedKalmanFilter to each message's stamp with
the shipped process model (config/ekf.yaml's drive response, as bench_localizer's peer) and
update it; every 20 ms publish nav_msgs/Odometry from a copy predicted to now; once a second
publish how many messages each input received on /diagnostics, as ekf_node does. It has no
validation, frames, lag handling, outputs on /tf or diagnostics beyond those counts: a floor
under what a filter node in Python costs, not a filter to run a robot on.
"""

from __future__ import annotations

import contextlib
import copy
import math
import sys
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from filterpy.kalman import ExtendedKalmanFilter
from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_localizer import shipped_config  # noqa: E402

from ekf_localization.models.registry import make_localizer  # noqa: E402
from ekf_localization.ros.node_runner import make_executor, spin_forever  # noqa: E402
from ekf_localization.ros.tf_io import TF_QOS, TF_TOPIC, tf_message_class  # noqa: E402

FIELDS = [0, 1, 5, 6, 7, 11]  # the state's robot_localization fields: x y yaw vx vy vyaw
H_TWIST, H_IMU, H_POSE = np.eye(6)[[3, 4, 5]], np.eye(6)[[2, 5]], np.eye(6)[[0, 1, 2]]


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _wrap_residual(index: int):
    def residual(a, b):
        y = a - b
        y[index] = math.remainder(y[index], math.tau)
        return y
    return residual


class FilterpyNode(Node):
    def __init__(self) -> None:
        super().__init__("filterpy_node")
        config = shipped_config()
        self.model = make_localizer(config).model
        self.ekf = ExtendedKalmanFilter(dim_x=6, dim_z=3)
        self.ekf.x = np.asarray(config.initial_state, dtype=float)[FIELDS]
        self.ekf.P = np.asarray(config.initial_estimate_covariance, dtype=float)[np.ix_(FIELDS, FIELDS)]
        self.t_ns: int | None = None
        self.u: np.ndarray | None = None
        self.received = {"odom0": 0, "imu0": 0, "pose0": 0, "cmd_vel": 0}
        self.yaw_residual, self.pose_residual = _wrap_residual(0), _wrap_residual(2)
        qos = {}
        for depth in (5, 10, 50):  # bench_ekf_node.INPUTS' depths, config/ekf.yaml's
            qos[depth] = copy.copy(qos_profile_sensor_data)
            qos[depth].depth = depth
        self.create_subscription(Odometry, "odometry/dead_wheels", self._on_odom, qos[50])
        self.create_subscription(Imu, "imu/data", self._on_imu, qos[50])
        self.create_subscription(PoseWithCovarianceStamped, "camera/pose", self._on_pose, qos[10])
        self.create_subscription(TwistStamped, "cmd_vel", self._on_cmd, qos[5])
        self.create_subscription(tf_message_class(), TF_TOPIC, lambda _msg: None, TF_QOS)
        self.out = self.create_publisher(Odometry, "odometry/filtered", 10)
        self.diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(0.02, self._publish)
        self.create_timer(1.0, self._publish_counts)

    def _predict(self, x: np.ndarray, P: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        U = None if self.u is None else self.u[None]
        X, F = self.model.f_and_jacobian(x[None], U, dt)
        Q = np.asarray(self.model.noise(x[None], U, dt)).reshape(6, 6)
        return X[0], F[0] @ P @ F[0].T + Q

    def _predict_to(self, stamp: int) -> None:
        if self.t_ns is not None and stamp > self.t_ns:
            self.ekf.x, self.ekf.P = self._predict(self.ekf.x, self.ekf.P, (stamp - self.t_ns) / 1e9)
        self.t_ns = stamp if self.t_ns is None else max(self.t_ns, stamp)

    def _update(self, z: np.ndarray, R: np.ndarray, H: np.ndarray, residual=np.subtract) -> None:
        self.ekf.update(z, lambda _x: H, lambda x: H @ x, R=R, residual=residual)

    def _on_odom(self, msg: Odometry) -> None:
        self.received["odom0"] += 1
        self._predict_to(_stamp(msg))
        t, c = msg.twist.twist, msg.twist.covariance
        self._update(np.array([t.linear.x, t.linear.y, t.angular.z]),
                     np.array([[c[0], c[1], c[5]], [c[6], c[7], c[11]], [c[30], c[31], c[35]]]), H_TWIST)

    def _on_imu(self, msg: Imu) -> None:
        self.received["imu0"] += 1
        self._predict_to(_stamp(msg))
        self._update(np.array([_yaw(msg.orientation), msg.angular_velocity.z]),
                     np.diag([msg.orientation_covariance[8], msg.angular_velocity_covariance[8]]), H_IMU,
                     self.yaw_residual)

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self.received["pose0"] += 1
        self._predict_to(_stamp(msg))
        p, c = msg.pose.pose, msg.pose.covariance
        self._update(np.array([p.position.x, p.position.y, _yaw(p.orientation)]),
                     np.array([[c[0], c[1], c[5]], [c[6], c[7], c[11]], [c[30], c[31], c[35]]]), H_POSE,
                     self.pose_residual)

    def _on_cmd(self, msg: TwistStamped) -> None:
        self.received["cmd_vel"] += 1
        t = msg.twist
        self.u = np.array([t.linear.x, t.linear.y, t.angular.z])

    def _publish(self) -> None:
        if self.t_ns is None:
            return
        now = self.get_clock().now()
        x, P = self.ekf.x, self.ekf.P
        if now.nanoseconds > self.t_ns:
            x, P = self._predict(x, P, (now.nanoseconds - self.t_ns) / 1e9)
        msg = Odometry()
        msg.header.stamp = now.to_msg()
        msg.header.frame_id, msg.child_frame_id = "map", "base_link"
        pose, twist = msg.pose.pose, msg.twist.twist
        pose.position.x, pose.position.y = float(x[0]), float(x[1])
        pose.orientation.z, pose.orientation.w = math.sin(x[2] / 2.0), math.cos(x[2] / 2.0)
        twist.linear.x, twist.linear.y, twist.angular.z = float(x[3]), float(x[4]), float(x[5])
        cov = np.zeros((6, 6))
        cov[np.ix_([0, 1, 5], [0, 1, 5])] = P[:3, :3]
        msg.pose.covariance = cov.ravel().tolist()
        cov[np.ix_([0, 1, 5], [0, 1, 5])] = P[3:, 3:]
        msg.twist.covariance = cov.ravel().tolist()
        self.out.publish(msg)

    def _publish_counts(self) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [DiagnosticStatus(name=f"filterpy_node: {name}",
                                       values=[KeyValue(key="received", value=str(n))])
                      for name, n in self.received.items()]
        self.diag.publish(msg)


def main() -> int:
    rclpy.init()
    node = FilterpyNode()
    ex = make_executor()
    ex.add_node(node)
    with contextlib.suppress(KeyboardInterrupt, ExternalShutdownException):
        spin_forever(ex)
    return 0


if __name__ == "__main__":
    sys.exit(main())
