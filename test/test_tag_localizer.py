"""tag_localizer: images -> pose over DDS, bad images counted, bad parameters exit 2, the image reader."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from helpers import tag_images
from helpers.ros_helpers import (
    REPO,
    node_command,
    running_process,
    spin_until,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.angles import quaternion_to_rpy, rpy_to_quaternion
from ekf_localization.core.units import ns_to_sec_nanosec, stamp_to_ns
from ekf_localization.ros import markers
from ekf_localization.ros.image_io import BadImageError, camera_info_to_pinhole, image_to_mono8
from ekf_localization.ros.parameters import ParameterError
from ekf_localization.ros.tag_localizer_parameters import parse_settings
from ekf_localization.vision import tag_pnp
from ekf_localization.vision.corner_noise import CornerNoise

pytest.importorskip("cv2")


def _layout_file(tmp_path: Path) -> Path:
    path = tmp_path / "tags.yaml"
    path.write_text(yaml.safe_dump(tag_images.LAYOUT_DICT))
    return path


def _image_msg(pixels: np.ndarray, stamp_ns: int, frame: str = "camera_optical", **change):
    from sensor_msgs.msg import Image

    msg = Image()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    msg.header.frame_id = frame
    msg.height, msg.width = pixels.shape
    msg.encoding, msg.step = "mono8", pixels.shape[1]
    msg.data = pixels.tobytes()
    for k, v in change.items():
        setattr(msg, k, v)
    return msg


def _camera_info_msg(stamp_ns: int):
    from sensor_msgs.msg import CameraInfo

    cam = tag_images.CAMERA
    msg = CameraInfo()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    msg.header.frame_id = "camera_optical"
    msg.width, msg.height = cam.width, cam.height
    msg.distortion_model = "plumb_bob"
    msg.d = [0.0] * 5
    msg.k = [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0]
    return msg


def _static_mount_tf():
    from tf2_msgs.msg import TFMessage

    return TFMessage(transforms=[_tf("base_link", "camera_optical", tag_images.mount(), 0)])


def _probe_node(ros_context, tmp_path: Path, name: str, params: str):
    """tag_localizer's parameter file (the test layout plus ``params``, YAML lines) and a probe
    node with its executor that has published the camera mount on /tf_static."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from tf2_msgs.msg import TFMessage

    from ekf_localization.ros.tf_io import TF_STATIC_QOS

    path = tmp_path / "tag.yaml"
    path.write_text(f"tag_localizer:\n  ros__parameters:\n    layout_file: {_layout_file(tmp_path)}\n"
                    + "".join(f"    {line}\n" for line in params.splitlines()))
    node = Node(name, context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    node.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS).publish(_static_mount_tf())
    return path, node, ex


# --- ROS-free parts ---------------------------------------------------------------------------------


def test_image_reader_rejects_bad_images_with_their_reason() -> None:
    ok = SimpleNamespace(encoding="mono8", height=2, width=3, step=3, data=bytes(range(6)))
    np.testing.assert_array_equal(image_to_mono8(ok), [[0, 1, 2], [3, 4, 5]])
    rgb = SimpleNamespace(encoding="bgr8", height=1, width=1, step=4, data=bytes([0, 0, 255, 9]))
    assert image_to_mono8(rgb)[0, 0] == round(0.299 * 255)        # red, stride with padding
    cases = {"bad_encoding": dict(encoding="16UC1"), "empty_image": dict(height=0),
             "truncated_image": dict(data=bytes(5)), "bad_size": dict(width=10**6, step=10**6)}
    for reason, change in cases.items():
        with pytest.raises(BadImageError) as e:
            image_to_mono8(SimpleNamespace(**{**vars(ok), **change}))
        assert e.value.reason == reason
    with pytest.raises(BadImageError) as e:
        image_to_mono8(SimpleNamespace(**{**vars(ok), "step": 2}))
    assert e.value.reason == "truncated_image"


