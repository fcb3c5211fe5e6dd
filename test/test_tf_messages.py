"""tf2_msgs/TFMessage in the venv (built by scripts/setup_env.sh) is the real tf2_msgs type on the wire."""

from __future__ import annotations

import pytest
from ros_helpers import spin_until, wait_for_publishers

pytestmark = pytest.mark.ros


def test_tfmessage_type_hash_is_jazzy_tf2_msgs(ros_context) -> None:
    """RIHS01 hashes the type's full definition: the hash our publisher announces is the one of
    Jazzy's tf2_msgs/msg/TFMessage (rosbags' independent copy), so a real tf2 peer matches."""
    from rclpy.node import Node
    from rosbags.typesys import Stores, get_typestore
    from tf2_msgs.msg import TFMessage

    jazzy = get_typestore(Stores.ROS2_JAZZY).hash_rihs01("tf2_msgs/msg/TFMessage")
    node = Node("tf_type_probe", context=ros_context)
    node.create_publisher(TFMessage, "/tf", 10)
    infos = node.get_publishers_info_by_topic("/tf")
    assert [i.topic_type for i in infos] == ["tf2_msgs/msg/TFMessage"]
    assert str(infos[0].topic_type_hash) == jazzy
    node.destroy_node()


def test_tf_static_over_dds_latched(ros_context) -> None:
    """A transient-local /tf_static publisher reaches a late subscriber (what tf2's listener relies on)."""
    from geometry_msgs.msg import TransformStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from tf2_msgs.msg import TFMessage

    static_qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                            reliability=ReliabilityPolicy.RELIABLE)
    pub_node = Node("tf_static_pub", context=ros_context)
    sub_node = Node("tf_static_sub", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(pub_node)
    ex.add_node(sub_node)
    tf = TransformStamped()
    tf.header.frame_id = "base_link"
    tf.child_frame_id = "imu_link"
    tf.transform.translation.x = 0.1
    tf.transform.rotation.w = 1.0
    pub_node.create_publisher(TFMessage, "/tf_static", static_qos).publish(TFMessage(transforms=[tf]))
    got: list[TFMessage] = []
    sub = sub_node.create_subscription(TFMessage, "/tf_static", got.append, static_qos)
    assert wait_for_publishers(ex, sub)
    assert spin_until(ex, lambda: bool(got), timeout=10.0)
    (t,) = got[0].transforms
    assert (t.header.frame_id, t.child_frame_id, t.transform.translation.x) == ("base_link", "imu_link", 0.1)
    ex.shutdown()
    pub_node.destroy_node()
    sub_node.destroy_node()
