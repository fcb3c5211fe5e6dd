"""The pinhole camera: intrinsics (as in sensor_msgs/CameraInfo) and projection.

Points are in the camera's optical frame (REP-103 ``*_optical``: +z forward, +x right,
+y down); pixels are (u right, v down) with the pixel centre at integer coordinates.
Distortion is the plumb-bob model (k1, k2, p1, p2, k3) of CameraInfo's ``D``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """Image size (px), focal lengths and principal point (px), plumb-bob distortion."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov: float) -> PinholeCamera:
        """A centred, undistorted camera with the given horizontal field of view (rad)."""
        f = 0.5 * width / np.tan(0.5 * horizontal_fov)
        return cls(width, height, f, f, 0.5 * (width - 1), 0.5 * (height - 1))

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) pixels of (N, 3) optical-frame points (z > 0), distortion applied."""
        p = np.asarray(points, dtype=float)
        x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
        k1, k2, p1, p2, k3 = (tuple(self.distortion) + (0.0,) * 5)[:5]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.column_stack([self.fx * xd + self.cx, self.fy * yd + self.cy])

    def floor_wedge(self, base_from_optical: np.ndarray, reach: float) -> np.ndarray | None:
        """The horizontal field of view on the floor of the frame ``base_from_optical`` maps into
        (4x4, e.g. base_link <- camera optical): (3, 2) points, the end of the image's left edge
        ray ``reach`` m out, the camera's (x, y), the end of its right edge ray. The edge rays are
        those of the principal row's outer pixel edges, distortion ignored; None when one is
        vertical (it has no direction on the floor)."""
        edges_u = np.array([-0.5, self.width - 0.5])
        rays = np.column_stack([(edges_u - self.cx) / self.fx, np.zeros(2), np.ones(2)])
        xy = (rays @ np.asarray(base_from_optical, dtype=float)[:3, :3].T)[:, :2]
        length = np.hypot(xy[:, 0], xy[:, 1])
        if np.any(length < 1e-9):
            return None
        apex = np.asarray(base_from_optical, dtype=float)[:2, 3]
        ends = apex + reach * xy / length[:, None]
        return np.array([ends[0], apex, ends[1]])