def test_camera_info_reader() -> None:
    good = SimpleNamespace(k=[500.0, 0, 320, 0, 500.0, 240, 0, 0, 1], d=[0.1, 0, 0, 0, 0], width=640,
                           height=480, distortion_model="plumb_bob")
    cam = camera_info_to_pinhole(good)
    assert (cam.fx, cam.cy, cam.distortion[0]) == (500.0, 240, 0.1)
    for change in (dict(k=[0.0] * 9), dict(k=[1.0] * 8), dict(d=[math.nan]), dict(width=0),
                   dict(distortion_model="equidistant")):
        with pytest.raises(BadImageError) as e:
            camera_info_to_pinhole(SimpleNamespace(**{**vars(good), **change}))
        assert e.value.reason == "bad_camera_info"


def test_parameters_name_the_bad_one(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match="layout_file"):
        parse_settings({})
    with pytest.raises(ParameterError, match="layout_file"):
        parse_settings({"layout_file": str(tmp_path / "missing.yaml")})
    with pytest.raises(ParameterError, match="max_ambiguity"):
        parse_settings({"layout_file": str(_layout_file(tmp_path)), "max_ambiguity": -1.0})
    s = parse_settings({"layout_file": str(_layout_file(tmp_path))})
    assert sorted(s.layout.tags) == [1, 2, 3] and s.pose_topic == "camera/pose"


def test_bad_parameter_file_exits_2_naming_it(tmp_path: Path) -> None:
    params = tmp_path / "p.yaml"
    params.write_text(f"tag_localizer:\n  ros__parameters:\n    layout_file: {_layout_file(tmp_path)}\n"
                      "    pixel_std: -1.0\n")
    res = subprocess.run([*node_command("tag_localizer"), "--ros-args", "--params-file", str(params)],
                         capture_output=True, text=True, timeout=60, cwd=str(REPO))
    assert res.returncode == 2, res.stderr
    assert "pixel_std" in res.stderr and "Traceback" not in res.stderr + res.stdout


# --- over DDS ---------------------------------------------------------------------------------------


