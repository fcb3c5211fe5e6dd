"""A ramp on the field: a rectangular region whose surface rises and falls along x.

Like an FRC charge station: inside ``x_min ≤ x ≤ x_max``, ``y_min ≤ y ≤ y_max`` the surface
height z(x) climbs at ``slope`` (rad) from x_min, stays level over ``flat_top_length`` in the
middle and descends to x_max (a symmetric trapezoid; the sides at y_min / y_max are steps,
which paths should not cross). Outside it the field is level at z = 0.

A robot on the surface has its body z axis along the surface normal and its heading ψ (the
yaw of R = Rz(ψ)·Ry(p)·Rx(r), REP-103) unchanged; with the gradient g = ∇z and the slopes
along and across the heading, s_f = g·(cos ψ, sin ψ) and s_l = g·(−sin ψ, cos ψ),

    pitch p = −atan(s_f)          roll r = atan(s_l · cos p)

(nose up on a climb is negative pitch): ``Ramp.attitude``, for N poses at once. The world
(``sim_robot.world.world``) moves the robot by ``ekf_localization.core.tilt``'s projection
of its body velocity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Ramp:
    """Region (m, field frame), slope (rad) and the level top's length (m); disabled by default."""

    enabled: bool = False
    x_min: float = 0.15
    x_max: float = 0.85
    y_min: float = -1.2
    y_max: float = -0.45
    slope: float = math.radians(15.0)
    flat_top_length: float = 0.2

    def __post_init__(self) -> None:
        values = (self.x_min, self.x_max, self.y_min, self.y_max, self.slope, self.flat_top_length)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"ramp values must be finite, got {values!r}")
        if not (self.x_max > self.x_min and self.y_max > self.y_min):
            raise ValueError("ramp region must have x_max > x_min and y_max > y_min")
        if not 0.0 < self.slope < math.radians(45.0):
            raise ValueError(f"ramp slope must be in (0, 45°), got {math.degrees(self.slope)!r}°")
        if not 0.0 <= self.flat_top_length < self.x_max - self.x_min:
            raise ValueError("ramp flat_top_length must be >= 0 and shorter than the region")

    @property
    def run(self) -> float:
        """Horizontal length of each slope, m."""
        return 0.5 * (self.x_max - self.x_min - self.flat_top_length)

    @property
    def height(self) -> float:
        """Height of the level top, m."""
        return self.run * math.tan(self.slope)

    def surface(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(z, ∂z/∂x) of the surface at the field points (x, y); (0, 0) off the ramp or disabled."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        on = self.enabled & (x > self.x_min) & (x < self.x_max) & (y >= self.y_min) & (y <= self.y_max)
        up, down = x - self.x_min, self.x_max - x  # horizontal distance from the foot of each slope
        k = math.tan(self.slope)
        z = k * np.minimum(np.minimum(up, down), self.run)  # the two slopes never overlap (run <= half)
        gradient = np.where(up < self.run, k, np.where(down < self.run, -k, 0.0))
        return np.where(on, z, 0.0), np.where(on, gradient, 0.0)

    def attitude(self, pose: np.ndarray) -> np.ndarray:
        """(N, 3) [z roll pitch] of robots at the (N, 3) poses [x y ψ] (module docstring)."""
        pose = np.asarray(pose, dtype=float)
        z, gx = self.surface(pose[:, 0], pose[:, 1])  # the gradient g = (gx, 0): slope along x only
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        pitch = -np.arctan(gx * c)  # s_f = g·(cos ψ, sin ψ)
        roll = np.arctan(-gx * s * np.cos(pitch))  # s_l = g·(−sin ψ, cos ψ)
        return np.column_stack([z, roll, pitch])
