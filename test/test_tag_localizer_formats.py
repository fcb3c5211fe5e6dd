"""tag_localizer reads the formats robots send: CompressedImage (JPEG, PNG), mono16, yuv422 (UYVY)
and yuv422_yuy2 (YUYV) give the poses of the same image sent as mono8, over DDS; bad images are
counted; ``stamp_offset`` shifts the pose's stamp by exactly its nanoseconds."""

from __future__ import annotations

import dataclasses
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
from test_tag_localizer import (
    _camera_info_msg,
    _count,
    _image_msg,
    _layout_file,
    _probe_node,
    _static_mount_tf,
    _tf,
)

from ekf_localization.core.angles import quaternion_to_rpy
from ekf_localization.core.units import ns_to_sec_nanosec, stamp_to_ns
from ekf_localization.ros.image_io import BadImageError, compressed_to_mono8, image_to_mono8
from ekf_localization.ros.parameters import ParameterError
from ekf_localization.ros.tag_localizer_parameters import parse_settings

cv2 = pytest.importorskip("cv2")

# The pixel noise of the test images (grey levels) and the corner std it causes in the
# AprilRobotics detector: measured over 30 noise draws of the scene at 1.6, 1.8 (0.063 px).
IMAGE_NOISE = 2.0
CORNER_STD_OF_THE_NOISE = 0.063
JPEG_QUALITY = 95
STAMP_OFFSET_S = -0.0123456789   # -12_345_678.9 ns, rounded to the nearest: -12_345_679 ns
STAMP_OFFSET_NS = -12_345_679
CHI2_6_999 = 22.458  # chi2(6)'s 99.9 % quantile
# The tag tests' camera cropped to its middle 240 rows (the tags sit in rows 224-305): a mono16 or
# yuv422 frame is then as large as a full mono8 one, which best-effort DDS delivers under load.
CROP = dataclasses.replace(tag_images.CAMERA, height=240, cy=tag_images.CAMERA.cy - 120)


# --- the encodings: one grey image in each -----------------------------------------------------


def mono16(grey: np.ndarray, rng: np.random.Generator, big_endian: bool, pad: int = 0) -> dict:
    """Image fields of ``grey`` as mono16: grey in the high byte, random low bits, rows of ``pad``
    extra bytes."""
    h, w = grey.shape
    values = (grey.astype(np.uint16) << 8) | rng.integers(0, 256, grey.shape, dtype=np.uint16)
    rows = np.zeros((h, 2 * w + pad), dtype=np.uint8)
    rows[:, : 2 * w] = values.astype(">u2" if big_endian else "<u2").view(np.uint8).reshape(h, 2 * w)
    return dict(encoding="mono16", is_bigendian=int(big_endian), step=2 * w + pad, data=rows.tobytes())


def yuv422(grey: np.ndarray, rng: np.random.Generator, yuyv: bool) -> dict:
    """Image fields of ``grey`` as packed YUV 4:2:2 with random chroma: UYVY (``yuv422``, Y at the
    odd bytes) or YUYV (``yuv422_yuy2``, Y at the even bytes)."""
    h, w = grey.shape
    rows = rng.integers(0, 256, (h, 2 * w), dtype=np.uint8)
    rows[:, (0 if yuyv else 1)::2] = grey
    return dict(encoding="yuv422_yuy2" if yuyv else "yuv422", step=2 * w, data=rows.tobytes())