def test_images_to_poses_and_bad_images_over_dds(ros_context, tmp_path: Path) -> None:
    """Rendered images -> camera/pose at the truth within its covariance, stamped at capture, in
    map; bad images, a missing CameraInfo and an unknown tag are counted on /diagnostics; ~/markers
    draws the camera's field of view in base_link and the layout tags it saw in map."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PolygonStamped, PoseWithCovarianceStamped
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image
    from visualization_msgs.msg import MarkerArray

    params, node, ex = _probe_node(ros_context, tmp_path, "tag_test",
                                   "pixel_std: 0.5\npublish_corners: true\nfov_marker_reach: 1.5")
    pub_img = node.create_publisher(Image, "camera/image_raw", qos_profile_sensor_data)
    pub_info = node.create_publisher(CameraInfo, "camera/camera_info", qos_profile_sensor_data)
    poses: list = []
    diags: list = []
    sub_pose = node.create_subscription(PoseWithCovarianceStamped, "camera/pose", poses.append, 10)
    corners: list = []
    node.create_subscription(PolygonStamped, "tag_corners/tag_2", corners.append, qos_profile_sensor_data)
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: diags.extend(s for s in m.status if "tag fixes" in s.name), 10)
    marker_arrays: list = []
    node.create_subscription(MarkerArray, "tag_localizer/markers", marker_arrays.append, 50)
    rng = np.random.default_rng(5)
    truths = [np.array([1.6 + 0.05 * k, 1.8 + 0.03 * k, 0.0, 0.0, 0.0, math.pi + 0.04 * k]) for k in range(6)]
    images = [tag_images.render(t, (1, 2, 3), noise_std=2.0, rng=rng) for t in truths]
    try:
        with running_process([*node_command("tag_localizer"), "--ros-args", "--params-file", str(params)],
                             tmp_path / "tag_localizer.log"):
            assert wait_for_subscribers(ex, pub_img) and wait_for_subscribers(ex, pub_info)
            assert wait_for_publishers(ex, sub_pose)
            t0 = 1_000_000_000
            sent: dict[str, int] = {}

            def until_counted(msg, key: str) -> None:
                """Best-effort transport may drop a message: publish until the counter moves."""
                before = _count(diags[-1], key) if diags else 0
                for _ in range(5):
                    pub_img.publish(msg)
                    sent[key] = sent.get(key, 0) + 1
                    if spin_until(ex, lambda: bool(diags) and _count(diags[-1], key) > before, 2.5):
                        return

            # an image before any CameraInfo: no_camera_info
            until_counted(_image_msg(images[0], t0), "rejected_no_camera_info")
            for k, image in enumerate(images):
                for _ in range(5):
                    pub_info.publish(_camera_info_msg(t0 + k * 50_000_000))
                    pub_img.publish(_image_msg(image, t0 + k * 50_000_000))
                    if spin_until(ex, lambda k=k: len(poses) > k, 2.5):
                        break
            assert len(poses) == len(images)
            # bad images: wrong encoding, zero size, truncated data
            until_counted(_image_msg(images[0], t0, encoding="16UC1"), "rejected_bad_encoding")
            until_counted(_image_msg(images[0][:0], t0), "rejected_empty_image")
            until_counted(_image_msg(images[0], t0, data=images[0].tobytes()[:1000]),
                          "rejected_truncated_image")
            received = _count(diags[-1], "frames_received")
            spin_until(ex, lambda: _count(diags[-1], "frames_received") > received, 1.5)  # one more period
    finally:
        node.destroy_node()
    d = diags[-1]
    assert _count(d, "fixes_accepted") == len(images)
    assert _count(d, "frames_received") == _count(d, "fixes_accepted") + _count(d, "fixes_rejected")
    for key in ("rejected_no_camera_info", "rejected_bad_encoding", "rejected_empty_image",
                "rejected_truncated_image"):
        assert 1 <= _count(d, key) <= sent[key], (key, [(v.key, v.value) for v in d.values])
    nees = []
    for msg, truth, k in zip(poses, truths, range(len(poses)), strict=True):
        assert msg.header.frame_id == "map"
        assert stamp_to_ns(msg.header.stamp) == 1_000_000_000 + k * 50_000_000
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        est = np.array([p.x, p.y, p.z, *quaternion_to_rpy(q.x, q.y, q.z, q.w)])
        e = est - truth
        e[3:] = (e[3:] + math.pi) % (2 * math.pi) - math.pi
        assert np.linalg.norm(e[:2]) < 0.02
        cov = np.array(msg.pose.covariance).reshape(6, 6)
        nees.append(float(e @ np.linalg.solve(cov, e)))
    # publish_corners: tag 2's corners, stamped at capture, within a pixel of the projection
    assert corners, "no tag_corners/tag_2"
    c = corners[0]
    k = (stamp_to_ns(c.header.stamp) - 1_000_000_000) // 50_000_000
    assert c.header.frame_id == "camera_optical" and 0 <= k < len(truths)
    uv = np.array([[p.x, p.y] for p in c.polygon.points])
    assert np.abs(uv - tag_images.project_tag(truths[k], 2)).max() < 1.5
    # ~/markers: the field of view (the camera's own wedge, tests/test_tag_pnp.py) and tags 1-3
    fov = [markers.points_of(m, markers.NS_CAMERA_FOV) for m in marker_arrays]
    seen = [markers.points_of(m, markers.NS_TAGS_SEEN) for m in marker_arrays]
    assert fov and fov[0] is not None and seen[0] is not None, "no tag_localizer/markers"
    frames = {mk.ns: mk.header.frame_id for mk in marker_arrays[0].markers}
    assert frames == {markers.NS_CAMERA_FOV: "base_link", markers.NS_TAGS_SEEN: "map"}
    np.testing.assert_allclose(fov[0], tag_images.CAMERA.floor_wedge(tag_images.mount(), 1.5), atol=1e-9)
    layout_xy = {t["id"]: t["position"][:2] for t in tag_images.LAYOUT_DICT["tags"]}
    assert any(sorted(map(tuple, s)) == sorted(map(tuple, layout_xy.values())) for s in seen), seen
    # six fixes: the sum of their NEES is chi2(36) if the covariance is honest (99.9 % bound)
    from scipy.stats import chi2
    assert sum(nees) < chi2.ppf(0.999, 6 * len(nees)), nees


def _count(status, key: str) -> int:
    return next((int(v.value) for v in status.values if v.key == key), 0)


def _opencv_before_4_7() -> bool:
    import cv2

    return tuple(int(v) for v in cv2.__version__.split(".")[:2]) < (4, 7)


# Ubuntu 24.04's python3-opencv is OpenCV 4.6: its aruco finds none of this scene's three tags
# (1.2-2.2 m, ~50 px; 7 candidates rejected at decoding, with every DetectorParameters tried,
# 2026-12-06) where 4.7+ finds all three: tag_localizer's default detector (apriltag) is the one
# for a stock Jazzy robot (docs/apriltags.md). Strict: passing there fails, and says so.
OPENCV_46_MISSES = pytest.mark.xfail(condition=_opencv_before_4_7(), strict=True,
                                     reason="OpenCV 4.6's aruco does not decode these tags")


@pytest.mark.parametrize("detector", [pytest.param("opencv", marks=OPENCV_46_MISSES)])
def test_pnp_fix_from_a_rendered_image_is_within_a_centimetre(detector: str) -> None:
    """The rendered image through OpenCV's detector and PnP, without the node (a reference for
    the DDS test). The AprilRobotics detector is held to its corner noise over many poses
    instead (next test): one frame's error is a draw of that noise, not a bound."""
    from ekf_localization.vision.detectors import make_detector

    truth = np.array([1.6, 1.8, 0.0, 0.0, 0.0, math.pi + 0.1])
    dets = make_detector(detector).detect(tag_images.render(truth, (1, 2, 3)))
    fix, unknown = tag_pnp.localize(dets, tag_images.LAYOUT, tag_images.CAMERA, tag_images.mount(),
                                    CornerNoise(0.5))
    assert isinstance(fix, tag_pnp.TagFix) and unknown == ()
    assert np.linalg.norm(fix.pose[:3] - truth[:3]) < 0.01


