"""sim_node's camera images over real DDS: Image + CameraInfo + static TF, and the tags in them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.ros_helpers import REPO, node_command, running_process, spin_until, wait_for_publishers

from ekf_localization.core.angles import quaternion_to_matrix
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import load_tag_layout

pytestmark = pytest.mark.ros
LAYOUT = REPO / "config" / "tags" / "ftc_seed000.yaml"
MOUNT = [0.1, 0.0, 0.15, 0.0, 0.0]


def test_sim_node_images_show_the_tags_in_view(ros_context, tmp_path):
    pytest.importorskip("cv2")
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image

    from ekf_localization.ros.tf_io import TF_STATIC_QOS, TF_STATIC_TOPIC, tf_message_class
    from ekf_localization.vision.detectors import make_detector

    tf_type = tf_message_class()
    probe = Node("camera_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(probe)
    got: dict[str, list] = {"image": [], "info": [], "tf": []}
    # reliable: best effort drops 300 kB images (many DDS fragments) on a loaded machine
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    subs = [probe.create_subscription(Image, "camera/image_raw", got["image"].append, reliable),
            probe.create_subscription(CameraInfo, "camera/camera_info", got["info"].append,
                                      qos_profile_sensor_data)]
    if tf_type is not None:
        subs.append(probe.create_subscription(tf_type, TF_STATIC_TOPIC, got["tf"].append, TF_STATIC_QOS))
    cmd = [*node_command("sim_node"), "--ros-args", "--params-file", str(REPO / "config" / "sim.yaml"),
           "-p", "camera_images.enabled:=true", "-p", f"camera_images.tag_layout:={LAYOUT}",
           "-p", f"camera_images.mount:={MOUNT}", "-p", "initial_pose:=[0.0, 0.0, 1.5707963267948966]",
           "-p", "publish_clock:=true"]   # sim time: stamps on the capture grid, no dropped ticks
    with running_process(cmd, tmp_path / "sim.log") as proc:
        for s in subs:
            assert wait_for_publishers(ex, s, timeout=20.0), f"no publisher on {s.topic_name}"
        assert spin_until(ex, lambda: len(got["image"]) >= 2, timeout=30.0)
        got["image"].clear()   # from here on the writer has matched this reader: nothing lost
        ok = spin_until(ex, lambda: len(got["image"]) >= 5 and len(got["info"]) >= 5
                        and (tf_type is None or got["tf"]), timeout=30.0)
        assert ok, (tmp_path / "sim.log").read_text()
        assert proc.poll() is None

    img, info = got["image"][-1], got["info"][-1]
    assert (img.encoding, img.width, img.height, img.step) == ("mono8", 640, 480, 640)
    assert img.header.frame_id == info.header.frame_id == "camera_optical"
    stamps = [stamp_to_ns(m.header.stamp) for m in got["image"]]
    steps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
    assert all(s % 50_000_000 == 0 for s in stamps) and all(d > 0 for d in steps), stamps  # 20 Hz grid
    assert all(d == 50_000_000 for d in steps), stamps   # none lost
    assert {stamp_to_ns(m.header.stamp) for m in got["info"]} & set(stamps)
    cam = PinholeCamera(info.width, info.height, info.k[0], info.k[4], info.k[2], info.k[5])
    np.testing.assert_allclose(cam.fx, PinholeCamera.from_fov(640, 480, math.radians(70.0)).fx)

    # the static TF base_link -> camera_optical: the mount, optical axes (z forward = base x)
    if tf_type is not None:
        t = next(t for m in got["tf"] for t in m.transforms if t.child_frame_id == "camera_optical")
        assert t.header.frame_id == "base_link"
        tr, q = t.transform.translation, t.transform.rotation
        np.testing.assert_allclose([tr.x, tr.y, tr.z], MOUNT[:3], atol=1e-12)
        R = quaternion_to_matrix(q.x, q.y, q.z, q.w)
        np.testing.assert_allclose(R[:, 2], [1.0, 0.0, 0.0], atol=1e-9)   # optical z = forward
        np.testing.assert_allclose(R[:, 1], [0.0, 0.0, -1.0], atol=1e-9)  # optical y = down

    # the tags: the robot stands still at the centre facing the top wall (+y)
    pixels = np.frombuffer(bytes(img.data), np.uint8).reshape(img.height, img.width)
    found = {d.tag_id for d in make_detector().detect(pixels)}
    layout = load_tag_layout(LAYOUT)
    R_map_opt = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # yaw pi/2
    cam_pos = np.array([0.0, 0.1, 0.15])
    inside, partly = set(), set()
    for tag in layout.tags.values():
        c = (tag.corners_map() - cam_pos) @ R_map_opt
        p = cam.project(c)
        ok = (c[:, 2] > 0.05) & (p[:, 0] > 1) & (p[:, 0] < 638) & (p[:, 1] > 1) & (p[:, 1] < 478)
        if ok.all():
            inside.add(tag.tag_id)
        if ok.any():
            partly.add(tag.tag_id)
    assert len(inside) >= 3 and inside <= found <= partly, (inside, found, partly)


def test_camera_images_parameters() -> None:
    from ekf_localization.ros.parameters import ParameterError
    from sim_robot.ros.sim_params import parse_parameters

    _, off = parse_parameters({})
    assert off.camera_images is None
    _, on = parse_parameters({"camera_images.enabled": True,
                              "camera_images.tag_layout": "config/tags/ftc_seed000.yaml",
                              "camera_images.latency": 0.05, "camera_images.width": 320,
                              "camera_images.height": 240})
    cfg = on.camera_images
    assert cfg.period_ns == 50_000_000 and cfg.latency_ns == 50_000_000
    assert (cfg.camera.width, cfg.camera.height) == (320, 240) and len(cfg.layout.tags) == 12
    with pytest.raises(ParameterError, match="camera_images.tag_layout"):
        parse_parameters({"camera_images.enabled": True})
    with pytest.raises(ParameterError, match="camera_images.tag_layout"):
        parse_parameters({"camera_images.enabled": True, "camera_images.tag_layout": "/nonexistent.yaml"})
    with pytest.raises(ParameterError, match="camera_images.mount"):
        parse_parameters({"camera_images.mount": [0.0, 0.0, 0.1]})