def test_each_encoding_gives_back_the_grey_image() -> None:
    rng = np.random.default_rng(3)
    grey = rng.integers(0, 256, (5, 6), dtype=np.uint8)
    base = dict(height=5, width=6, is_bigendian=0)
    for fields in (mono16(grey, rng, False), mono16(grey, rng, True), mono16(grey, rng, False, pad=7),
                   yuv422(grey, rng, False), yuv422(grey, rng, True)):
        np.testing.assert_array_equal(image_to_mono8(SimpleNamespace(**{**base, **fields})), grey)
    # mono16 is scaled by >> 8 (65535 -> 255, 256 -> 1, 255 -> 0)
    m16 = SimpleNamespace(**{**base, **mono16(grey, rng, False)})
    m16.data = np.array([[65535, 256, 255, 0, 1, 32768]] * 5, dtype="<u2").tobytes()
    assert image_to_mono8(m16)[0].tolist() == [255, 1, 0, 0, 0, 128]
    png16 = cv2.imencode(".png", np.frombuffer(m16.data, "<u2").reshape(5, 6))[1]   # OpenCV's 16 -> 8 bits
    np.testing.assert_array_equal(compressed_to_mono8(SimpleNamespace(format="mono16; png", data=png16)),
                                  image_to_mono8(m16))
    for ext in (".png", ".jpg"):
        data = cv2.imencode(ext, grey)[1].tobytes()
        out = compressed_to_mono8(SimpleNamespace(format=ext[1:], data=data))
        assert out.shape == grey.shape and (ext == ".jpg" or np.array_equal(out, grey))
    colour = cv2.imencode(".png", np.dstack([grey] * 3))[1]           # bgr8; png: decoded to grey
    np.testing.assert_array_equal(compressed_to_mono8(SimpleNamespace(format="bgr8; png", data=colour)), grey)


