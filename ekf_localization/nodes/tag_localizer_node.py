"""tag_localizer: AprilTag images (or apriltag_ros's TF tag frames) -> the robot pose in the map.

Mode ``images`` (default): subscribes to ``camera/image_raw`` (sensor_msgs/Image; with
``image_transport: compressed`` sensor_msgs/CompressedImage on ``camera/image_raw/compressed``,
image_transport's name) and ``camera/camera_info`` (sensor-data QoS), detects tag36h11
(``vision/detectors``), solves multi-tag PnP against the tag layout (``vision/tag_pnp.py``) with
camera -> base_link from TF, and publishes ``camera/pose`` (geometry_msgs/PoseWithCovarianceStamped
of base_link in ``map``, stamped at the image's stamp plus ``stamp_offset``, the covariance from the
PnP Jacobian and the corner noise): the topic ekf_node fuses as pose0.

A single tag's two mirrored solutions are decided by ``single_tag`` (vision/heading_prior.py)
with the filter's yaw and yaw variance from ``heading_topic`` (nav_msgs/Odometry,
``odometry/filtered``) at the image's stamp; without a fresh one, by the ambiguity gate. With
``single_tag: corners`` a frame with one layout tag gives no pose: the tag's undistorted corner
pixels go out on ``tag_corners/tag_<id>`` (geometry_msgs/PolygonStamped, the detector's order,
the camera's optical frame, stamped as the pose would be) for ekf_node's ``tag_cornersN``, which
fuses them at the filter's own prediction, so the mirror never has to be decided here.

Mode ``tf``: robots that run apriltag_ros read its tag frames (camera -> ``tag36h11:<id>``)
from TF; each seen layout tag's pose gives its four corners' pixels in an ideal camera of
the same geometry, and the same PnP solver turns them into the robot pose.

Every frame is counted: accepted, or rejected with its reason (bad_encoding, empty_image,
truncated_image, bad_data_size, corrupt_image, bad_size, bad_camera_info, no_camera_info,
camera_info_mismatch, bad_stamp, no_transform, detector_error, no_tags, no_layout_tags, ambiguous,
off_field, pnp_failed, bad_fit) on /diagnostics (1 Hz), with the ids seen that are not in the
layout. The node never raises on a message. With ``publish_markers`` it draws each image's
camera field of view on the floor (``base_link``) and the layout tags it saw (``map``) on
``~/markers``, for RViz and field_view. Parameters: ros/tag_localizer_parameters.py, docs/tag_localizer.md.
"""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point32, PolygonStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from visualization_msgs.msg import MarkerArray

from ekf_localization.core.angles import quaternion_to_yaw, rpy_to_quaternion
from ekf_localization.core.frames import TransformBuffer
from ekf_localization.core.units import ns_to_sec_nanosec, seconds_to_ns, stamp_to_ns
from ekf_localization.ros import markers
from ekf_localization.ros.due_timer import create_due_timer
from ekf_localization.ros.image_io import (
    BadImageError,
    camera_info_to_pinhole,
    compressed_to_mono8,
    image_to_mono8,
)
from ekf_localization.ros.node_parameters import declare_unset, given_values, refuse_changes
from ekf_localization.ros.node_runner import run_node
from ekf_localization.ros.tag_localizer_parameters import (
    NODE_NAME,
    TAG_LOCALIZER_PARAMETERS,
    parse_settings,
)
from ekf_localization.ros.tf_io import TfListener
from ekf_localization.ros.throttled_log import ThrottledLog
from ekf_localization.vision import tag_pnp
from ekf_localization.vision.heading_prior import CORNERS, HEADING_METHODS, HeadingHistory
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_bridge import detections_from_tag_poses


def _matrix(T: Any) -> np.ndarray:
    """4x4 of a core RigidTransform."""
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = T.rotation, T.translation
    return M


def _stamp_msg(t_ns: int) -> Time:
    """builtin_interfaces/Time of integer nanoseconds."""
    sec, nanosec = ns_to_sec_nanosec(t_ns)
    return Time(sec=sec, nanosec=nanosec)


