"""qos_overrides: applied to ekf_node's inputs (over DDS), refused at start-up for any other topic."""

from __future__ import annotations

import subprocess

import pytest
import yaml
from helpers.ros_helpers import node_command, running_process, spin_until

pytestmark = pytest.mark.ros
IMU_CONFIG = [False] * 5 + [True] + [False] * 5 + [True] + [False] * 3


def _params(tmp_path, overrides: dict) -> str:
    path = tmp_path / "ekf.yaml"
    path.write_text(yaml.safe_dump({"ekf_node": {"ros__parameters": {
        "imu0": "imu/data", "imu0_config": IMU_CONFIG, "qos_overrides": overrides}}}))
    return str(path)


def test_qos_override_of_an_input_is_applied(ros_context, tmp_path) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import ReliabilityPolicy

    params = _params(tmp_path, {"/imu/data": {"subscription": {"reliability": "reliable", "depth": 7}}})
    node = Node("qos_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    with running_process(node_command("ekf_node") + ["--ros-args", "--params-file", params],
                         tmp_path / "ekf.log") as proc:
        found = spin_until(ex, lambda: bool(node.get_subscriptions_info_by_topic("/imu/data"))
                           or proc.poll() is not None, timeout=120.0)
        assert found and proc.poll() is None, (tmp_path / "ekf.log").read_text()
        (info,) = node.get_subscriptions_info_by_topic("/imu/data")
        assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE  # sensor-data QoS is best effort
    ex.shutdown()
    node.destroy_node()


def test_qos_override_of_another_topic_is_refused(tmp_path) -> None:
    params = _params(tmp_path, {"/imu/dta": {"subscription": {"depth": 7}}})
    res = subprocess.run(node_command("ekf_node") + ["--ros-args", "--params-file", params],
                         capture_output=True, text=True, timeout=180)
    assert res.returncode == 2, res.stdout + res.stderr
    assert "qos_overrides./imu/dta.subscription.depth" in res.stdout + res.stderr
    assert "Traceback" not in res.stdout + res.stderr