def test_bad_images_name_their_reason() -> None:
    grey = np.zeros((4, 6), dtype=np.uint8)
    ok = dict(height=4, width=6, is_bigendian=0)
    cases = {"bad_encoding": dict(encoding="bayer_rggb8", step=6, data=bytes(24)),
             "truncated_image": dict(encoding="yuv422", step=11, data=bytes(44)),   # step < 2 x width
             "bad_data_size": dict(encoding="mono16", step=12, data=bytes(49))}     # step x height is 48
    for reason, fields in cases.items():
        with pytest.raises(BadImageError) as e:
            image_to_mono8(SimpleNamespace(**ok, **fields))
        assert e.value.reason == reason
    jpeg = cv2.imencode(".jpg", grey)[1].tobytes()
    compressed = {"corrupt_image": dict(format="jpeg", data=jpeg[: len(jpeg) // 2]),
                  "empty_image": dict(format="jpeg", data=b""),
                  "bad_encoding": dict(format="16UC1; compressedDepth png", data=jpeg)}
    for reason, fields in compressed.items():
        with pytest.raises(BadImageError) as e:
            compressed_to_mono8(SimpleNamespace(**fields))
        assert e.value.reason == reason


def test_stamp_offset_and_image_transport_are_validated(tmp_path: Path) -> None:
    layout = str(_layout_file(tmp_path))
    for bad in (math.nan, math.inf, 11.0):
        with pytest.raises(ParameterError, match="stamp_offset"):
            parse_settings({"layout_file": layout, "stamp_offset": bad})
    with pytest.raises(ParameterError, match="image_transport"):
        parse_settings({"layout_file": layout, "image_transport": "theora"})
    s = parse_settings({"layout_file": layout, "stamp_offset": STAMP_OFFSET_S})
    assert s.stamp_offset_ns == STAMP_OFFSET_NS and s.image_transport == "raw"
    params = tmp_path / "p.yaml"
    params.write_text(f"tag_localizer:\n  ros__parameters:\n    layout_file: {layout}\n"
                      "    stamp_offset: .nan\n")
    res = subprocess.run([*node_command("tag_localizer"), "--ros-args", "--params-file", str(params)],
                         capture_output=True, text=True, timeout=60, cwd=str(REPO))
    assert res.returncode == 2, res.stderr
    assert "stamp_offset" in res.stderr and "Traceback" not in res.stderr + res.stdout


# --- over DDS ----------------------------------------------------------------------------------


def _compressed_msg(data: bytes, fmt: str, stamp_ns: int):
    from sensor_msgs.msg import CompressedImage

    msg = CompressedImage(format=fmt, data=data)
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    msg.header.frame_id = "camera_optical"
    return msg


def _crop_camera_info(stamp_ns: int):
    msg = _camera_info_msg(stamp_ns)
    msg.height, msg.k[5] = CROP.height, CROP.cy
    return msg


def _pose_vector(msg) -> np.ndarray:
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return np.array([p.x, p.y, p.z, *quaternion_to_rpy(q.x, q.y, q.z, q.w)])


def _wrapped(d: np.ndarray) -> np.ndarray:
    d = d.copy()
    d[3:] = (d[3:] + math.pi) % (2 * math.pi) - math.pi
    return d


RAW_VARIANTS = ("mono8", "mono16", "mono16_bigendian_padded", "yuv422", "yuv422_yuy2")
COMPRESSED_VARIANTS = ("png", "jpeg")
T0_NS = 2_000_000_000


class _Frames:
    """The test's rendered frames in every encoding, one stamp per frame and encoding."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.truths = [np.array([1.6 + 0.06 * k, 1.8 + 0.04 * k, 0.0, 0.0, 0.0, math.pi + 0.05 * k])
                       for k in range(4)]
        self.greys = [tag_images.render(t, (1, 2, 3), camera=CROP, noise_std=IMAGE_NOISE, rng=rng)
                      for t in self.truths]

    @staticmethod
    def stamp(k: int, variant: str) -> int:
        return T0_NS + k * 1_000_000_000 + (RAW_VARIANTS + COMPRESSED_VARIANTS).index(variant) * 1_000_000

    def message(self, k: int, variant: str):
        grey, t = self.greys[k], self.stamp(k, variant)
        if variant == "png":
            return _compressed_msg(cv2.imencode(".png", grey)[1].tobytes(), "mono8; png compressed mono8", t)
        if variant == "jpeg":
            data = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1].tobytes()
            return _compressed_msg(data, "mono8; jpeg compressed mono8", t)
        fields = {"mono8": {}, "mono16": mono16(grey, self.rng, False),
                  "mono16_bigendian_padded": mono16(grey, self.rng, True, pad=64),
                  "yuv422": yuv422(grey, self.rng, False), "yuv422_yuy2": yuv422(grey, self.rng, True)}
        return _image_msg(grey, t, **fields[variant])

    def bad_messages(self) -> dict:
        """(node, counter) -> a bad image that node counts there."""
        grey = self.greys[0]
        small = np.ascontiguousarray(grey[::2, ::2])
        uyvy_short_step = {**yuv422(grey, self.rng, False), "step": grey.shape[1]}
        jpeg = cv2.imencode(".jpg", grey)[1].tobytes()
        return {("tag_raw", "rejected_bad_encoding"): _image_msg(grey, T0_NS, encoding="bayer_rggb8"),
                ("tag_raw", "rejected_bad_data_size"): _image_msg(grey, T0_NS,
                                                                  data=grey.tobytes() + bytes(7)),
                ("tag_raw", "rejected_truncated_image"): _image_msg(grey, T0_NS, **uyvy_short_step),
                ("tag_raw", "rejected_camera_info_mismatch"): _image_msg(small, T0_NS),
                ("tag_compressed", "rejected_corrupt_image"): _compressed_msg(jpeg[: len(jpeg) // 2], "jpeg",
                                                                              T0_NS),
                ("tag_compressed", "rejected_camera_info_mismatch"): _compressed_msg(
                    cv2.imencode(".png", small)[1].tobytes(), "png", T0_NS)}


def _kind(variant: str) -> str:
    return "compressed" if variant in COMPRESSED_VARIANTS else "raw"


def _node_commands(tmp_path: Path) -> dict[str, list[str]]:
    """tag_raw (image_transport raw, stamp_offset) and tag_compressed: the test layout, pixel_std of
    the image noise's corners, poses on pose_raw and pose_compressed."""
    layout = _layout_file(tmp_path)
    commands = {}
    for name, extra in (("tag_raw", {"stamp_offset": STAMP_OFFSET_S, "pose_topic": "pose_raw"}),
                        ("tag_compressed", {"image_transport": "compressed",
                                            "pose_topic": "pose_compressed"})):
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
            "layout_file": str(layout), "pixel_std": CORNER_STD_OF_THE_NOISE, "publish_markers": False,
            **extra}}}))
        commands[name] = [*node_command("tag_localizer"), "--ros-args", "-r", f"__node:={name}",
                          "--params-file", str(path)]
    return commands