def test_pnp_fixes_from_rendered_images_agree_with_the_corner_noise() -> None:
    """The shipped detector and PnP on 40 still frames with the real photographs' noise and
    lens blur (tag_images.PHOTO_*): each gives a fix, and their mean 3-D position NEES against
    the covariance of config/tag_localizer.yaml's corner noise (still camera: no motion blur)
    is below the 99 % top of the mean of 40 independent χ²(3) values (the NEES is ~0.8 here). A
    corner order or camera model that disagrees with the renderer fails it (a focal length 2 %
    off gives a mean over 1000); the AprilRobotics library also checks the test renderer's
    corner order. The residual check widens a covariance whose corners scatter more than the
    model says, so this bounds the fixes' honesty rather than the noise constants."""
    from ekf_localization.core.chi2_bands import chi2_quantile
    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.vision.detectors import make_detector

    shipped = parse_settings(parameters_from_yaml(REPO / "config" / "tag_localizer.yaml", "tag_localizer"))
    n = shipped.corner_noise
    noise = CornerNoise(n.pixel_std, n.tag_shift_std, n.blur_std_per_px, n.exposure_time, 0.0)
    detector, rng, nees = make_detector("apriltag"), np.random.default_rng(7), []
    for _ in range(40):
        truth = np.array([1.6 + rng.uniform(-0.3, 0.4), 1.8 + rng.uniform(-0.3, 0.3), 0.0, 0.0, 0.0,
                          math.pi + rng.uniform(-0.15, 0.15)])
        image = tag_images.render(truth, (1, 2, 3), noise_std=tag_images.PHOTO_NOISE_STD, rng=rng,
                                  blur_std=tag_images.PHOTO_BLUR_STD)
        fix, unknown = tag_pnp.localize(detector.detect(image), tag_images.LAYOUT, tag_images.CAMERA,
                                        tag_images.mount(), noise)
        assert isinstance(fix, tag_pnp.TagFix) and unknown == (), fix
        e = fix.pose[:3] - truth[:3]
        nees.append(float(e @ np.linalg.solve(fix.covariance[:3, :3], e)))
    top = chi2_quantile(0.99, 3 * len(nees)) / len(nees)
    assert np.mean(nees) < top, (np.mean(nees), top, np.round(nees, 2))


