"""pure_pursuit_node: follows a path with the ROS-free pure-pursuit follower.

Subscribes
  ``odometry/filtered`` (nav_msgs/Odometry; ``odom_topic`` to follow ``ground_truth/odom`` or
  ``odometry/dead_wheels`` instead), reliable, depth 10: the robot's pose in the path's frame;
  ``pure_pursuit/path_in`` (nav_msgs/Path): replaces the path at run time.
Publishes
  ``cmd_vel`` (geometry_msgs/Twist, or TwistStamped with ``stamped_cmd_vel``; body frame,
  REP-103) every control tick;
  ``pure_pursuit/target`` (geometry_msgs/PointStamped, path frame);
  ``pure_pursuit/progress`` (std_msgs/Float64, distance along the path, m);
  ``pure_pursuit/done`` (std_msgs/Bool, transient local);
  ``pure_pursuit/path`` (nav_msgs/Path, transient local);
  ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, 1 Hz);
  ``pure_pursuit/markers`` (visualization_msgs/MarkerArray, with ``publish_markers``): the path,
  the lookahead circle and the target point of the follower's last step, at ``marker_frequency``
  on the steady clock.

The control loop runs at ``frequency`` on the node clock (sim time with use_sim_time). It
commands a zero twist before the first odometry, once the path is done, and whenever no
odometry was *accepted* for ``odom_timeout`` (received on the node clock) or the accepted
pose is older than that: diagnostics then say why (WARN; ERROR while odometry arrives but
every message is rejected, naming the reasons). The node clock jumping backwards (a
simulator restart, a bag loop) resets the follower: path from the start, odometry history
cleared. Odometry with a non-finite pose, a bad quaternion or covariance, a frame other than
the path's (or ``accepted_odom_frames``), a stale, future or repeated stamp is rejected and
counted in diagnostics. Parameters: docs/pure_pursuit.md;
a bad value stops the node at start-up (exit code 2) with a message naming it.
"""

from __future__ import annotations

import math
import sys
from collections import Counter
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PointStamped, PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool, Float64

from ekf_localization.control.field_path import FieldPath, PathError
from ekf_localization.control.pure_pursuit import ZERO, Command, PurePursuitFollower
from ekf_localization.core.angles import quaternion_to_yaw, yaw_to_quaternion
from ekf_localization.core.ellipse import circle_points
from ekf_localization.core.linalg import is_symmetric
from ekf_localization.core.units import ns_to_sec_nanosec, ns_to_seconds, stamp_to_ns
from ekf_localization.ros import markers
from ekf_localization.ros.due_timer import create_due_timer
from ekf_localization.ros.node_parameters import declare_unset, given_values, refuse_changes
from ekf_localization.ros.node_runner import run_node
from ekf_localization.ros.pure_pursuit_parameters import NODE_NAME, PURE_PURSUIT_PARAMETERS, parse_settings
from ekf_localization.ros.throttled_log import ThrottledLog


# -- message checks / conversions (plain functions on duck-typed messages) ----------------------
def odometry_problem(msg, accepted_frames: frozenset[str], now_ns: int, last_ns: int | None,
                     timeout_ns: int) -> str | None:
    """Why an odometry message cannot be used (a short reason), or None."""
    if msg.header.frame_id.lstrip("/") not in accepted_frames:
        return "wrong_frame"
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    if not all(math.isfinite(a) for a in (p.x, p.y, q.x, q.y, q.z, q.w)):
        return "non_finite"
    if not math.hypot(q.x, q.y, q.z, q.w) > 1e-6:  # (norm² > 1e-12): no orientation
        return "bad_quaternion"
    cov = msg.pose.covariance
    if not all(math.isfinite(c) for c in cov):
        return "non_finite"
    if any(cov[7 * i] < 0.0 for i in range(6)) or not is_symmetric(np.reshape(cov, (6, 6))):
        return "bad_covariance"
    t = stamp_to_ns(msg.header.stamp)
    if now_ns > 0:  # no clock yet (sim time before the first /clock): no age check
        if t < now_ns - timeout_ns:
            return "stale_stamp"
        if t > now_ns + timeout_ns:
            return "future_stamp"
    if last_ns is not None and t <= last_ns:
        return "repeated_stamp"
    return None


