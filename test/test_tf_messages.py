"""tf2_msgs/TFMessage in the venv (built by scripts/setup_env.sh) is the real tf2_msgs type on the wire."""

from __future__ import annotations

import pytest
from helpers.ros_helpers import spin_until, wait_for_publishers

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


def test_ekf_node_takes_an_imu_mount_from_tf_static_and_broadcasts_its_tf(ros_context, tmp_path) -> None:
    """Over DDS: an IMU in imu_link (turned 90° on the robot), the mount only on /tf_static;
    ekf_node (world odom) estimates base_link's heading and broadcasts odom->base_link on /tf."""
    import math

    import yaml
    from geometry_msgs.msg import TransformStamped
    from helpers.ros_helpers import node_command, running_process, wait_for_subscribers
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu
    from tf2_msgs.msg import TFMessage

    from ekf_localization.core.angles import quaternion_to_yaw, yaw_to_quaternion
    from ekf_localization.ros.tf_io import TF_QOS, TF_STATIC_QOS

    imu_config = [False] * 5 + [True] + [False] * 5 + [True] + [False] * 3
    params = tmp_path / "ekf.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        "world_frame": "odom", "frequency": 50.0, "imu0": "imu/data", "imu0_config": imu_config}}}))
    node = Node("tf_feeder", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    mount = TransformStamped()
    mount.header.frame_id, mount.child_frame_id = "base_link", "imu_link"
    mount.transform.translation.x = 0.1
    qx, qy, qz, qw = yaw_to_quaternion(math.pi / 2)
    mount.transform.rotation.z, mount.transform.rotation.w = qz, qw
    static_pub = node.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
    static_pub.publish(TFMessage(transforms=[mount]))  # latched: ekf_node gets it when it comes up
    imu_pub = node.create_publisher(Imu, "imu/data", qos_profile_sensor_data)
    out: list[Odometry] = []
    tf_out: list[TransformStamped] = []
    node.create_subscription(Odometry, "/odometry/filtered", out.append, 10)
    node.create_subscription(TFMessage, "/tf", lambda m: tf_out.extend(m.transforms), TF_QOS)
    with running_process(node_command("ekf_node") + ["--ros-args", "--params-file", str(params)],
                         tmp_path / "ekf.log") as proc:
        assert wait_for_subscribers(ex, imu_pub, timeout=120.0), (tmp_path / "ekf.log").read_text()
        assert wait_for_subscribers(ex, static_pub, timeout=20.0)
        heading = 0.3  # base_link's; the IMU, turned +90°, reads heading + π/2
        for _ in range(200):
            if len(out) >= 10 and tf_out:
                break
            m = Imu()
            m.header.stamp = node.get_clock().now().to_msg()
            m.header.frame_id = "imu_link"
            _, _, m.orientation.z, m.orientation.w = yaw_to_quaternion(heading + math.pi / 2)
            m.orientation_covariance[0] = m.orientation_covariance[4] = m.orientation_covariance[8] = 1e-4
            m.angular_velocity_covariance[0] = m.angular_velocity_covariance[4] = 1e-4
            m.angular_velocity_covariance[8] = 1e-4
            m.linear_acceleration_covariance[0] = -1.0
            imu_pub.publish(m)
            ex.spin_once(timeout_sec=0.02)
        assert proc.poll() is None, (tmp_path / "ekf.log").read_text()
    assert len(out) >= 10, (tmp_path / "ekf.log").read_text()
    q = out[-1].pose.pose.orientation
    assert quaternion_to_yaw(q.x, q.y, q.z, q.w) == pytest.approx(heading, abs=0.01)
    t = next(t for t in tf_out if t.header.frame_id == "odom" and t.child_frame_id == "base_link")
    r = t.transform.rotation
    assert quaternion_to_yaw(r.x, r.y, r.z, r.w) == pytest.approx(heading, abs=0.05)
    ex.shutdown()
    node.destroy_node()
