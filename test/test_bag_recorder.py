"""The recorder writes real rosbag2 files that rosbags and the mcap library read back."""

from __future__ import annotations

import sys

import pytest
from helpers.ros_helpers import running_process, spin_until

from ekf_localization.core.units import stamp_to_ns

pytestmark = pytest.mark.ros

PUBLISHER = r"""
import time, rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import QoSProfile, DurabilityPolicy
from nav_msgs.msg import Odometry
from std_msgs.msg import Bool
rclpy.init()
node = Node("rec_pub")
pub = node.create_publisher(Odometry, "/odometry/test", 50)
tl = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
latched = node.create_publisher(Bool, "/latched", tl)
latched.publish(Bool(data=True))
deadline = time.monotonic() + 20.0
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.01)
for i in range(40):
    m = Odometry()
    m.header.frame_id = "odom"
    m.header.stamp.sec = 100 + i // 10
    m.header.stamp.nanosec = (i % 10) * 100_000_000
    m.child_frame_id = "base_link"
    m.pose.pose.position.x = float(i)
    m.pose.covariance[0] = 0.5
    pub.publish(m)
    time.sleep(0.01)
for p in (pub, latched):  # every message delivered: acknowledged by the recorder (reliable QoS)
    assert p.wait_for_all_acked(Duration(seconds=10.0))
"""


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_record_and_read_back(ros_context, tmp_path, storage):
    from rclpy.executors import SingleThreadedExecutor
    from rosbags.highlevel import AnyReader

    from ekf_localization.tools.bag_recorder import BagRecorder

    bag = tmp_path / "bag"
    rec = BagRecorder(bag, storage=storage, topics=["/odometry/test", "/latched"], context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(rec)
    with running_process([sys.executable, "-c", PUBLISHER], tmp_path / "pub.log") as proc:
        assert spin_until(ex, lambda: rec.counts.get("/odometry/test", 0) >= 40, timeout=20.0), rec.counts
        assert spin_until(ex, lambda: rec.counts.get("/latched", 0) >= 1, timeout=5.0), rec.counts
        proc.wait(timeout=10)
    rec.close()
    ex.shutdown()
    rec.destroy_node()

    assert (bag / "metadata.yaml").is_file()
    with AnyReader([bag]) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert conns["/odometry/test"].msgtype == "nav_msgs/msg/Odometry"
        xs, stamps = [], []
        for conn, _t, raw in reader.messages(connections=[conns["/odometry/test"]]):
            msg = reader.deserialize(raw, conn.msgtype)
            xs.append(msg.pose.pose.position.x)
            stamps.append(stamp_to_ns(msg.header.stamp))
            assert msg.header.frame_id == "odom" and msg.pose.covariance[0] == 0.5
    assert xs == [float(i) for i in range(40)]
    assert stamps[0] == 100_000_000_000 and stamps[-1] == 103_900_000_000

    if storage == "mcap":
        from mcap.reader import make_reader

        files = list(bag.glob("*.mcap"))
        assert len(files) == 1
        with open(files[0], "rb") as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            topics = {ch.topic for ch in summary.channels.values()}
            schemas = {s.name for s in summary.schemas.values()}
            n = sum(1 for _ in reader.iter_messages(topics=["/odometry/test"]))
        assert {"/odometry/test", "/latched"} <= topics
        assert "nav_msgs/msg/Odometry" in schemas
        assert n == 40


def test_drain_takes_every_delivered_message_after_the_stop(ros_context, tmp_path):
    """What DDS delivered before a stop but the executor had not yet taken is written by
    ``drain`` (the recorder's main runs it after the spin loop ends on SIGINT / SIGTERM)."""
    from rclpy.duration import Duration
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosbags.highlevel import AnyReader
    from std_msgs.msg import String

    from ekf_localization.tools.bag_recorder import BagRecorder, drain

    count = 500
    rec = BagRecorder(tmp_path / "bag", topics=["/drain_probe"], context=ros_context)
    probe = Node("drain_probe", context=ros_context)
    pub = probe.create_publisher(String, "/drain_probe",
                                 QoSProfile(depth=count, reliability=ReliabilityPolicy.RELIABLE))
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(rec)
    assert spin_until(ex, lambda: rec.matched("/drain_probe"), timeout=20.0)
    for i in range(count):
        pub.publish(String(data=str(i)))
    assert pub.wait_for_all_acked(Duration(seconds=10.0))  # in the recorder's reader cache
    assert rec.counts["/drain_probe"] == 0  # the executor has not spun since: nothing taken yet
    drain(ex, rec)
    rec.close()
    ex.shutdown()
    rec.destroy_node()
    probe.destroy_node()
    with AnyReader([tmp_path / "bag"]) as reader:
        got = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages()]
    assert got == [str(i) for i in range(count)]