def path_from_message(msg, accepted_frames: frozenset[str]) -> FieldPath:
    """nav_msgs/Path -> FieldPath. Orientations count as headings unless all are identity."""
    frame = msg.header.frame_id.lstrip("/")
    if frame not in accepted_frames:
        raise PathError(f"frame_id {frame!r} is not one of {sorted(accepted_frames)}")
    xs, ys, quats = [], [], []
    for i, ps in enumerate(msg.poses):
        p, q = ps.pose.position, ps.pose.orientation
        if not all(math.isfinite(a) for a in (p.x, p.y, q.x, q.y, q.z, q.w)):
            raise PathError(f"poses[{i}]: non-finite value")
        xs.append(p.x)
        ys.append(p.y)
        quats.append((q.x, q.y, q.z, q.w))
    identity = all(q == (0.0, 0.0, 0.0, 1.0) for q in quats)
    if not identity and any(not (sum(c * c for c in q) > 1e-12) for q in quats):
        raise PathError("a pose has an all-zero quaternion")
    headings = None if identity else [quaternion_to_yaw(*q) for q in quats]
    return FieldPath.from_poses(xs, ys, headings, frame_id=frame, name="path_in")


class PurePursuitNode(Node):
    """Thin adapter around :class:`PurePursuitFollower` (module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings = parse_settings(given_values(self))
        declare_unset(self, PURE_PURSUIT_PARAMETERS, PURE_PURSUIT_PARAMETERS.defaults())
        refuse_changes(self, PURE_PURSUIT_PARAMETERS)
        s = self.settings
        self._throttled = ThrottledLog(self.get_logger())  # warnings on the odometry and tick paths
        self.follower = PurePursuitFollower(s.path, s.follower)
        self._pose: tuple[float, float, float, int] | None = None  # x, y, yaw, stamp_ns
        self._followed: tuple[float, float, float, int] | None = None  # the pose of the follower's last step
        self._cmd = ZERO
        self._rejected: Counter[str] = Counter()
        self._received = 0
        self._stale_ticks = 0
        self._accepted_at_ns: int | None = None  # node clock when odometry was last accepted
        self._clock_ns: int | None = None  # newest node clock seen (time-jump detection)
        self._time_jumps = 0
        self._diag_prev = (0, Counter())  # (received, rejected) at the previous diagnostics
        self._paths_in = Counter()

        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        self._pub_cmd = self.create_publisher(TwistStamped if s.stamped_cmd_vel else Twist, "cmd_vel", 10)
        self._pub_target = self.create_publisher(PointStamped, "pure_pursuit/target", 10)
        self._pub_progress = self.create_publisher(Float64, "pure_pursuit/progress", 10)
        self._pub_done = self.create_publisher(Bool, "pure_pursuit/done", latched)
        self._pub_path = self.create_publisher(PathMsg, "pure_pursuit/path", latched)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Odometry, s.odom_topic, self._on_odometry,
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(PathMsg, "pure_pursuit/path_in", self._on_path, 10)
        create_due_timer(self, 1.0 / s.frequency, self._on_tick)  # ros/due_timer.py: events + sim time
        create_due_timer(self, 1.0, self._publish_diagnostics)
        self._marker_pub = None
        if s.publish_markers:
            from visualization_msgs.msg import MarkerArray

            self._marker_pub = self.create_publisher(MarkerArray, markers.PURE_PURSUIT_MARKER_TOPIC, 1)
            create_due_timer(self, 1.0 / s.marker_frequency, self._publish_markers,
                             clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._publish_path()
        self._publish_done(False)
        self.get_logger().info(
            f"following {s.path!r} in {s.follower.mode} mode at {s.frequency:g} Hz from {s.odom_topic}")

    # -- input -------------------------------------------------------------------------------
    def _now_ns(self) -> int:
        """The node clock; a jump backwards resets the follower first."""
        now = self.get_clock().now().nanoseconds
        if self._clock_ns is not None and now < self._clock_ns:
            self._on_time_jump(self._clock_ns - now)
        self._clock_ns = now
        return now

    def _on_time_jump(self, back_ns: int) -> None:
        self._time_jumps += 1
        self.get_logger().warning(f"time jumped back by {ns_to_seconds(back_ns):.3f} s (simulator restart "
                                  "or bag loop?): follower reset, path from the start")
        self.follower.reset()
        self._pose = None
        self._followed = None
        self._accepted_at_ns = None
        self._cmd = ZERO
        self._publish_done(False)

    def _stale_for_ns(self, now: int) -> int:
        """How long past ``odom_timeout`` the control input is (> 0: stale), given a pose."""
        timeout = self.settings.odom_timeout_ns
        return max(now - self._pose[3], now - self._accepted_at_ns) - timeout

    def _on_odometry(self, msg: Odometry) -> None:
        self._received += 1
        s = self.settings
        now = self._now_ns()
        last = self._pose[3] if self._pose else None
        reason = odometry_problem(msg, s.accepted_frames, now, last, s.odom_timeout_ns)
        if reason:
            self._rejected[reason] += 1
            self._throttled.warning(reason, f"odometry rejected ({reason}) on {s.odom_topic}")
            return
        q = msg.pose.pose.orientation
        self._pose = (msg.pose.pose.position.x, msg.pose.pose.position.y,
                      quaternion_to_yaw(q.x, q.y, q.z, q.w), stamp_to_ns(msg.header.stamp))
        self._accepted_at_ns = now

    def _on_path(self, msg: PathMsg) -> None:
        try:
            path = path_from_message(msg, self.settings.accepted_frames)
        except PathError as exc:
            self._paths_in["rejected"] += 1
            self.get_logger().error(f"pure_pursuit/path_in rejected: {exc}")
            return
        self._paths_in["accepted"] += 1
        self.follower.reset(path, keep_motion=True)
        self._followed = None
        self.get_logger().info(f"new path from pure_pursuit/path_in: {path!r}")
        self._publish_path()
        self._publish_done(False)

    # -- control -----------------------------------------------------------------------------
    def _on_tick(self) -> None:
        now = self._now_ns()  # first: a time jump clears the pose
        pose = self._pose
        if pose is None or self.follower.done:
            self._publish_cmd(ZERO)
            return
        if self._stale_for_ns(now) > 0:
            self._stale_ticks += 1
            self._throttled.warning("stale", "no accepted odometry for odom_timeout: commanding zero")
            self._cmd = ZERO
            self._publish_cmd(ZERO)
            return
        if self._followed is None or pose[3] != self._followed[3]:  # new information: one step at its stamp
            self._followed = pose
            self._cmd = self.follower.update(pose[0], pose[1], pose[2], pose[3])
            self._publish_feedback(pose[3])
        self._publish_cmd(self._cmd)
        if self.follower.done:  # the zero twist goes out first, then done
            self._publish_done(True)
            self.get_logger().info(f"path done ({self.follower.progress:.3f} m)")

    # -- output ------------------------------------------------------------------------------
    def _publish_cmd(self, cmd: Command) -> None:
        if not all(math.isfinite(c) for c in cmd):  # never publish a non-finite command
            self.get_logger().error(f"non-finite command {cmd}: sending zero")
            cmd = ZERO
        twist = Twist()
        twist.linear.x, twist.linear.y, twist.angular.z = float(cmd.vx), float(cmd.vy), float(cmd.wz)
        if self.settings.stamped_cmd_vel:  # stamped at the control time: consumers need no guess
            msg = TwistStamped(twist=twist)
            msg.header.stamp = self.get_clock().now().to_msg()
            msg.header.frame_id = self.settings.base_link_frame
            self._pub_cmd.publish(msg)
        else:
            self._pub_cmd.publish(twist)

    def _publish_feedback(self, t_ns: int) -> None:
        f = self.follower
        target = PointStamped()
        target.header.frame_id = f.path.frame_id
        target.header.stamp.sec, target.header.stamp.nanosec = ns_to_sec_nanosec(t_ns)
        target.point.x, target.point.y = float(f.target[0]), float(f.target[1])
        self._pub_target.publish(target)
        self._pub_progress.publish(Float64(data=float(f.progress)))

    def _publish_done(self, done: bool) -> None:
        self._pub_done.publish(Bool(data=done))

    def _publish_path(self) -> None:
        path = self.follower.path
        msg = PathMsg()
        msg.header.frame_id = path.frame_id
        msg.header.stamp = self.get_clock().now().to_msg()
        for i in range(len(path.xs)):
            seg = min(i, path.segment_count - 1)
            yaw = path.heading_at(path.s[i], seg)
            ps = PoseStamped()
            ps.header = msg.header
            ps.pose.position.x, ps.pose.position.y = float(path.xs[i]), float(path.ys[i])
            q = yaw_to_quaternion(yaw)
            ps.pose.orientation.x, ps.pose.orientation.y, ps.pose.orientation.z, ps.pose.orientation.w = q
            msg.poses.append(ps)
        self._pub_path.publish(msg)

    def _publish_markers(self) -> None:
        """The path, and the lookahead circle and target point of the follower's last step (drawn
        together, so the target is always the one found from the circle's centre)."""
        f = self.follower
        frame = f.path.frame_id
        stamp = self.get_clock().now().to_msg()
        path_xy = np.column_stack([f.path.xs, f.path.ys])
        out = [markers.line_strip(markers.NS_PATH, frame, stamp, path_xy, markers.PATH_RGBA, 0.015)]
        if self._followed is not None:
            circle = circle_points(self._followed[:2], self.settings.follower.lookahead_distance)
            out.append(markers.line_strip(markers.NS_LOOKAHEAD, frame, stamp, circle, markers.LOOKAHEAD_RGBA,
                                          0.008))
            out.append(markers.sphere_list(markers.NS_TARGET, frame, stamp, [f.target], markers.TARGET_RGBA,
                                           0.06))
        self._marker_pub.publish(markers.marker_array(out))

    def _publish_diagnostics(self) -> None:
        f = self.follower
        now = self._now_ns()
        st = DiagnosticStatus(name=f"{self.get_name()}: follower", hardware_id="pure_pursuit")
        prev_received, prev_rejected = self._diag_prev
        received = self._received - prev_received
        rejected = self._rejected - prev_rejected
        self._diag_prev = (self._received, self._rejected.copy())
        all_rejected = received > 0 and sum(rejected.values()) >= received
        why = ""
        if all_rejected:
            why = (f": all {received} odometry messages of the last period rejected ("
                   + ", ".join(f"{k} {n}" for k, n in rejected.most_common()) + ")")
        if f.done:
            st.level, st.message = DiagnosticStatus.OK, "path done"
        elif self._pose is None:
            st.level = DiagnosticStatus.ERROR if all_rejected else DiagnosticStatus.WARN
            st.message = "waiting for odometry: stopped" + why
        elif self._stale_for_ns(now) > 0:
            age = ns_to_seconds(now - min(self._pose[3], self._accepted_at_ns))
            st.level = DiagnosticStatus.ERROR if all_rejected else DiagnosticStatus.WARN
            st.message = f"odometry stale: stopped (no accepted odometry for {age:.2f} s){why}"
        else:
            st.level, st.message = DiagnosticStatus.OK, f"following leg {f.leg + 1}/{f.leg_count}"
        values = {
            "path": f.path.name, "path_length_m": f"{f.path.length:.3f}", "progress_m": f"{f.progress:.3f}",
            "cross_track_error_m": f"{f.cross_track_error:.3f}", "done": str(f.done),
            "odometry_received": str(self._received), "odometry_rejected": str(sum(self._rejected.values())),
            "stale_ticks": str(self._stale_ticks), "time_jumps": str(self._time_jumps),
            "paths_in_accepted": str(self._paths_in["accepted"]),
            "paths_in_rejected": str(self._paths_in["rejected"]),
        }
        values.update({f"odometry_rejected_{k}": str(n) for k, n in sorted(self._rejected.items())})
        st.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [st]
        self._pub_diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    return run_node(NODE_NAME, PurePursuitNode, args=args, empty_lists=True)


if __name__ == "__main__":
    sys.exit(main())
