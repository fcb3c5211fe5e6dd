"""ekf_node's transport over real DDS: typed subscriptions in, rclpy messages out.

Checked: the node fuses odometry and publishes /odometry/filtered with and without numba
and rosbags installed; bytes that are no message (rmw drops them: no message reaches the
callback) neither kill the node nor count as received; a message whose values cannot be
fused (NaN) is rejected and counted on /diagnostics with its reason.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.ros_helpers import (
    node_command,
    running_process,
    spin_until,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.units import NS_PER_S as SEC

pytestmark = [pytest.mark.ros, pytest.mark.slow]
# bytes that are no Odometry (an empty payload never reaches a reader: Fast DDS drops it)
GARBAGE = [b"\x00\x01\x00\x00", b"\x00\x01\x00\x00" + b"\xff" * 40, b"not cdr at all" * 10]


def _params(tmp_path: Path) -> Path:
    cfg = [False] * 15
    cfg[6] = cfg[7] = cfg[11] = True  # vx vy vyaw
    params = {"model": "mecanum", "frequency": 50.0, "world_frame": "odom", "publish_tf": False,
              "odom0": "odometry/dead_wheels", "odom0_config": cfg, "publish_on_measurement": True}
    path = tmp_path / "ekf.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    return path


def _hidden(tmp_path: Path, *packages: str) -> dict[str, str]:
    """An environment in which importing ``packages`` fails, as if they were not installed."""
    root = tmp_path / "hidden"
    for name in packages:
        (root / name).mkdir(parents=True)
        (root / name / "__init__.py").write_text(f"raise ImportError('{name} is hidden by this test')\n")
    return {"PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}


def _drive(ros_context, tmp_path: Path, env: dict[str, str] | None) -> tuple[list, dict, str]:
    """Run ekf_node; once it fuses, publish 100 twists of 0.5 m/s at 50 Hz, with the GARBAGE
    bytes and five twists of NaN speed in between; return (the outputs since, the odom0
    diagnostics, the log)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data

    node = Node("transport_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    outputs: list[Odometry] = []
    diag: dict[str, str] = {}

    def on_diag(msg) -> None:
        for st in msg.status:
            if st.name == "ekf_node: odom0":
                diag.clear()
                diag.update({kv.key: kv.value for kv in st.values})

    out_sub = node.create_subscription(Odometry, "odometry/filtered", outputs.append, 500)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    pub = node.create_publisher(Odometry, "odometry/dead_wheels", qos_profile_sensor_data)
    log = tmp_path / "ekf.log"
    cmd = node_command("ekf_node") + ["--ros-args", "--params-file", str(_params(tmp_path))]
    try:
        with running_process(cmd, log, env=env) as proc:
            assert wait_for_subscribers(ex, pub, timeout=60.0), log.read_text()
            assert wait_for_publishers(ex, out_sub, timeout=10.0)
            msg = Odometry()
            msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
            cov = np.zeros(36)
            cov[::7] = 1e-4
            msg.twist.covariance = cov

            def publish(vx: float = 0.5) -> None:
                msg.header.stamp = node.get_clock().now().to_msg()
                msg.twist.twist.linear.x = vx
                pub.publish(msg)
                spin_until(ex, lambda: False, 0.02)

            # best effort: what is sent before the node's reader has matched may be lost, so the
            # count starts once the node has fused something
            assert spin_until(ex, lambda: bool(outputs) or publish(), 60.0), log.read_text()
            spin_until(ex, lambda: bool(diag), 3.0)
            before = int(diag.get("received", 0))
            outputs.clear()
            for k in range(100):
                publish()
                if k % 20 == 10:  # k = 10, 30, 50, 70, 90
                    pub.publish(GARBAGE[(k // 20) % len(GARBAGE)])
                    publish(math.nan)
            assert spin_until(ex, lambda: int(diag.get("rejected_nonfinite", -1)) == 5
                              and int(diag.get("received", 0)) >= before + 105, 20.0), diag
            assert proc.poll() is None, log.read_text()
    finally:
        ex.shutdown()
        node.destroy_node()
    return outputs, dict(diag), log.read_text()


def _moved_at_half_a_metre_per_second(outputs, diag: dict, log: str) -> None:
    assert len(outputs) >= 80
    last = outputs[-1]
    assert last.header.frame_id == "odom" and last.child_frame_id == "base_link"
    assert last.twist.twist.linear.x == pytest.approx(0.5, abs=0.05)
    first = outputs[0]
    dt = ((last.header.stamp.sec - first.header.stamp.sec) * SEC
          + last.header.stamp.nanosec - first.header.stamp.nanosec) / SEC
    moved = last.pose.pose.position.x - first.pose.pose.position.x
    assert moved == pytest.approx(0.5 * dt, rel=0.2)
    assert all(math.isfinite(v) for v in last.pose.covariance) and last.pose.covariance[0] > 0.0
    # the NaN twists are rejected and counted; the garbage never reaches the node as a message
    assert int(diag["received"]) == int(diag["applied"]) + 5, diag
    assert diag["rejected_unreadable_message"] == "0", diag
    assert "rejected twist (nonfinite)" in log and "Traceback" not in log


def test_fuses_and_rejects_over_dds(ros_context, tmp_path: Path) -> None:
    outputs, diag, log = _drive(ros_context, tmp_path, None)
    _moved_at_half_a_metre_per_second(outputs, diag, log)


def test_runs_without_numba_and_rosbags(ros_context, tmp_path: Path) -> None:
    """An install without numba or rosbags: the same drive, the same outcome."""
    outputs, diag, log = _drive(ros_context, tmp_path, _hidden(tmp_path, "numba", "rosbags"))
    _moved_at_half_a_metre_per_second(outputs, diag, log)
