"""diff_drive_controller's all-zero covariances over DDS: fused with zero_variance_floor, warned once."""

from __future__ import annotations

import pytest
import yaml
from helpers.ros_helpers import node_command, running_process, spin_until, wait_for_subscribers

pytestmark = pytest.mark.ros


def test_zero_covariance_odometry_is_fused_and_reported_once(ros_context, tmp_path) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data

    params = tmp_path / "ekf.yaml"
    params.write_text(yaml.safe_dump({"ekf_node": {"ros__parameters": {
        "frequency": 50.0, "odom0": "diff_drive_controller/odom",
        "odom0_config": [False] * 6 + [True, True, False, False, False, True] + [False] * 3}}}))
    node = Node("zero_cov_feeder", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    pub = node.create_publisher(Odometry, "diff_drive_controller/odom", qos_profile_sensor_data)
    out: list[Odometry] = []
    statuses: list = []
    node.create_subscription(Odometry, "/odometry/filtered", out.append, 10)
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: statuses.extend(s for s in m.status if s.name.endswith("odom0")), 10)
    with running_process(node_command("ekf_node") + ["--ros-args", "--params-file", str(params)],
                         tmp_path / "ekf.log"):
        assert wait_for_subscribers(ex, pub, timeout=120.0), (tmp_path / "ekf.log").read_text()

        def send() -> bool:
            m = Odometry()  # covariances all zero, as diff_drive_controller publishes by default
            m.header.stamp = node.get_clock().now().to_msg()
            m.header.frame_id, m.child_frame_id = "odom", "base_link"
            m.twist.twist.linear.x = 0.3
            pub.publish(m)
            floored = [s for s in statuses if dict((v.key, v.value) for v in s.values)
                       .get("zero_variances_floored", "0") != "0"]
            return len(out) >= 20 and len(floored) >= 2

        assert spin_until(ex, send, timeout=30.0, step=0.02), (len(out), (tmp_path / "ekf.log").read_text())
        log = (tmp_path / "ekf.log").read_text()
    assert abs(out[-1].twist.twist.linear.x - 0.3) < 0.01
    floored = [s for s in statuses if dict((v.key, v.value) for v in s.values)
               .get("zero_variances_floored", "0") != "0"]
    assert sum("zero_variance_floor" in s.message for s in floored) == 1  # warned once
    assert log.count("zero variance on a fused field") == 1
    ex.shutdown()
    node.destroy_node()
