"""Bounded work under an input burst, over real DDS (issue 35, case 7).

ekf_node runs the shipped config (config/ekf.yaml, cmd_vel fused) on wall time, fed dead-wheel
odometry at 100 Hz by this process. A burst of cmd_vel, all stamped at the burst's start: each
command is older than the odometry fused since, so each rewinds and replays the history
(milliseconds), and the EventsExecutor runs the whole queued burst before the publish timer's
event: /odometry/filtered was silent for 0.4-0.8 s (0.795 s measured before the fix). Now a
message callback publishes itself once a period has passed without output (ekf_node
``_publish_if_overdue``): no gap between output stamps is longer than two publish periods.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from helpers.ros_helpers import REPO, node_command, running_process, spin_until, wait_for_publishers

from ekf_localization.core.units import NS_PER_S, stamp_to_ns

pytestmark = [pytest.mark.ros, pytest.mark.slow]

PERIOD_NS = NS_PER_S // 50  # config/ekf.yaml frequency
BURST = 1000
ODOM_PER_TICK = 8  # odometry messages per 10 ms in the replay-bound test: 800 Hz


def test_a_cmd_vel_burst_leaves_no_output_gap(ros_context, tmp_path: Path) -> None:
    from geometry_msgs.msg import TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, qos_profile_sensor_data

    node = Node("burst_test", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    stamps: list[int] = []
    sub = node.create_subscription(Odometry, "odometry/filtered",
                             lambda m: stamps.append(stamp_to_ns(m.header.stamp)), 100)
    diag: dict[str, dict[str, str]] = {}

    def on_diagnostics(msg) -> None:
        for st in msg.status:
            diag[st.name] = {kv.key: kv.value for kv in st.values} | {"_message": st.message}

    from diagnostic_msgs.msg import DiagnosticArray

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    odom_pub = node.create_publisher(Odometry, "odometry/dead_wheels", qos_profile_sensor_data)
    cmd_pub = node.create_publisher(TwistStamped, "cmd_vel", QoSProfile(depth=BURST))

    def odometry() -> None:
        msg = Odometry()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.twist.twist.linear.x = 0.3
        for i in (0, 7, 14, 21, 28, 35):
            msg.pose.covariance[i] = msg.twist.covariance[i] = 1e-4
        odom_pub.publish(msg)

    node.create_timer(0.01, odometry)
    cmd = [*node_command("ekf_node"), "--ros-args", "--params-file", str(REPO / "config" / "ekf.yaml")]
    try:
        with running_process(cmd, tmp_path / "ekf.log"):
            assert wait_for_publishers(executor, sub, timeout=30.0)
            assert spin_until(executor, lambda: len(stamps) > 100, 30.0), (tmp_path / "ekf.log").read_text()
            assert cmd_pub.get_subscription_count() >= 1
            before = len(stamps)
            now = node.get_clock().now()
            for k in range(BURST):  # within the 20 ms control latency, as fast as DDS takes them
                msg = TwistStamped()
                msg.header.stamp = now.to_msg()
                msg.header.frame_id = "base_link"
                msg.twist.linear.x = 0.3 + 1e-4 * k
                cmd_pub.publish(msg)
                executor.spin_once(timeout_sec=0.0002)  # paced so that the burst reaches ekf_node
            t_end = time.monotonic() + 2.0
            spin_until(executor, lambda: time.monotonic() > t_end, 3.0)
            gaps = np.diff(stamps[before - 10:])
            received = int(diag.get("ekf_node: cmd_vel", {}).get("received", "0"))
            print(f"burst: {received} cmd_vel received, longest output gap {gaps.max() / NS_PER_S:.3f} s")
            assert received >= 50, diag.get("ekf_node: cmd_vel")  # the burst reached the node
            log = (tmp_path / "ekf.log").read_text()
            assert gaps.max() <= 2 * PERIOD_NS, (gaps.max() / NS_PER_S, log[-2000:])
    finally:
        executor.shutdown()
        node.destroy_node()


def test_a_pose_lagged_beyond_the_replay_bound_is_dropped_and_reported(ros_context, tmp_path: Path) -> None:
    """A camera pose 0.4 s late, behind ~360 odometry and IMU entries (odometry at 800 Hz: eight
    per 10 ms tick; timeline.MAX_REPLAY_ENTRIES is 256; history_length 0.5 s keeps it
    insertable), is dropped as ``overloaded`` and said on /diagnostics at WARN; one 20 ms late
    (~18 entries) is fused by a rewind."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from rclpy.duration import Duration
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, qos_profile_sensor_data
    from sensor_msgs.msg import Imu

    from ekf_localization.core.timeline import MAX_REPLAY_ENTRIES

    node = Node("lag_test", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    filter_status: list[tuple[int, str, dict[str, str]]] = []
    pose_status: dict[str, str] = {}

    def on_diagnostics(msg) -> None:
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            if st.name == "ekf_node: filter":
                filter_status.append((int.from_bytes(st.level, "little") if isinstance(st.level, bytes)
                                      else int(st.level), st.message, values))
            elif st.name == "ekf_node: pose0":
                pose_status.clear()
                pose_status.update(values)

    diag_sub = node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    odom_pub = node.create_publisher(Odometry, "odometry/dead_wheels", QoSProfile(depth=100))
    imu_pub = node.create_publisher(Imu, "imu/data", qos_profile_sensor_data)
    pose_pub = node.create_publisher(PoseWithCovarianceStamped, "camera/pose", qos_profile_sensor_data)

    def inputs() -> None:
        now = node.get_clock().now()
        stamp = now.to_msg()
        for k in range(ODOM_PER_TICK - 1, -1, -1):  # 800 Hz of odometry, in stamp order
            odom = Odometry()
            odom.header.stamp = (now - Duration(nanoseconds=k * 10_000_000 // ODOM_PER_TICK)).to_msg()
            odom.header.frame_id, odom.child_frame_id = "odom", "base_link"
            for i in (0, 7, 14, 21, 28, 35):
                odom.pose.covariance[i] = odom.twist.covariance[i] = 1e-4
            odom_pub.publish(odom)
        imu = Imu()
        imu.header.stamp, imu.header.frame_id = stamp, "base_link"
        imu.orientation.w = 1.0
        for i in (0, 4, 8):
            imu.orientation_covariance[i] = imu.angular_velocity_covariance[i] = 1e-4
            imu.linear_acceleration_covariance[i] = 1e-2
        imu_pub.publish(imu)

    def pose(late_s: float) -> None:
        msg = PoseWithCovarianceStamped()
        msg.header.stamp = (node.get_clock().now() - Duration(seconds=late_s)).to_msg()
        msg.header.frame_id = "map"
        msg.pose.pose.orientation.w = 1.0
        for i in (0, 7, 14, 21, 28, 35):
            msg.pose.covariance[i] = 1e-3
        pose_pub.publish(msg)

    node.create_timer(0.01, inputs)
    cmd = [*node_command("ekf_node"), "--ros-args", "--params-file", str(REPO / "config" / "ekf.yaml")]
    log = tmp_path / "ekf.log"
    try:
        with running_process(cmd, log):
            assert wait_for_publishers(executor, diag_sub, timeout=30.0)
            assert spin_until(executor, lambda: pose_pub.get_subscription_count() >= 1, 30.0)
            assert spin_until(executor, lambda: int(pose_status.get("received", "0")) == 0
                              and any(v.get("initialized") == "True" for _, _, v in filter_status), 30.0)
            spin_until(executor, lambda: False, 1.0)  # > 0.5 s of history: ~450 entries
            pose(0.02)
            assert spin_until(executor, lambda: int(pose_status.get("applied", "0")) == 1, 5.0), \
                (pose_status, log.read_text()[-2000:])
            seen = len(filter_status)
            pose(0.4)  # behind ~360 entries > MAX_REPLAY_ENTRIES
            assert MAX_REPLAY_ENTRIES + 50 < 0.4 * (100 * ODOM_PER_TICK + 100)
            assert spin_until(executor, lambda: int(pose_status.get("rejected_overloaded", "0")) == 1, 5.0), \
                (pose_status, log.read_text()[-2000:])
            assert spin_until(executor, lambda: any("overloaded: dropped 1" in m for _, m, _ in
                                                    filter_status[seen:]), 5.0), filter_status[seen:]
            level, message, values = next(s for s in filter_status[seen:] if "overloaded" in s[1])
            assert level == int.from_bytes(DiagnosticStatus.WARN, "little"), (level, message)
            assert values["dropped_overloaded"] == "1"
            assert pose_status["applied"] == "1"  # the dropped pose was not fused
    finally:
        executor.shutdown()
        node.destroy_node()
