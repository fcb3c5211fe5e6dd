"""tag_localizer over DDS: a single tag decided by the filter's heading on odometry/filtered,
and the fallback when that heading is missing or stale."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from helpers import tag_images
from helpers.ros_helpers import node_command, running_process, spin_until, wait_for_subscribers
from test_tag_localizer import _camera_info_msg, _count, _image_msg, _probe_node

from ekf_localization.core.angles import quaternion_to_yaw, wrap_angle, yaw_to_quaternion
from ekf_localization.core.units import ns_to_sec_nanosec, stamp_to_ns
from ekf_localization.vision import tag_pnp

pytest.importorskip("cv2")

MS = 1_000_000
YAW_STD = math.radians(0.5)


def _odometry(stamp_ns: int, yaw: float):
    from nav_msgs.msg import Odometry

    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    msg.header.frame_id, msg.child_frame_id = "map", "base_link"
    q = msg.pose.pose.orientation
    q.x, q.y, q.z, q.w = yaw_to_quaternion(yaw)
    cov = np.zeros((6, 6))
    cov[5, 5] = YAW_STD**2
    msg.pose.covariance = cov.reshape(-1).tolist()
    return msg


@pytest.mark.parametrize("method", ["heading", "fixed_heading"])
def test_single_tag_uses_the_filters_heading_and_falls_back_without_it(ros_context, tmp_path: Path,
                                                                     method: str) -> None:
    """One tag 2 m away, max_ambiguity 0 (every unconstrained single-tag solution is refused):
    a frame before any odometry/filtered falls back and is refused as ambiguous; with two
    estimates 20 ms either side of the image's stamp, the frame gives a fix (fixed_heading: its
    yaw is the interpolated one, published as uninformative); an image 1 s after the newest
    estimate (heading_max_age 0.2 s) falls back again. /diagnostics counts the fallbacks."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image

    params, node, ex = _probe_node(ros_context, tmp_path, "tag_heading_test",
                                   f"pixel_std: 0.5\nmax_ambiguity: 0.0\nsingle_tag: {method}\n"
                                   "heading_max_age: 0.2\npublish_markers: false")
    pub_img = node.create_publisher(Image, "camera/image_raw", qos_profile_sensor_data)
    pub_info = node.create_publisher(CameraInfo, "camera/camera_info", qos_profile_sensor_data)
    pub_odom = node.create_publisher(Odometry, "odometry/filtered", 10)
    poses: list = []
    diags: list = []
    node.create_subscription(PoseWithCovarianceStamped, "camera/pose", poses.append, 10)
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: diags.extend(s for s in m.status if "tag fixes" in s.name), 10)
    truth = np.array([2.0, 1.5, 0.0, 0.0, 0.0, math.pi + 0.05])
    image = tag_images.render(truth, (1,), noise_std=tag_images.PHOTO_NOISE_STD, rng=np.random.default_rng(3),
                              blur_std=tag_images.PHOTO_BLUR_STD)
    t0, t1 = 1_000 * MS, 2_000 * MS

    def frame_counted(stamp_ns: int, key: str, target: int) -> bool:
        """Publish the frame until /diagnostics' ``key`` reaches ``target`` (best effort drops)."""
        for _ in range(5):
            pub_info.publish(_camera_info_msg(stamp_ns))
            pub_img.publish(_image_msg(image, stamp_ns))
            if spin_until(ex, lambda: bool(diags) and _count(diags[-1], key) >= target, 2.5):
                return True
        return False

    try:
        with running_process([*node_command("tag_localizer"), "--ros-args", "--params-file", str(params)],
                             tmp_path / "tag_localizer.log"):
            assert wait_for_subscribers(ex, pub_img) and wait_for_subscribers(ex, pub_info)
            assert wait_for_subscribers(ex, pub_odom)
            for _ in range(3):      # CameraInfo first: the frames below are counted as solved
                pub_info.publish(_camera_info_msg(t0))
                spin_until(ex, lambda: False, 0.2)
            # no heading yet: the fallback, refused at max_ambiguity 0
            assert frame_counted(t0, "rejected_ambiguous", 1)
            assert _count(diags[-1], "heading_fallbacks") >= 1 and _count(diags[-1], "fixes_accepted") == 0
            # the filter's yaw 20 ms either side: interpolated to the truth at the image's stamp
            pub_odom.publish(_odometry(t1 - 20 * MS, truth[5] - 0.02))
            pub_odom.publish(_odometry(t1 + 20 * MS, truth[5] + 0.02))
            assert spin_until(ex, lambda: bool(diags) and _count(diags[-1], "headings_received") == 2, 5.0)
            fallbacks = _count(diags[-1], "heading_fallbacks")
            assert frame_counted(t1, "fixes_accepted", 1), [(v.key, v.value) for v in diags[-1].values]
            assert spin_until(ex, lambda: bool(poses), 2.0)
            # stale: 1 s after the newest estimate
            rejected = _count(diags[-1], "rejected_ambiguous")
            assert frame_counted(t1 + 1_000 * MS, "rejected_ambiguous", rejected + 1)
            d = diags[-1]
    finally:
        node.destroy_node()
    assert _count(d, "heading_fallbacks") > fallbacks
    assert {v.key: v.value for v in d.values}["single_tag"] == method
    msg = poses[0]
    assert stamp_to_ns(msg.header.stamp) == t1
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    yaw = quaternion_to_yaw(q.x, q.y, q.z, q.w)
    cov = np.array(msg.pose.covariance).reshape(6, 6)
    e = np.array([p.x - truth[0], p.y - truth[1], wrap_angle(yaw - truth[5])])
    if method == "fixed_heading":
        assert abs(e[2]) < 1e-9                      # the interpolated heading, exactly
        assert cov[5, 5] == pytest.approx(tag_pnp.UNINFORMATIVE_YAW_VARIANCE)
        assert np.all(cov[5, :5] == 0.0)
    else:
        assert abs(e[2]) < math.radians(10.0)       # the solution near the heading, not its mirror
    assert np.linalg.norm(e[:2]) < 0.1
    assert float(e[:2] @ np.linalg.solve(cov[:2, :2], e[:2])) < 13.8   # χ²(2) 99.9 %
