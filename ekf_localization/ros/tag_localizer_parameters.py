"""tag_localizer's parameters: the schema and its parsing into :class:`TagLocalizerSettings` (no rclpy).

Every problem (a bad value, an unknown name, a tag layout that does not load) is collected
and raised as one :class:`~ekf_localization.ros.parameters.ParameterError` naming the
parameter; the node then exits with status 2 (``ros/node_runner.py``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ekf_localization.control.field_path import resolve_config_file
from ekf_localization.core.units import seconds_to_ns
from ekf_localization.ros.parameters import (
    Check,
    Entry,
    Problem,
    Schema,
    choice,
    expected,
    non_negative,
    positive,
    raise_problems,
    timer_rate,
)
from ekf_localization.vision.corner_noise import CornerNoise
from ekf_localization.vision.heading_prior import AMBIGUITY, CORNERS, SINGLE_TAG_METHODS
from ekf_localization.vision.tag_layout import TagLayout, load_tag_layout

NODE_NAME = "tag_localizer"
MODES = ("images", "tf")
DETECTORS = ("opencv", "apriltag")  # vision/detectors.DETECTORS (imported there only when built)
IMAGE_TRANSPORTS = ("raw", "compressed")  # image_transport's names (its `image_transport` parameter)
MAX_STAMP_OFFSET_S = 10.0
_TOPIC = Check(lambda v: bool(v), "a non-empty topic name")
_FRAME = Check(lambda v: bool(v.strip("/ ")), "a non-empty frame id")

TAG_LOCALIZER_PARAMETERS = Schema(NODE_NAME, "docs/tag_localizer.md", (
    Entry("layout_file", "str", "", "",
          "tag layout YAML (vision/tag_layout.py): absolute, or relative to the cwd, the package share "
          "directory, the source tree",
          Check(lambda v: bool(v), "a tag layout YAML file"), default_doc="**required**"),
    Entry("mode", "str", "images", "",
          "images: detect tags in Image + CameraInfo; tf: read apriltag_ros's TF tag frames "
          "(camera -> <tag_frame_prefix><id>)", choice(MODES)),
    Entry("detector", "str", "apriltag", "",
          "mode images: the tag36h11 detector (vision/detectors: apriltag = the AprilRobotics library "
          "through dt-apriltags, opencv = OpenCV's aruco)", choice(DETECTORS)),
    Entry("image_topic", "str", "camera/image_raw", "",
          "sensor_msgs/Image (mono8, mono16, rgb8, bgr8, rgba8, bgra8, yuv422, yuv422_yuy2)", _TOPIC),
    Entry("image_transport", "str", "raw", "",
          "mode images: raw reads sensor_msgs/Image on image_topic; compressed reads "
          "sensor_msgs/CompressedImage (JPEG or PNG) on <image_topic>/compressed, as image_transport names "
          "it", choice(IMAGE_TRANSPORTS)),
    Entry("stamp_offset", "float", 0.0, "s",
          "added to each image's stamp (tag frames' in mode tf) to give the exposure time the pose is "
          "stamped at: negative for a driver that stamps a frame on arrival",
          Check(lambda v: math.isfinite(v) and abs(v) <= MAX_STAMP_OFFSET_S,
                f"a finite float from {-MAX_STAMP_OFFSET_S:g} to {MAX_STAMP_OFFSET_S:g}")),
    Entry("camera_info_topic", "str", "camera/camera_info", "", "sensor_msgs/CameraInfo of the images",
          _TOPIC),
    Entry("pose_topic", "str", "camera/pose", "",
          "geometry_msgs/PoseWithCovarianceStamped of base_link in map (ekf_node's pose0)", _TOPIC),
    Entry("publish_corners", "bool", False, "",
          "also publish each layout tag's undistorted corner pixels (geometry_msgs/PolygonStamped, bl br tr "
          "tl) on tag_corners/tag_<id>: ekf_node's tag_cornersN input"),
    Entry("publish_markers", "bool", True, "",
          "draw each image's camera field of view on the floor (base_link) and the layout tags seen (map) "
          "on ~/markers (visualization_msgs/MarkerArray: RViz, field_view)"),
    Entry("fov_marker_reach", "float", 2.0, "m", "length of the field-of-view wedge's edges on ~/markers",
          positive()),
    Entry("map_frame", "str", "map", "", "the layout's frame: the frame_id of the published pose", _FRAME),
    Entry("base_link_frame", "str", "base_link", "", "robot body frame (camera -> base_link from TF)",
          _FRAME),
    Entry("camera_frame", "str", "", "",
          "the camera's optical frame; empty: the image's header.frame_id"),
    Entry("tag_frame_prefix", "str", "tag36h11:", "", "mode tf: apriltag_ros's tag frame name before the id"),
    Entry("tf_frequency", "float", 10.0, "Hz", "mode tf: rate at which the tag frames are read",
          timer_rate()),
    Entry("tf_max_age", "float", 0.2, "s", "mode tf: older tag transforms are not used", positive()),
    Entry("pixel_std", "float", 1.0, "px",
          "std of a detected corner's own error (each axis); the covariance's corner noise "
          "(vision/corner_noise.py)", positive()),
    Entry("tag_shift_std", "float", 0.0, "px",
          "std of the error shared by a tag's four corners (each axis)", non_negative()),
    Entry("blur_std_per_px", "float", 0.0, "px/px",
          "corner std added along the image motion per px of motion blur", non_negative()),
    Entry("exposure_time", "float", 0.0, "s",
          "the camera's exposure: the motion blur is the image motion over it (0: no blur model)",
          non_negative()),
    Entry("unknown_motion_blur_px", "float", 0.0, "px",
          "blur assumed along the image rows when no fix of the last 0.25 s gives the motion",
          non_negative()),
    Entry("max_ambiguity", "float", 0.2, "",
          "a single-tag fix whose IPPE reprojection error ratio best/second exceeds this is rejected "
          "(PhotonVision's ambiguity)", non_negative()),
    Entry("single_tag", "str", "ambiguity", "",
          "how a single tag's two mirrored solutions are decided: ambiguity (the better fit, rejected above "
          "max_ambiguity), heading (the one nearest the filter's yaw on heading_topic), fixed_heading (the "
          "yaw held at the filter's, its variance carried into x, y), both falling back to ambiguity without "
          "a fresh heading; corners (no pose, the tag's undistorted corner pixels on tag_corners/tag_<id> "
          "for ekf_node's tag_cornersN; in mode tf, without pixels, ambiguity)",
          choice(SINGLE_TAG_METHODS)),
    Entry("heading_topic", "str", "odometry/filtered", "",
          "nav_msgs/Odometry of the filter whose yaw and yaw variance the heading methods use", _TOPIC),
    Entry("heading_max_age", "float", 0.2, "s",
          "a heading further than this from the image's stamp is stale: the frame falls back to ambiguity",
          positive()),
    Entry("field_margin", "float", 0.5, "m", "fixes further off the layout's field are rejected",
          non_negative()),
    Entry("max_reprojection_rms", "float", 5.0, "px", "fixes whose corners fit worse are rejected",
          positive()),
))


@dataclass(frozen=True)
class TagLocalizerSettings:
    layout: TagLayout
    mode: str
    detector: str
    image_topic: str
    image_transport: str
    stamp_offset_ns: int
    camera_info_topic: str
    pose_topic: str
    publish_corners: bool
    publish_markers: bool
    fov_marker_reach: float
    map_frame: str
    base_link_frame: str
    camera_frame: str
    tag_frame_prefix: str
    tf_frequency: float
    tf_max_age: float
    corner_noise: CornerNoise
    max_ambiguity: float
    single_tag: str
    heading_topic: str
    heading_max_age_ns: int
    field_margin: float
    max_reprojection_rms: float


def parse_settings(values: Mapping[str, Any]) -> TagLocalizerSettings:
    """Validate parameter values (missing ones take their defaults); raises one ParameterError."""
    parsed = TAG_LOCALIZER_PARAMETERS.parse(values)
    problems = parsed.problems + TAG_LOCALIZER_PARAMETERS.unknown_problems(parsed.others)
    v = parsed.values
    layout = None
    if not v["layout_file"] and "layout_file" not in parsed.given:
        problems.append(expected("layout_file", "a tag layout YAML file (it is required)"))
    elif v["layout_file"]:
        try:
            layout = load_tag_layout(resolve_config_file(v["layout_file"]))
        except (OSError, ValueError) as exc:
            problems.append(Problem("layout_file", str(exc)))
    raise_problems(problems)
    # corners needs the images' own pixels; apriltag_ros's tag frames (mode tf) have none
    single_tag = AMBIGUITY if v["single_tag"] == CORNERS and v["mode"] != "images" else v["single_tag"]
    return TagLocalizerSettings(
        layout=layout, mode=v["mode"], detector=v["detector"], image_topic=v["image_topic"],
        image_transport=v["image_transport"], stamp_offset_ns=seconds_to_ns(v["stamp_offset"]),
        camera_info_topic=v["camera_info_topic"], pose_topic=v["pose_topic"],
        publish_corners=v["publish_corners"], publish_markers=v["publish_markers"],
        fov_marker_reach=v["fov_marker_reach"],
        map_frame=v["map_frame"].strip("/ "), base_link_frame=v["base_link_frame"].strip("/ "),
        camera_frame=v["camera_frame"].strip("/ "), tag_frame_prefix=v["tag_frame_prefix"],
        tf_frequency=v["tf_frequency"], tf_max_age=v["tf_max_age"],
        corner_noise=CornerNoise(v["pixel_std"], v["tag_shift_std"], v["blur_std_per_px"],
                                 v["exposure_time"], v["unknown_motion_blur_px"]),
        max_ambiguity=v["max_ambiguity"], single_tag=single_tag, heading_topic=v["heading_topic"],
        heading_max_age_ns=seconds_to_ns(v["heading_max_age"]), field_margin=v["field_margin"],
        max_reprojection_rms=v["max_reprojection_rms"])
