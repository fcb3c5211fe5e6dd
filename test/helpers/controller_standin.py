"""Stand-ins for ros2_controllers' mecanum_drive_controller and diff_drive_controller (Jazzy):
rclpy nodes with the controllers' names that publish exactly their odometry and TF, from a
simulated drive that follows the commands they take.

What each publishes, as the controllers do with their default parameters:

* ``mecanum_drive_controller``: ``~/odometry`` (nav_msgs/Odometry, odom -> base_link, body
  twist vx vy vyaw, pose and twist covariance a fixed 0.1 diagonal) and ``~/tf_odometry``
  (tf2_msgs/TFMessage, odom -> base_link) on every update; it takes ``~/reference``
  (geometry_msgs/TwistStamped).
* ``diff_drive_controller``: ``~/odom`` (vx and vyaw, all-zero covariances) and ``/tf``
  (odom -> base_link) at ``publish_rate`` (50 Hz); it takes ``~/cmd_vel`` (TwistStamped).

The drive: each axis follows the last command (held for the controller's timeout, then zero)
through a first-order lag ``tau``, and reaches ``gain`` times it (a drive under load). The
wheels measure the true body twist with Gaussian noise of covariance ``twist_variance`` (the
one the config declares); the controller integrates the measured twist into its odometry
pose, as the real ones do. Everything is stamped with the node's clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Controller:
    """One controller's topics and habits."""

    name: str  # its node name (the controller's name in controller_manager)
    odometry_topic: str
    tf_topic: str
    command_topic: str
    placeholder_variance: float  # the diagonal of the covariances it publishes
    holonomic: bool  # vy measured and commanded
    publish_every: int  # updates per odometry/TF message
    command_timeout: float  # s: reference_timeout / cmd_vel_timeout


MECANUM = Controller("mecanum_drive_controller", "~/odometry", "~/tf_odometry", "~/reference", 0.1, True, 1,
                     0.5)
DIFF = Controller("diff_drive_controller", "~/odom", "/tf", "~/cmd_vel", 0.0, False, 2, 0.5)
UPDATE_RATE = 100.0  # Hz, controller_manager's update_rate


def make_standin(context, c: Controller, twist_variance: np.ndarray, tau: np.ndarray, gain: float,
                 seed: int, cli_args: list[str] | None = None):
    """The stand-in node for ``c`` (``cli_args``: its ROS arguments, e.g. a remap)."""
    from geometry_msgs.msg import TransformStamped, TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from tf2_msgs.msg import TFMessage

    class StandIn(Node):
        def __init__(self) -> None:
            super().__init__(c.name, context=context, cli_args=cli_args, use_global_arguments=False)
            self.rng = np.random.default_rng(seed)
            self.noise_std = np.sqrt(np.asarray(twist_variance, dtype=float))  # vx vy vyaw
            self.tau = np.asarray(tau, dtype=float)
            self.v = np.zeros(3)  # true body twist vx vy vyaw
            self.truth = np.zeros(3)  # true x y yaw (odom = map at the start)
            self.odom = np.zeros(3)  # the controller's integrated pose
            self.command = np.zeros(3)
            self.command_ns: int | None = None
            self.truth_log: list[tuple[int, float, float, float]] = []
            self.odom_log: list[tuple[int, float, float, float]] = []
            self.tf_sent: list[int] = []
            self.last_ns: int | None = None
            self.ticks = 0
            self.running = False
            self.odom_pub = self.create_publisher(Odometry, c.odometry_topic, 10)
            self.tf_pub = self.create_publisher(TFMessage, c.tf_topic, 10)
            self.create_subscription(TwistStamped, c.command_topic, self._on_command, 10)
            self.create_timer(1.0 / UPDATE_RATE, self._update)
            self._Odometry, self._Transform, self._TFMessage = Odometry, TransformStamped, TFMessage

        def _on_command(self, msg) -> None:
            self.command = np.array([msg.twist.linear.x, msg.twist.linear.y if c.holonomic else 0.0,
                                     msg.twist.angular.z])
            self.command_ns = self.get_clock().now().nanoseconds

        def _update(self) -> None:
            now = self.get_clock().now()
            t = now.nanoseconds
            if not self.running:
                self.last_ns = t
                return
            dt = (t - self.last_ns) * 1e-9
            self.last_ns = t
            fresh = self.command_ns is not None and (t - self.command_ns) * 1e-9 <= c.command_timeout
            target = gain * self.command if fresh else np.zeros(3)
            alpha = np.where(self.tau > 0.0, 1.0 - np.exp(-dt / np.maximum(self.tau, 1e-9)), 1.0)
            v0 = self.v.copy()
            self.v = self.v + alpha * (target - self.v)
            _integrate(self.truth, 0.5 * (v0 + self.v), dt)
            measured = self.v + self.rng.normal(0.0, 1.0, 3) * self.noise_std
            if not c.holonomic:
                measured[1] = 0.0
            _integrate(self.odom, measured, dt)
            self.truth_log.append((t, *self.truth))
            self.ticks += 1
            if self.ticks % c.publish_every:
                return
            self.odom_log.append((t, *self.odom))
            stamp = now.to_msg()
            qz, qw = math.sin(0.5 * self.odom[2]), math.cos(0.5 * self.odom[2])
            msg = self._Odometry()
            msg.header.stamp, msg.header.frame_id, msg.child_frame_id = stamp, "odom", "base_link"
            msg.pose.pose.position.x, msg.pose.pose.position.y = float(self.odom[0]), float(self.odom[1])
            msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = qz, qw
            msg.twist.twist.linear.x, msg.twist.twist.linear.y = float(measured[0]), float(measured[1])
            msg.twist.twist.angular.z = float(measured[2])
            diagonal = [c.placeholder_variance if i % 7 == 0 else 0.0 for i in range(36)]
            msg.pose.covariance, msg.twist.covariance = diagonal, diagonal
            self.odom_pub.publish(msg)
            tf = self._Transform()
            tf.header.stamp, tf.header.frame_id, tf.child_frame_id = stamp, "odom", "base_link"
            tf.transform.translation.x, tf.transform.translation.y = float(self.odom[0]), float(self.odom[1])
            tf.transform.rotation.z, tf.transform.rotation.w = qz, qw
            self.tf_pub.publish(self._TFMessage(transforms=[tf]))
            self.tf_sent.append(t)

    return StandIn()


def _integrate(pose: np.ndarray, v: np.ndarray, dt: float) -> None:
    """``pose`` (x, y, yaw) moved by body twist ``v`` for ``dt``, rotated by the mid-step heading."""
    mid = pose[2] + 0.5 * v[2] * dt
    cy, sy = math.cos(mid), math.sin(mid)
    pose[0] += (cy * v[0] - sy * v[1]) * dt
    pose[1] += (sy * v[0] + cy * v[1]) * dt
    pose[2] += v[2] * dt


def truth_at(log: list[tuple[int, float, float, float]], t_ns: int) -> np.ndarray | None:
    """The logged (x, y, yaw) at ``t_ns``, linearly between samples (None outside the log)."""
    stamps = np.array([r[0] for r in log])
    if len(stamps) < 2 or t_ns < stamps[0] or t_ns > stamps[-1]:
        return None
    k = int(np.searchsorted(stamps, t_ns))
    if stamps[k] == t_ns:
        return np.array(log[k][1:])
    a, b = np.array(log[k - 1][1:]), np.array(log[k][1:])
    w = (t_ns - stamps[k - 1]) / (stamps[k] - stamps[k - 1])
    d = b - a
    d[2] = math.remainder(d[2], math.tau)
    return a + w * d
