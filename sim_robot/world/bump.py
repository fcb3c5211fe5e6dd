"""A push of the robot by the world (a collision, another robot): no ROS imports.

The robot is moved by (dx, dy) in the field frame over ``duration_ns`` from ``start_ns``, on top
of its drive: its driven wheels keep their speeds (their encoders do not see the push), while
the body's velocity, and so the dead wheels and the IMU's acceleration, do. The push's field
velocity is a raised cosine, smooth at both ends so that its acceleration is finite:

    v(t) = (d / T)·(1 − cos(2π s)),   a(t) = (2π d / T²)·sin(2π s),   s = (t − t₀) / T ∈ [0, 1]

which moves the robot by exactly d over T (peak speed 2d/T, peak acceleration 2πd/T²).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.units import ns_to_seconds

BUMP_DURATION_NS = 300_000_000


@dataclass(frozen=True)
class Bump:
    """A push of (dx, dy) (field frame, length unit) from ``start_ns`` over ``duration_ns``."""

    start_ns: int
    dx: float
    dy: float
    duration_ns: int = BUMP_DURATION_NS

    def __post_init__(self) -> None:
        if not (isinstance(self.start_ns, int) and self.start_ns >= 0):
            raise ValueError(f"bump start_ns must be an int >= 0, got {self.start_ns!r}")
        if not (isinstance(self.duration_ns, int) and self.duration_ns > 0):
            raise ValueError(f"bump duration_ns must be an int > 0, got {self.duration_ns!r}")
        if not (math.isfinite(self.dx) and math.isfinite(self.dy)):
            raise ValueError(f"bump displacement must be finite, got ({self.dx!r}, {self.dy!r})")

    def active(self, t_ns: int) -> bool:
        return self.start_ns <= t_ns < self.start_ns + self.duration_ns

    def velocity_acceleration(self, t_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """Field-frame push velocity and acceleration [x y] at ``t_ns`` (zero outside the push)."""
        if not self.active(t_ns):
            return np.zeros(2), np.zeros(2)
        T = ns_to_seconds(self.duration_ns)
        s = (t_ns - self.start_ns) / self.duration_ns
        d = np.array([self.dx, self.dy])
        w = 2.0 * math.pi * s
        return d / T * (1.0 - math.cos(w)), d * (2.0 * math.pi / (T * T)) * math.sin(w)
