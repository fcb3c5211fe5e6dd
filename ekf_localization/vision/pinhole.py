"""The camera as sensor_msgs/CameraInfo describes it: image size, intrinsics, lens distortion.

Points are in the camera's optical frame (REP-103 ``*_optical``: +z forward, +x right,
+y down); pixels are (u right, v down) with the pixel centre at integer coordinates. The
geometry itself (projection, distortion and its inverse) is vision/camera_geometry.py's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ekf_localization.vision import camera_geometry


@dataclass(frozen=True)
class PinholeCamera:
    """Image size (px), focal lengths and principal point (px), CameraInfo's distortion model
    and its coefficients D (stored complete: missing ones are 0.0; ValueError if not valid)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))
    distortion_model: str = camera_geometry.PLUMB_BOB

    def __post_init__(self) -> None:
        object.__setattr__(self, "distortion",
                           camera_geometry.distortion_coefficients(self.distortion_model, self.distortion))

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy)."""
        return self.fx, self.fy, self.cx, self.cy

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov: float) -> PinholeCamera:
        """A centred, undistorted camera with the given horizontal field of view (rad)."""
        f = 0.5 * width / np.tan(0.5 * horizontal_fov)
        return cls(width, height, f, f, 0.5 * (width - 1), 0.5 * (height - 1))

    def project(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) pixels of (..., 3) optical-frame points (z > 0), distortion applied."""
        return camera_geometry.project_distorted(points, self.intrinsics, self.distortion_model,
                                                 self.distortion)

    def undistort(self, pixels: np.ndarray) -> np.ndarray:
        """(..., 2) pixels of this camera -> the ideal pinhole's (same K); unchanged without D."""
        return camera_geometry.undistort_pixels(pixels, self.intrinsics, self.distortion_model,
                                                self.distortion)

    def floor_wedge(self, base_from_optical: np.ndarray, reach: float) -> np.ndarray | None:
        """The horizontal field of view on the floor of the frame ``base_from_optical`` maps into
        (4x4, e.g. base_link <- camera optical): (3, 2) points, the end of the image's left edge
        ray ``reach`` m out, the camera's (x, y), the end of its right edge ray. The edge rays are
        those of the principal row's outer pixel edges, distortion ignored; None when one is
        vertical (it has no direction on the floor)."""
        edges = np.array([[-0.5, self.cy], [self.width - 0.5, self.cy]])
        rays = camera_geometry.pixel_rays(edges, self.intrinsics)
        xy = (rays @ np.asarray(base_from_optical, dtype=float)[:3, :3].T)[:, :2]
        length = np.hypot(xy[:, 0], xy[:, 1])
        if np.any(length < 1e-9):
            return None
        apex = np.asarray(base_from_optical, dtype=float)[:2, 3]
        ends = apex + reach * xy / length[:, None]
        return np.array([ends[0], apex, ends[1]])
