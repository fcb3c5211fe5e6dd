"""ekf_node publishes its static_transforms on /tf_static and reports another node's value for them."""

from __future__ import annotations

import math

import pytest
from helpers.ros_helpers import Diagnostics, node_command, running_process

pytestmark = pytest.mark.ros

MOUNT = (0.12, -0.05, 0.3, 0.4, 0.0, 0.0)  # x y z yaw pitch roll of base_link -> camera_link
STATUS = "ekf_node: static_transforms"


def _mount_tf(x: float, yaw: float):
    from geometry_msgs.msg import TransformStamped

    from ekf_localization.core.angles import yaw_to_quaternion

    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = "base_link", "camera_link"
    t.transform.translation.x = x
    r = t.transform.rotation
    r.x, r.y, r.z, r.w = yaw_to_quaternion(yaw)
    return t


def test_static_transforms_reach_tf_static_and_a_conflict_is_reported(ros_context, tmp_path) -> None:
    import yaml
    from tf2_msgs.msg import TFMessage

    from ekf_localization.core.angles import quaternion_to_rpy
    from ekf_localization.ros.tf_io import TF_STATIC_QOS

    params = tmp_path / "ekf.yaml"
    entry = " ".join(str(v) for v in MOUNT) + " base_link camera_link"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        "world_frame": "odom", "frequency": 20.0, "static_transforms": [entry]}}}))
    diag = Diagnostics(ros_context)
    log = tmp_path / "ekf.log"
    try:
        cmd = node_command("ekf_node") + ["--ros-args", "--params-file", str(params)]
        with running_process(cmd, log) as proc:
            # subscribed only once ekf_node publishes: transient local hands a late subscriber the message
            assert diag.spin_until(lambda: diag.node.count_publishers("/tf_static") >= 1, 60.0), \
                log.read_text()
            got: list = []
            diag.node.create_subscription(TFMessage, "/tf_static", lambda m: got.extend(m.transforms),
                                          TF_STATIC_QOS)
            assert diag.spin_until(lambda: bool(got), 5.0), log.read_text()
            (t,) = got
            assert (t.header.frame_id, t.child_frame_id) == ("base_link", "camera_link")
            tr, q = t.transform.translation, t.transform.rotation
            roll, pitch, yaw = quaternion_to_rpy(q.x, q.y, q.z, q.w)
            assert (tr.x, tr.y, tr.z, yaw, pitch, roll) == pytest.approx(MOUNT, abs=1e-9)
            # its own echo on /tf_static is no conflict
            assert diag.spin_until(lambda: diag.get(STATUS, "_level") != "", 3.0), diag.latest
            assert diag.get(STATUS, "_level") == b"\x00", diag.latest[STATUS]
            assert diag.get(STATUS, "published") == "1"

            pub = diag.node.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
            pub.publish(TFMessage(transforms=[_mount_tf(0.2, math.radians(10.0))]))
            assert diag.spin_until(lambda: diag.get(STATUS, "_level") == b"\x01", 3.0), diag.latest
            text = diag.get(STATUS, "conflict camera_link")
            assert "base_link -> camera_link = 0.2 0 0 0.174533 0 0" in text, text
            assert "= 0.12 -0.05 0.3 0.4 0 0" in text and "uses its static_transforms" in text, text
            assert proc.poll() is None, log.read_text()
        warnings = [line for line in log.read_text().splitlines() if "another node has" in line]
        assert len(warnings) == 1 and "WARN" in warnings[0], log.read_text()
    finally:
        diag.close()


class _StubNode:
    """Records what StaticTransforms publishes, without DDS."""

    def __init__(self) -> None:
        self.sent: list = []

    def create_publisher(self, _type, _topic, _qos):
        return self

    def publish(self, msg) -> None:
        self.sent.append(msg)


def test_filter_keeps_the_entries_frames_out_and_reports_a_different_value_once() -> None:
    from tf2_msgs.msg import TFMessage

    from ekf_localization.core.frames import RigidTransform
    from ekf_localization.ros.static_tf import StaticTransforms

    warned: list[str] = []
    node = _StubNode()
    static = StaticTransforms(node, TFMessage, (("base_link", "camera_link", MOUNT),), 5, warned.append)
    assert len(node.sent) == 1 and len(node.sent[0].transforms) == 1
    echo = ("/base_link", "camera_link", RigidTransform.from_xyz_ypr(*MOUNT), 5)
    other = ("base_link", "imu_link", RigidTransform.from_xyz_ypr(0, 0, 0, 1, 0, 0), 5)
    assert static.filter([echo, other]) == [other] and not warned
    moved = ("base_link", "camera_link", RigidTransform.from_xyz_ypr(*MOUNT[:3], 0.41, 0, 0), 5)
    reparented = ("odom", "camera_link", RigidTransform.from_xyz_ypr(*MOUNT), 5)
    assert static.filter([moved, reparented]) == []  # the entry is pinned in the buffer
    assert len(warned) == 1 and "0.41" in warned[0] and static.status("n")[0].level == b"\x01"
    empty = _StubNode()  # no entries: nothing published, no status
    assert StaticTransforms(empty, TFMessage, (), 0, warned.append).status("n") == [] and not empty.sent