def _tf(parent: str, child: str, T: np.ndarray, stamp_ns: int):
    from geometry_msgs.msg import TransformStamped

    from ekf_localization.core.angles import matrix_to_rpy

    t = TransformStamped()
    t.header.stamp.sec, t.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    t.header.frame_id, t.child_frame_id = parent, child
    tr = t.transform.translation
    tr.x, tr.y, tr.z = (float(v) for v in T[:3, 3])
    r = t.transform.rotation
    r.x, r.y, r.z, r.w = rpy_to_quaternion(*matrix_to_rpy(T[:3, :3]))
    return t


def test_apriltag_ros_tf_frames_to_pose_over_dds(ros_context, tmp_path: Path) -> None:
    """mode tf: camera_optical -> tag36h11:<id> on /tf (apriltag_ros's frames: x right, y down,
    z into the tag) plus the layout -> camera/pose at the truth, stamped as the tag frames."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from tf2_msgs.msg import TFMessage

    params, node, ex = _probe_node(ros_context, tmp_path, "tag_tf_test",
                                   "mode: tf\ncamera_frame: camera_optical\ntf_max_age: 1.0")
    pub_tf = node.create_publisher(TFMessage, "/tf",
                                   QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    poses: list = []
    sub = node.create_subscription(PoseWithCovarianceStamped, "camera/pose", poses.append, 10)
    truth = np.array([1.5, 1.7, 0.0, 0.0, 0.0, math.pi - 0.05])
    T_map_cam = tag_pnp.pose_matrix(truth) @ tag_images.mount()
    at_in_tag = np.eye(4)
    at_in_tag[:3, :3] = [[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]  # x=+y, y=-z, z=-x
    try:
        with running_process([*node_command("tag_localizer"), "--ros-args", "--params-file", str(params)],
                             tmp_path / "tag_localizer.log"):
            assert wait_for_subscribers(ex, pub_tf) and wait_for_publishers(ex, sub)
            stamps = []
            for _ in range(20):
                stamp = node.get_clock().now().nanoseconds
                msg = TFMessage(transforms=[
                    _tf("camera_optical", f"tag36h11:{i}",
                        np.linalg.inv(T_map_cam) @ tag_images.LAYOUT.tags[i].pose_in_map @ at_in_tag, stamp)
                    for i in (1, 2)])
                pub_tf.publish(msg)
                stamps.append(stamp)
                if spin_until(ex, lambda: bool(poses), 0.5):
                    break
    finally:
        node.destroy_node()
    assert poses, "no pose from the TF tag frames"
    msg = poses[0]
    assert stamp_to_ns(msg.header.stamp) in stamps and msg.header.frame_id == "map"
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    assert math.hypot(p.x - truth[0], p.y - truth[1]) < 1e-6
    yaw = quaternion_to_rpy(q.x, q.y, q.z, q.w)[2]
    assert abs((yaw - truth[5] + math.pi) % (2 * math.pi) - math.pi) < 1e-6


def _diagonal15(values: dict[int, float]) -> list[float]:
    m = np.zeros((15, 15))
    for i, v in values.items():
        m[i, i] = v
    return m.ravel().tolist()


def test_images_to_tag_localizer_to_ekf_node_over_dds(ros_context, tmp_path: Path) -> None:
    """Rendered images -> tag_localizer -> camera/pose -> ekf_node (pose0, x y yaw) ->
    odometry/filtered at the truth: the pose message is what ekf_node fuses, no edit between."""
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image

    ekf = {"model": "mecanum", "world_frame": "map", "frequency": 50.0, "publish_tf": False,
           "initial_estimate_covariance": _diagonal15({0: 4.0, 1: 4.0, 5: 4.0, 6: 1e-6, 7: 1e-6, 11: 1e-6}),
           "process_noise_covariance": _diagonal15({0: 1e-6, 1: 1e-6, 5: 1e-6, 6: 1e-4, 7: 1e-4, 11: 1e-4}),
           "pose0": "camera/pose",
           "pose0_config": [True, True, False, False, False, True] + [False] * 9}
    ekf_params = tmp_path / "ekf.yaml"
    ekf_params.write_text(yaml.safe_dump({"ekf_node": {"ros__parameters": ekf}}))
    tag_params, node, ex = _probe_node(ros_context, tmp_path, "tag_ekf_test", "")
    pub_img = node.create_publisher(Image, "camera/image_raw", qos_profile_sensor_data)
    pub_info = node.create_publisher(CameraInfo, "camera/camera_info", qos_profile_sensor_data)
    outputs: list[Odometry] = []
    node.create_subscription(Odometry, "odometry/filtered", outputs.append, 100)
    truth = np.array([1.7, 1.9, 0.0, 0.0, 0.0, math.pi + 0.05])
    image = tag_images.render(truth, (1, 2, 3), noise_std=2.0)
    tag_log, ekf_log = tmp_path / "tag_localizer.log", tmp_path / "ekf.log"
    try:
        with running_process([*node_command("tag_localizer"), "--ros-args", "--params-file", str(tag_params)],
                             tag_log), \
             running_process([*node_command("ekf_node"), "--ros-args", "--params-file", str(ekf_params)],
                             ekf_log) as ekf_proc:
            assert wait_for_subscribers(ex, pub_img, timeout=60.0), tag_log.read_text()

            def converged() -> bool:
                if not outputs:
                    return False
                p = outputs[-1].pose.pose.position
                return math.hypot(p.x - truth[0], p.y - truth[1]) < 0.02

            for _ in range(100):                      # 10 Hz camera for up to 10 s
                now = node.get_clock().now().nanoseconds
                pub_info.publish(_camera_info_msg(now))
                pub_img.publish(_image_msg(image, now))
                if spin_until(ex, converged, 0.1):
                    break
            assert converged(), (outputs[-1].pose.pose if outputs else None, tag_log.read_text())
            q = outputs[-1].pose.pose.orientation
            yaw = quaternion_to_rpy(q.x, q.y, q.z, q.w)[2]
            assert abs((yaw - truth[5] + math.pi) % (2 * math.pi) - math.pi) < 0.02
            assert ekf_proc.poll() is None and "Traceback" not in ekf_log.read_text() + tag_log.read_text()
    finally:
        ex.shutdown()
        node.destroy_node()


def test_shipped_config_parses() -> None:
    """config/tag_localizer.yaml (its layout: config/tags/ftc_seed000.yaml, the simulator's field)."""
    from ekf_localization.ros.parameters import parameters_from_yaml

    s = parse_settings(parameters_from_yaml(REPO / "config" / "tag_localizer.yaml", "tag_localizer"))
    assert s.layout.tags and s.pose_topic == "camera/pose" and s.mode == "images"
