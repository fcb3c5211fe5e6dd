"""Renders what a camera sees: the field's tag36h11 AprilTags on a plain background (mono8).

Each tag is drawn as its printed plate (the 8x8-cell black square of the tag plus a 1-cell
white border: 10/8 of ``Tag.size``) with its real bit pattern from OpenCV's
``DICT_APRILTAG_36h11`` (``cv2.aruco.generateImageMarker``), warped into the image by the
homography of its four projected corners (``PinholeCamera.project`` of the plate corners,
vision/camera_geometry.py; ``optical_pose``, from there too, turns a body pose into the
camera's optical pose).
Anti-aliasing: each tag's bounding box is rendered ``supersample`` times finer and averaged
down (``INTER_AREA``), pixel centres at integer coordinates on both grids.

Then, in order: exposure (grey levels scale with ``exposure_time / reference_exposure_time``),
an optional left-to-right illumination gradient, motion blur (a line kernel along the tags'
mean pixel motion between the camera pose at the start and the end of the exposure; the
blurred tag is centred where the camera at mid-exposure sees it), the lens's blur (a Gaussian
point spread of ``optics_blur_std`` px), Gaussian noise, rounding to uint8. The optics blur and
the noise in config/sim.yaml are those measured on real photographs (docs/apriltags.md). Lens
distortion moves the corners but the edges between them stay straight (one homography per tag).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ekf_localization.vision.camera_geometry import optical_pose  # noqa: F401 - re-exported beside planar_pose
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import Tag, TagLayout, corners_in_tag

_NEAR = 0.05   # m: tags with a plate corner nearer than this (or behind) are not drawn


@dataclass(frozen=True)
class RenderSettings:
    """Grey levels (0..255 at the reference exposure), exposure (s), blur, noise, anti-aliasing."""

    background_level: float = 120.0
    white_level: float = 215.0
    black_level: float = 25.0
    exposure_time: float = 0.004
    reference_exposure_time: float = 0.004
    illumination_gradient: float = 0.0   # brightness goes from (1 - g) at the left to (1 + g)
    noise_std: float = 0.0               # grey levels
    motion_blur: bool = True
    supersample: int = 3
    optics_blur_std: float = 0.0         # px, std of the lens's Gaussian point spread

    def __post_init__(self) -> None:
        for name in ("background_level", "white_level", "black_level", "noise_std",
                     "optics_blur_std"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0")
        if not (self.exposure_time > 0.0 and self.reference_exposure_time > 0.0):
            raise ValueError("exposure_time and reference_exposure_time must be > 0 (s)")
        if not 0.0 <= self.illumination_gradient < 1.0:
            raise ValueError("illumination_gradient must be in [0, 1)")
        if not (isinstance(self.supersample, int) and 1 <= self.supersample <= 8):
            raise ValueError("supersample must be an int in [1, 8]")


def planar_pose(x: float, y: float, z: float, yaw: float, pitch: float = 0.0) -> np.ndarray:
    """map <- body (4x4) at (x, y, z), heading ``yaw``, nose down by ``pitch`` (rad)."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rz @ Ry, (x, y, z)
    return T


@functools.lru_cache(maxsize=256)
def tag_texture(tag_id: int, cell_px: int) -> np.ndarray:
    """The tag's plate (10x10 cells: white border, black square, 6x6 data), 0..1 float32.

    Upright as printed: the AprilRobotics detector's first corner is the bottom-left one.
    """
    import cv2

    aruco = cv2.aruco
    dictionary = aruco.getPredefinedDictionary(aruco.DICT_APRILTAG_36h11)
    if hasattr(aruco, "generateImageMarker"):
        marker = aruco.generateImageMarker(dictionary, tag_id, 8 * cell_px, borderBits=1)
    else:   # OpenCV <= 4.6
        marker = aruco.drawMarker(dictionary, tag_id, 8 * cell_px, borderBits=1)
    plate = np.ones((10 * cell_px, 10 * cell_px), np.float32)
    # OpenCV's 36h11 markers are the AprilRobotics (printed) tags turned by 180 degrees
    # (opencv/opencv-python#1195; checked by test_camera_render against pupil_apriltags).
    plate[cell_px:9 * cell_px, cell_px:9 * cell_px] = np.rot90(marker, 2) / np.float32(255.0)
    return plate


def _in_camera(points_map: np.ndarray, cam_pose: np.ndarray) -> np.ndarray:
    R, t = cam_pose[:3, :3], cam_pose[:3, 3]
    return (points_map - t) @ R


def _plate_pixels(camera: PinholeCamera, cam_pose: np.ndarray, tag: Tag) -> np.ndarray | None:
    """(4, 2) pixels of the plate corners (bl, br, tr, tl), or None when not drawable."""
    R, t = tag.pose_in_map[:3, :3], tag.pose_in_map[:3, 3]
    if np.dot(R[:, 0], cam_pose[:3, 3] - t) <= 0.0:   # camera behind the printed face
        return None
    corners = _in_camera(corners_in_tag(tag.size * 10.0 / 8.0) @ R.T + t, cam_pose)
    if np.any(corners[:, 2] < _NEAR):
        return None
    return camera.project(corners)


