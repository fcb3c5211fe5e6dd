"""Real rclpy over real Fast DDS: a publisher and a subscriber in two processes."""

from __future__ import annotations

import sys

import pytest
from helpers.ros_helpers import running_process, spin_until, wait_for_publishers

pytestmark = pytest.mark.ros

PUBLISHER = r"""
import sys, time, rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from nav_msgs.msg import Odometry
rclpy.init()
node = Node("smoke_pub")
# history for all 50: the writer can match the reader before the reader matches the writer, and
# reliable delivery then repairs the early samples from the history (depth 10 could drop them)
pub = node.create_publisher(Odometry, "/smoke", 50)
deadline = time.monotonic() + 20.0
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.01)
for i in range(50):
    msg = Odometry()
    msg.header.frame_id = "odom"
    msg.pose.pose.position.x = float(i)
    pub.publish(msg)
    time.sleep(0.005)
assert pub.wait_for_all_acked(Duration(seconds=10.0))  # every message delivered (reliable QoS)
"""


def test_messages_cross_processes(ros_context, tmp_path):
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    node = Node("smoke_sub", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    got: list[float] = []
    sub = node.create_subscription(Odometry, "/smoke", lambda m: got.append(m.pose.pose.position.x), 100)
    with running_process([sys.executable, "-c", PUBLISHER], tmp_path / "pub.log") as proc:
        assert wait_for_publishers(ex, sub, timeout=15.0), "publisher never matched"
        assert spin_until(ex, lambda: len(got) >= 50, timeout=15.0)
        proc.wait(timeout=10)
    assert got == [float(i) for i in range(50)]
    ex.shutdown()
    node.destroy_node()
