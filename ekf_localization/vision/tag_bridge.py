"""apriltag_ros's tag poses -> corner "detections" for the same PnP solver (tag_localizer's tf mode).

apriltag_ros publishes each tag's pose in the camera's optical frame (camera -> ``tag36h11:<id>``,
the tag frame of AprilRobotics: origin at the centre, +z into the tag, +x right and +y down as the
camera sees the upright tag). Its four corners, projected through an ideal pinhole camera
(:data:`BRIDGE_CAMERA`, focal length 500 px, no distortion, centred), are the corner pixels the
detector would have given; :func:`ekf_localization.vision.tag_pnp.localize` then solves the
robot pose from them exactly as from an image, so tag_localizer's ``pixel_std`` is the corner
noise in that ideal camera.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ekf_localization.vision.detection import TagDetection
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import TagLayout

BRIDGE_CAMERA = PinholeCamera(640, 480, 500.0, 500.0, 319.5, 239.5)


def corners_in_apriltag_frame(size: float) -> np.ndarray:
    """(4, 3) corners bl, br, tr, tl in AprilRobotics' tag frame (x right, y down, z into the tag)."""
    h = 0.5 * size
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def detections_from_tag_poses(poses: Mapping[int, np.ndarray], layout: TagLayout,
                              camera: PinholeCamera = BRIDGE_CAMERA
                              ) -> tuple[PinholeCamera, list[TagDetection]]:
    """The corner pixels of each tag pose (4x4, camera optical <- apriltag_ros tag frame) in
    ``camera``; tags behind the camera are left out."""
    out = []
    for tag_id, T in poses.items():
        size = layout.tags[tag_id].size if tag_id in layout.tags else 0.1
        X = corners_in_apriltag_frame(size) @ T[:3, :3].T + T[:3, 3]
        if np.all(X[:, 2] > 0.0):
            out.append(TagDetection(int(tag_id), camera.project(X)))
    return camera, out