MARKER_LIFETIME_S = 0.5  # a camera that stops leaves no stale field of view in RViz
TAG_MARKER_DIAMETER_M = 0.12


class TagLocalizerNode(Node):
    """Thin adapter around :func:`ekf_localization.vision.tag_pnp.localize` (module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings = s = parse_settings(given_values(self))
        declare_unset(self, TAG_LOCALIZER_PARAMETERS, TAG_LOCALIZER_PARAMETERS.defaults())
        refuse_changes(self, TAG_LOCALIZER_PARAMETERS)
        self._log = ThrottledLog(self.get_logger())
        self.received = 0
        self.accepted = 0
        self._last_fix: tuple[int, np.ndarray] | None = None   # (stamp, pose): the blur's motion
        self.rejected: Counter[str] = Counter()
        self.unknown_tags: Counter[int] = Counter()
        self._camera: PinholeCamera | None = None
        self._camera_info_rejected = 0
        self._tf = TransformBuffer()
        self._tf_listener = TfListener(self, self._tf)
        self._pub = self.create_publisher(PoseWithCovarianceStamped, s.pose_topic, 10)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # tag id -> its tag_corners/tag_<id> publisher, made at the start so that a recorder or
        # ekf_node has matched it before the first corners are sent
        self._pub_corners: dict[int, Any] = (
            {i: self.create_publisher(PolygonStamped, f"tag_corners/tag_{i}", qos_profile_sensor_data)
             for i in s.layout.tags} if s.publish_corners or s.single_tag == CORNERS else {})
        self._pub_markers = (self.create_publisher(MarkerArray, markers.TAG_LOCALIZER_MARKER_TOPIC, 5)
                             if s.publish_markers else None)
        if s.mode == "images":
            from ekf_localization.vision.detectors import make_detector

            self._detector = make_detector(s.detector)
            self._camera_info_topic = self.create_subscription(
                CameraInfo, s.camera_info_topic, self._on_camera_info, qos_profile_sensor_data).topic_name
            if s.image_transport == "compressed":
                self.create_subscription(CompressedImage, s.image_topic.rstrip("/") + "/compressed",
                                         self._on_compressed, qos_profile_sensor_data)
            else:
                self.create_subscription(Image, s.image_topic, self._on_image, qos_profile_sensor_data)
        else:
            self._detector = None
            self._last_tf_stamp = -1
            create_due_timer(self, 1.0 / s.tf_frequency, self._on_tf_tick)
        self._headings = HeadingHistory(s.heading_max_age_ns)
        self.heading_fallbacks = 0       # single-tag frames solved without a fresh heading
        self.headings_received = 0
        self.headings_rejected = 0       # heading_topic messages with a non-finite yaw or variance
        self.corner_frames = 0           # single_tag corners: single-tag frames sent as corners
        self.corners_unheard = 0         # ... of them with no subscriber on the tag's corner topic
        self._last_corners_unheard = False
        if s.single_tag in HEADING_METHODS:
            self.create_subscription(Odometry, s.heading_topic, self._on_heading, 10)
        create_due_timer(self, 1.0, self._publish_diagnostics)

    def _on_heading(self, msg: Odometry) -> None:
        """The filter's yaw and yaw variance at its stamp, for the single-tag heading methods."""
        q = msg.pose.pose.orientation
        yaw = quaternion_to_yaw(q.x, q.y, q.z, q.w)
        self.headings_received += 1
        if not self._headings.add(stamp_to_ns(msg.header.stamp), yaw, float(msg.pose.covariance[35])):
            self.headings_rejected += 1
            self._log.warning("heading", f"{self.settings.heading_topic}: a non-finite yaw or yaw variance, "
                                         "ignored")

    # --- images ---------------------------------------------------------------------------------

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            self._camera = camera_info_to_pinhole(msg)
        except BadImageError as exc:
            self._camera_info_rejected += 1
            self._camera = None
            self._log.warning(("camera_info", exc.reason), f"CameraInfo rejected: {exc}")

    def _reject(self, reason: str, detail: str) -> None:
        self.rejected[reason] += 1
        self._log.warning(reason, f"frame rejected ({reason}): {detail}")

    def _on_image(self, msg: Image) -> None:
        self._on_frame(msg, image_to_mono8)

    def _on_compressed(self, msg: CompressedImage) -> None:
        self._on_frame(msg, compressed_to_mono8)

    def _on_frame(self, msg: Any, to_mono8: Callable[[Any], np.ndarray]) -> None:
        self.received += 1
        try:
            self._process_image(msg, to_mono8)
        except Exception as exc:  # noqa: BLE001 - a message never takes the node down
            self._reject("internal_error", f"{type(exc).__name__}: {exc}")

    def _exposure_stamp(self, stamp_ns: int) -> int | None:
        """A frame's stamp plus ``stamp_offset``: its exposure time, or None (counted) before 0."""
        t = stamp_ns + self.settings.stamp_offset_ns
        if t < 0:
            self._reject("bad_stamp", f"stamp {stamp_ns} ns + stamp_offset is before 0")
            return None
        return t

    def _process_image(self, msg: Any, to_mono8: Callable[[Any], np.ndarray]) -> None:
        if self._camera is None:
            self._reject("no_camera_info", "no valid CameraInfo received yet")
            return
        try:
            image = to_mono8(msg)
        except BadImageError as exc:
            self._reject(exc.reason, str(exc))
            return
        cam = self._camera
        if image.shape != (cam.height, cam.width):
            self._reject("camera_info_mismatch",
                         f"image {image.shape[1]}x{image.shape[0]}, CameraInfo {cam.width}x{cam.height}")
            return
        stamp_ns = self._exposure_stamp(stamp_to_ns(msg.header.stamp))
        if stamp_ns is None:
            return
        stamp = _stamp_msg(stamp_ns)
        mount = self._mount(msg.header.frame_id, stamp_ns)
        if mount is None:
            return
        try:
            detections = self._detector.detect(image)
        except Exception as exc:  # noqa: BLE001 - a detector's own failure is one rejected frame
            self._reject("detector_error", f"{type(exc).__name__}: {exc}")
            return
        if self._pub_markers is not None:
            self._publish_markers(detections, cam, mount, stamp)
        if not detections:
            self._reject("no_tags", "no tag36h11 tag in the image")
            return
        if self.settings.publish_corners:
            self._publish_corners(detections, cam, stamp, msg.header.frame_id)
        if self.settings.single_tag == CORNERS and self._single_tag_corners(detections, cam, stamp,
                                                                            msg.header.frame_id):
            return
        self._solve(detections, cam, mount, stamp_ns)

    def _single_tag_corners(self, detections: list, cam: PinholeCamera, stamp: Any, frame_id: str) -> bool:
        """``single_tag: corners``: a frame with one layout tag sends that tag's corners instead of a
        pose (True); several tags are left to PnP (False)."""
        layout = self.settings.layout.tags
        known = [d for d in detections if d.tag_id in layout]
        if len(known) != 1:
            return False
        self.unknown_tags.update(d.tag_id for d in detections if d.tag_id not in layout)
        if not self.settings.publish_corners:   # else already sent with every frame's tags
            self._publish_corners(known, cam, stamp, frame_id)
        self.corner_frames += 1
        # nobody fuses them (the filter lacks its tag_cornersN), or not yet (discovery at start)
        self._last_corners_unheard = self._pub_corners[known[0].tag_id].get_subscription_count() == 0
        self.corners_unheard += self._last_corners_unheard
        return True

    def _publish_corners(self, detections: list, cam: PinholeCamera, stamp: Any, frame_id: str) -> None:
        """Each layout tag's undistorted corners on tag_corners/tag_<id> (the tag_corners input)."""
        for d in detections:
            if d.tag_id not in self.settings.layout.tags:
                continue
            pub = self._pub_corners[d.tag_id]
            msg = PolygonStamped()
            msg.header.stamp, msg.header.frame_id = stamp, self.settings.camera_frame or frame_id
            msg.polygon.points = [Point32(x=float(u), y=float(v), z=0.0)
                                  for u, v in cam.undistort(d.corners)]
            pub.publish(msg)

    def _publish_markers(self, detections: list, cam: PinholeCamera, mount: np.ndarray, stamp: Any) -> None:
        """The camera's field of view on the floor (base_link) and the layout tags it sees (map)."""
        s = self.settings
        seen = [s.layout.tags[d.tag_id].pose_in_map[:2, 3] for d in detections if d.tag_id in s.layout.tags]
        parts = [markers.sphere_list(markers.NS_TAGS_SEEN, s.map_frame, stamp, seen, markers.TAGS_SEEN_RGBA,
                                     TAG_MARKER_DIAMETER_M, MARKER_LIFETIME_S)]
        wedge = cam.floor_wedge(mount, s.fov_marker_reach)
        if wedge is not None:
            parts.append(markers.line_strip(markers.NS_CAMERA_FOV, s.base_link_frame, stamp, wedge,
                                            markers.CAMERA_FOV_RGBA, 0.01, MARKER_LIFETIME_S))
        self._pub_markers.publish(markers.marker_array(parts))

    def _mount(self, header_frame: str, stamp_ns: int) -> np.ndarray | None:
        """base_link <- camera optical frame from TF, or None (counted)."""
        s = self.settings
        camera_frame = s.camera_frame or header_frame.strip("/ ")
        if not camera_frame:
            self._reject("no_transform", "the image has no frame_id and camera_frame is not set")
            return None
        T = self._tf.lookup(s.base_link_frame, camera_frame, stamp_ns)
        if T is None:
            self._reject("no_transform", f"no transform {s.base_link_frame} <- {camera_frame} in TF")
            return None
        return _matrix(T)

    def _solve(self, detections: list, cam: PinholeCamera, mount: np.ndarray, stamp_ns: int) -> None:
        s = self.settings
        heading = self._headings.at(stamp_ns) if s.single_tag in HEADING_METHODS else None
        result, unknown = tag_pnp.localize(detections, s.layout, cam, mount, s.corner_noise,
                                           s.max_ambiguity, s.field_margin, self._last_fix, stamp_ns,
                                           s.single_tag, heading)
        self.unknown_tags.update(unknown)
        if s.single_tag in HEADING_METHODS and (
                (isinstance(result, tag_pnp.TagFix) and result.heading_fallback)
                or (isinstance(result, tag_pnp.TagRejection) and result.reason == tag_pnp.AMBIGUOUS)):
            self.heading_fallbacks += 1   # only the fallback rejects as ambiguous
        if isinstance(result, tag_pnp.TagRejection):
            self._reject(result.reason, result.detail)
            return
        if result.reprojection_rms > s.max_reprojection_rms:
            self._reject("bad_fit", f"reprojection rms {result.reprojection_rms:.2f} px > "
                                    f"{s.max_reprojection_rms:.2f} px")
            return
        self.accepted += 1
        self._last_fix = (stamp_ns, result.pose)
        self._pub.publish(self._pose_message(result, stamp_ns))

    def _pose_message(self, fix: tag_pnp.TagFix, stamp_ns: int) -> PoseWithCovarianceStamped:
        msg = PoseWithCovarianceStamped()
        sec, nanosec = ns_to_sec_nanosec(stamp_ns)
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.header.frame_id = self.settings.map_frame
        p = msg.pose.pose
        p.position.x, p.position.y, p.position.z = (float(v) for v in fix.pose[:3])
        q = rpy_to_quaternion(*(float(v) for v in fix.pose[3:]))
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = q
        msg.pose.covariance = [float(v) for v in tag_pnp.published_covariance(fix).reshape(-1)]
        return msg

    # --- apriltag_ros's TF tag frames ----------------------------------------------------------

    def _on_tf_tick(self) -> None:
        s = self.settings
        if not s.camera_frame:
            self._log.warning("tf_mode", "mode tf needs camera_frame (the optical frame apriltag_ros uses)")
            return
        now_ns = self.get_clock().now().nanoseconds
        max_age_ns = seconds_to_ns(s.tf_max_age)
        seen = []
        for tag_id in s.layout.tags:
            frame = f"{s.tag_frame_prefix}{tag_id}"
            stamp_ns = self._tf.newest_stamp(frame)
            if stamp_ns is None or now_ns - stamp_ns > max_age_ns or stamp_ns <= self._last_tf_stamp:
                continue
            T = self._tf.lookup(s.camera_frame, frame, stamp_ns)
            if T is not None:
                seen.append((stamp_ns, tag_id, T))
        newest = max((stamp for stamp, _, _ in seen), default=-1)
        # one camera frame: the tags apriltag_ros published with the newest stamp
        poses = {tag_id: _matrix(T) for stamp, tag_id, T in seen if stamp == newest}
        if not poses:
            return
        self.received += 1
        self._last_tf_stamp = newest
        try:
            stamp_ns = self._exposure_stamp(newest)
            if stamp_ns is None:
                return
            mount = self._mount(s.camera_frame, stamp_ns)
            if mount is None:
                return
            camera, detections = detections_from_tag_poses(poses, s.layout)
            self._solve(detections, camera, mount, stamp_ns)
        except Exception as exc:  # noqa: BLE001 - a message never takes the node down
            self._reject("internal_error", f"{type(exc).__name__}: {exc}")

    # --- diagnostics ---------------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        # the name with its namespace (camera1/tag_localizer): one status per camera on the shared topic
        label = self.get_fully_qualified_name().lstrip("/")
        st = DiagnosticStatus(name=f"{label}: tag fixes", hardware_id="tag_localizer")
        rejected = sum(self.rejected.values())
        if self.settings.mode == "images" and self._camera is None:
            st.level = DiagnosticStatus.WARN
            st.message = (f"no valid CameraInfo on {self._camera_info_topic} "
                          f"({self._camera_info_rejected} rejected): no fixes until one arrives")
        elif self.received and not self.accepted and not self.corner_frames:
            st.level, st.message = DiagnosticStatus.WARN, "no frame accepted yet"
        elif self._last_corners_unheard:
            st.level = DiagnosticStatus.WARN
            st.message = (f"{self.corners_unheard} of {self.corner_frames} single-tag frames sent as corners "
                          "with nobody subscribed to tag_corners/tag_<id>, the last one too: give ekf_node a "
                          "tag_cornersN "
                          "per tag (python -m ekf_localization.tools.tag_corner_inputs) or set single_tag: "
                          "ambiguity")
        else:
            st.level, st.message = DiagnosticStatus.OK, f"{self.accepted} fixes"
            if self.settings.single_tag == CORNERS:
                st.message += f", {self.corner_frames} single-tag frames as corners"
        values = {"frames_received": self.received, "fixes_accepted": self.accepted,
                  "fixes_rejected": rejected, "camera_info_rejected": self._camera_info_rejected}
        values.update({f"rejected_{k}": n for k, n in sorted(self.rejected.items())})
        values.update(tf_frames=len(self._tf), tf_frames_cap=2 * self._tf.max_frames,
                      tf_frames_evicted=self._tf.evictions)  # static + time-stamped links
        if self.settings.single_tag == CORNERS:
            values.update(single_tag=CORNERS, corner_frames=self.corner_frames,
                          corner_frames_unsubscribed=self.corners_unheard)
        elif self.settings.single_tag in HEADING_METHODS:
            values.update(single_tag=self.settings.single_tag, heading_fallbacks=self.heading_fallbacks,
                          headings_received=self.headings_received, headings_rejected=self.headings_rejected)
        values["unknown_tags"] = sum(self.unknown_tags.values())
        if self.unknown_tags:
            values["unknown_tag_ids"] = " ".join(str(i) for i in sorted(self.unknown_tags))
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [st]
        self._pub_diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    return run_node(NODE_NAME, TagLocalizerNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