class CameraRenderer:
    """Draws a :class:`TagLayout` as seen by a :class:`PinholeCamera` (see the module doc)."""

    def __init__(self, camera: PinholeCamera, layout: TagLayout,
                 settings: RenderSettings | None = None) -> None:
        self.camera, self.layout = camera, layout
        self.settings = settings or RenderSettings()

    def visible_tags(self, cam_pose: np.ndarray) -> list[int]:
        """Ids of the tags whose whole plate falls inside the image at ``cam_pose``."""
        w, h = self.camera.width, self.camera.height
        ids = []
        for tag in self.layout.tags.values():
            px = _plate_pixels(self.camera, cam_pose, tag)
            if px is not None and np.all((px >= -0.5) & (px <= (w - 0.5, h - 0.5))):
                ids.append(tag.tag_id)
        return ids

    def render(self, cam_pose: np.ndarray, cam_pose_end: np.ndarray | None = None,
               rng: np.random.Generator | None = None) -> np.ndarray:
        """mono8 (H, W) image from ``cam_pose`` (map <- optical, 4x4) at the exposure's start.

        ``cam_pose_end`` (the pose at the exposure's end) makes the motion blur; ``rng``
        draws the noise (a fixed seed when omitted).
        """
        import cv2

        s, cam = self.settings, self.camera
        gain = s.exposure_time / s.reference_exposure_time
        image = np.full((cam.height, cam.width), gain * s.background_level, np.float32)
        motions = []
        for tag in self.layout.tags.values():
            px = _plate_pixels(cam, cam_pose, tag)
            if px is None or not self._draw(image, tag, px, gain):
                continue
            if cam_pose_end is not None:
                end = _plate_pixels(cam, cam_pose_end, tag)
                if end is not None:
                    motions.append((end - px).mean(axis=0))
        if s.illumination_gradient > 0.0:
            image *= np.linspace(1.0 - s.illumination_gradient, 1.0 + s.illumination_gradient,
                                 cam.width, dtype=np.float32)
        if s.motion_blur and motions:
            image = _motion_blur(image, np.mean(motions, axis=0))
        if s.optics_blur_std > 0.0:
            image = cv2.GaussianBlur(image, (0, 0), s.optics_blur_std, borderType=cv2.BORDER_REPLICATE)
        if s.noise_std > 0.0:
            rng = rng if rng is not None else np.random.default_rng(0)
            noise = rng.standard_normal(image.shape, np.float32)
            noise *= np.float32(s.noise_std)
            image += noise
        np.maximum(image, 0.0, out=image)
        return cv2.convertScaleAbs(image)   # rounds and saturates at 255

    def _draw(self, image: np.ndarray, tag: Tag, px: np.ndarray, gain: float) -> bool:
        """Composite one tag's plate (pixel corners ``px``) into ``image``; False if off-image."""
        import cv2

        s, h, w = self.settings, image.shape[0], image.shape[1]
        x0, y0 = max(int(math.floor(px[:, 0].min())) - 1, 0), max(int(math.floor(px[:, 1].min())) - 1, 0)
        x1 = min(int(math.ceil(px[:, 0].max())) + 2, w)
        y1 = min(int(math.ceil(px[:, 1].max())) + 2, h)
        if x1 <= x0 or y1 <= y0:
            return False
        k = s.supersample
        extent = float(np.ptp(px, axis=0).max())
        cell = int(min(max(math.ceil(extent * k / 10.0), 1), 32))
        texture = tag_texture(tag.tag_id, cell)
        n = texture.shape[0]
        # texture pixel centres at integers: plate edges at -0.5 and n - 0.5 (bl, br, tr, tl)
        src = np.float32([[-0.5, n - 0.5], [n - 0.5, n - 0.5], [n - 0.5, -0.5], [-0.5, -0.5]])
        dst = np.float32(k * (px - (x0, y0) + 0.5) - 0.5)
        H = cv2.getPerspectiveTransform(src, dst)
        levels = gain * (s.black_level + (s.white_level - s.black_level) * texture)
        rgba = cv2.merge([levels.astype(np.float32), np.ones_like(texture)])
        warped = cv2.warpPerspective(rgba, H, ((x1 - x0) * k, (y1 - y0) * k),
                                     flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                     borderValue=(0.0, 0.0, 0.0, 0.0))
        if k > 1:
            warped = cv2.resize(warped, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        premultiplied, alpha = warped[..., 0], warped[..., 1]
        box = image[y0:y1, x0:x1]
        box *= 1.0 - alpha
        box += premultiplied
        return True


def _motion_blur(image: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """``image`` (drawn at the exposure's start) averaged over the exposure, the scene moving
    by ``motion`` px: out(x) = mean over s in [0, 1] of image(x - s * motion)."""
    import cv2

    length = float(np.hypot(*motion))
    if length < 0.5:
        return image
    half = int(math.ceil(length)) + 1
    kernel = np.zeros((2 * half + 1, 2 * half + 1), np.float32)
    # filter2D correlates: out(x) = sum_u kernel[anchor + u] * image(x + u), so u = -s * motion
    for f in np.linspace(0.0, 1.0, max(int(math.ceil(2.0 * length)), 2) + 1):
        x, y = half - f * motion[0], half - f * motion[1]
        ix, iy = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - ix, y - iy
        kernel[iy, ix] += (1 - fx) * (1 - fy)
        kernel[iy, ix + 1] += fx * (1 - fy)
        kernel[iy + 1, ix] += (1 - fx) * fy
        kernel[iy + 1, ix + 1] += fx * fy
    kernel /= kernel.sum()
    return cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REPLICATE)