def test_formats_give_the_mono8_poses_over_dds(ros_context, tmp_path: Path) -> None:
    """Two tag_localizers, image_transport raw (stamp_offset -0.0123456789 s) and compressed, on the
    same rendered frames: every encoding's pose equals mono8's (PNG too: lossless), the JPEG's lies
    within the corner noise of the image's own pixel noise; the pose stamp is the image's plus
    exactly -12345679 ns; before CameraInfo /diagnostics says so and no pose is published; bad
    images are counted by reason and both nodes keep publishing poses."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, CompressedImage, Image
    from tf2_msgs.msg import TFMessage

    from ekf_localization.ros.tf_io import TF_STATIC_QOS

    commands = _node_commands(tmp_path)
    node = Node("tag_formats_test", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    node.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS).publish(_static_mount_tf())
    pubs = {"raw": node.create_publisher(Image, "camera/image_raw", qos_profile_sensor_data),
            "compressed": node.create_publisher(CompressedImage, "camera/image_raw/compressed",
                                                qos_profile_sensor_data)}
    pub_info = node.create_publisher(CameraInfo, "camera/camera_info", qos_profile_sensor_data)
    poses: dict[str, dict[int, PoseWithCovarianceStamped]] = {"raw": {}, "compressed": {}}
    subs = [node.create_subscription(
        PoseWithCovarianceStamped, f"pose_{kind}",
        lambda m, kind=kind: poses[kind].setdefault(stamp_to_ns(m.header.stamp), m), 50) for kind in poses]
    diags: dict[str, list] = {"tag_raw": [], "tag_compressed": []}
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: [
        diags[st.name.split(":")[0]].append(st) for st in msg.status if st.name.split(":")[0] in diags], 20)
    frames = _Frames(np.random.default_rng(11))

    def pose_of(variant: str, k: int):
        offset = STAMP_OFFSET_NS if _kind(variant) == "raw" else 0
        return poses[_kind(variant)].get(frames.stamp(k, variant) + offset)

    def send_until(kind: str, msg, done, info_stamp_ns: int) -> bool:
        """Best-effort transport may drop a message: CameraInfo and ``msg`` until ``done()``."""
        for _ in range(5):
            pub_info.publish(_crop_camera_info(info_stamp_ns))
            pubs[kind].publish(msg)
            if spin_until(ex, done, 2.5):
                return True
        return False

    def counted(name: str, key: str) -> int:
        return _count(diags[name][-1], key) if diags[name] else 0

    procs = {}
    try:
        with running_process(commands["tag_raw"], tmp_path / "tag_raw.log") as procs["tag_raw"], \
             running_process(commands["tag_compressed"],
                             tmp_path / "tag_compressed.log") as procs["tag_compressed"]:
            assert all(wait_for_subscribers(ex, pub, timeout=60.0) for pub in pubs.values())
            assert all(wait_for_publishers(ex, sub) for sub in subs)
            # no CameraInfo yet: a clear message, the frames counted, no pose
            for _ in range(10):
                pubs["raw"].publish(frames.message(0, "mono8"))
                pubs["compressed"].publish(frames.message(0, "png"))
                if spin_until(ex, lambda: all(counted(n, "rejected_no_camera_info") for n in diags), 1.5):
                    break
            for name, d in diags.items():
                assert counted(name, "rejected_no_camera_info") >= 1, name
                assert "no valid CameraInfo on /camera/camera_info" in d[-1].message, d[-1].message
                assert d[-1].level == DiagnosticStatus.WARN
            assert not poses["raw"] and not poses["compressed"]
            # each frame in every encoding
            for k in range(len(frames.greys)):
                for v in RAW_VARIANTS + COMPRESSED_VARIANTS:
                    got = send_until(_kind(v), frames.message(k, v),
                                     lambda k=k, v=v: pose_of(v, k) is not None, frames.stamp(k, v))
                    assert got, (v, k, [(x.key, x.value) for x in diags[f"tag_{_kind(v)}"][-1].values])
            # bad images: counted by reason
            for (name, key), msg in frames.bad_messages().items():
                before = counted(name, key)
                assert send_until(name[4:], msg, lambda n=name, k=key, b=before: counted(n, k) > b, T0_NS), \
                    (name, key, [(v.key, v.value) for v in diags[name][-1].values])
            # still running: a good frame gives its pose
            for v in ("mono8", "jpeg"):
                n, msg = len(poses[_kind(v)]), frames.message(1, v)
                msg.header.stamp.sec += 100
                assert send_until(_kind(v), msg, lambda v=v, n=n: len(poses[_kind(v)]) > n, 0), v
            for name, proc in procs.items():
                assert proc.poll() is None, name
    finally:
        ex.shutdown()
        node.destroy_node()
    for name in procs:
        assert "Traceback" not in (tmp_path / f"{name}.log").read_text(), name
    jpeg_rms = []
    for k, (truth, grey) in enumerate(zip(frames.truths, frames.greys, strict=True)):
        ref = pose_of("mono8", k)
        assert ref.header.frame_id == "map"
        assert stamp_to_ns(ref.header.stamp) == frames.stamp(k, "mono8") + STAMP_OFFSET_NS      # exactly
        p_ref = _pose_vector(ref)
        assert np.linalg.norm(p_ref[:2] - truth[:2]) < 0.02
        for variant in RAW_VARIANTS[1:] + ("png",):          # the same grey pixels: the same pose
            np.testing.assert_allclose(_pose_vector(pose_of(variant, k)), p_ref, rtol=0, atol=1e-9,
                                       err_msg=variant)
        # JPEG: its pixel error (rms, measured here) is below the image's own noise, so it moves a
        # corner by less than the noise does (CORNER_STD_OF_THE_NOISE, the covariance's pixel_std):
        # the pose difference lies inside that covariance's chi2(6) 99.9 % bound
        decoded = cv2.imdecode(cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1],
                               cv2.IMREAD_GRAYSCALE)
        jpeg_rms.append(float(np.sqrt(np.mean((decoded.astype(float) - grey) ** 2))))
        d = _wrapped(_pose_vector(pose_of("jpeg", k)) - p_ref)
        cov = np.array(ref.pose.covariance).reshape(6, 6)
        assert d @ np.linalg.solve(cov, d) < CHI2_6_999, (k, d)
    assert max(jpeg_rms) < IMAGE_NOISE, jpeg_rms


def test_stamp_offset_in_mode_tf_over_dds(ros_context, tmp_path: Path) -> None:
    """mode tf: the pose is stamped at the tag frames' stamp plus stamp_offset, to the nanosecond."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from tf2_msgs.msg import TFMessage

    from ekf_localization.vision import tag_pnp

    params, node, ex = _probe_node(ros_context, tmp_path, "tag_tf_offset_test",
                                   "mode: tf\ncamera_frame: camera_optical\ntf_max_age: 1.0\n"
                                   "stamp_offset: -0.25")
    pub_tf = node.create_publisher(TFMessage, "/tf",
                                   QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    poses: list = []
    sub = node.create_subscription(PoseWithCovarianceStamped, "camera/pose", poses.append, 10)
    truth = np.array([1.5, 1.7, 0.0, 0.0, 0.0, math.pi - 0.05])
    T_cam_map = np.linalg.inv(tag_pnp.pose_matrix(truth) @ tag_images.mount())
    at_in_tag = np.eye(4)
    at_in_tag[:3, :3] = [[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]  # apriltag_ros's axes
    stamps = []
    try:
        with running_process([*node_command("tag_localizer"), "--ros-args", "--params-file", str(params)],
                             tmp_path / "tag_localizer.log"):
            assert wait_for_subscribers(ex, pub_tf) and wait_for_publishers(ex, sub)
            for _ in range(20):
                stamp = node.get_clock().now().nanoseconds
                pub_tf.publish(TFMessage(transforms=[
                    _tf("camera_optical", f"tag36h11:{i}",
                        T_cam_map @ tag_images.LAYOUT.tags[i].pose_in_map @ at_in_tag, stamp)
                    for i in (1, 2)]))
                stamps.append(stamp)
                if spin_until(ex, lambda: bool(poses), 0.5):
                    break
    finally:
        node.destroy_node()
    assert poses, "no pose from the TF tag frames"
    assert stamp_to_ns(poses[0].header.stamp) + 250_000_000 in stamps, (poses[0].header.stamp, stamps)
