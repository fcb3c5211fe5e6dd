"""Test images of tag36h11 tags: the layout's tags seen from a robot pose (OpenCV warps).

A test fixture, not the simulator's renderer: each tag is the renderer's plate
(``sim_robot.world.camera_render.tag_texture``: OpenCV's marker image, the same codes as
AprilRobotics' tag36h11, turned by 180 degrees into the printed tag) warped by the
homography of its four projected corners onto a white image, rendered at 2x and averaged
down (anti-aliased), optionally blurred by a lens (Gaussian, ``blur_std`` px) and noisy
(``noise_std`` grey levels). ``PHOTO_NOISE_STD`` and ``PHOTO_BLUR_STD`` make it look like the
real photographs by the estimators of benchmarks/bench_tag_real_images.py (docs/apriltags.md).
Also the scene of the tag tests: a layout, camera and mount.
"""

from __future__ import annotations

import math

import numpy as np

from ekf_localization.vision import tag_pnp
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import TagLayout, tag_layout_from_dict
from sim_robot.world.camera_render import tag_texture

SIZE = 0.165
# grey levels and px that give this renderer the photographs' measured noise (0.44) and edge
# blur (0.58 px); its anti-aliasing alone measures 0.45 px
PHOTO_NOISE_STD = 0.42
PHOTO_BLUR_STD = 0.54
LAYOUT_DICT = {
    "tag_family": "tag36h11",
    "field": {"length": 3.6576, "width": 3.6576},
    "tags": [{"id": 1, "size": SIZE, "position": [0.0, 1.4, 0.30], "yaw": 0.0},
             {"id": 2, "size": SIZE, "position": [0.0, 1.9, 0.35], "yaw": 0.0},
             {"id": 3, "size": SIZE, "position": [0.0, 2.4, 0.25], "yaw": 0.3}]}
LAYOUT = tag_layout_from_dict(LAYOUT_DICT)
CAMERA = PinholeCamera.from_fov(640, 480, math.radians(70.0))
# base_link <- camera optical: 10 cm ahead, 2 cm left, 25 cm up, looking along base +x
# (z_opt = x_base, x_opt = -y_base, y_opt = -z_base), pitched up 5 degrees
MOUNT_XYZ_RPY = (0.10, 0.02, 0.25, 0.0, -math.radians(5.0), 0.0)
OPTICAL_IN_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def mount() -> np.ndarray:
    """4x4 base_link <- camera optical frame of the test scene."""
    T = tag_pnp.pose_matrix(MOUNT_XYZ_RPY)
    T[:3, :3] = T[:3, :3] @ OPTICAL_IN_BODY
    return T


def project_tag(pose: np.ndarray, tag_id: int, layout: TagLayout = LAYOUT,
                camera: PinholeCamera = CAMERA) -> np.ndarray:
    """(4, 2) pixels of a tag's corners (detector order) seen from robot pose ``pose``."""
    T_wc = tag_pnp.pose_matrix(pose) @ mount()
    Xc = (layout.tags[tag_id].corners_map() - T_wc[:3, 3]) @ T_wc[:3, :3]
    return camera.project(Xc)


def render(pose: np.ndarray, ids: tuple[int, ...], layout: TagLayout = LAYOUT,
           camera: PinholeCamera = CAMERA, noise_std: float = 0.0,
           rng: np.random.Generator | None = None, blur_std: float = 0.0) -> np.ndarray:
    """(H, W) uint8: the tags ``ids`` on a light grey background seen from robot pose ``pose``,
    blurred by ``blur_std`` px (Gaussian), then with ``noise_std`` grey levels of noise."""
    import cv2

    scale = 2
    W, H = camera.width * scale, camera.height * scale
    canvas = np.full((H, W), 200.0, dtype=np.float32)
    px = 24  # per cell: 8 cells of tag + a white cell around
    for tag_id in ids:
        # the renderer's plate (OpenCV 4.6 and 4.7+; the printed AprilRobotics tag)
        padded = np.round(tag_texture(tag_id, px) * 255.0).astype(np.uint8)
        uv = project_tag(pose, tag_id, layout, camera)
        dst = (uv[[3, 2, 1, 0]] + 0.5) * scale - 0.5     # tl, tr, br, bl at 2x
        src = np.array([[px, px], [9 * px, px], [9 * px, 9 * px], [px, 9 * px]], dtype=np.float32) - 0.5
        Hm = cv2.getPerspectiveTransform(src, dst.astype(np.float32))
        warped = cv2.warpPerspective(padded, Hm, (W, H), flags=cv2.INTER_LINEAR, borderValue=0)
        mask = cv2.warpPerspective(np.ones_like(padded), Hm, (W, H), flags=cv2.INTER_NEAREST,
                                   borderValue=0).astype(bool)
        canvas[mask] = warped[mask]
    image = cv2.resize(canvas, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    if blur_std > 0.0:
        image = cv2.GaussianBlur(image, (0, 0), blur_std, borderType=cv2.BORDER_REPLICATE)
    if noise_std > 0.0:
        image = image + (rng or np.random.default_rng(0)).normal(0.0, noise_std, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)
