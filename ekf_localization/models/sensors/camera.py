"""Camera landmark pose measurement (seed 000, eq. 28 and 32).

The camera, having recognised a wall image at a known field pose, reports the robot's
field pose ``[x_m y_m θ_m]``. Each component has variance ``a·d² + b`` where d is the
distance from the robot to the image (seed 000: a = b = 0.001 in inch units).
When no image is in view there is no measurement: skipping the update is equivalent
to the paper's inflated variance and cheaper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.linear import LinearMeasurement, select_rows


@dataclass(frozen=True)
class CameraNoise:
    """Pose variance ``distance_variance_coeff · d² + variance_floor`` for each of x, y, θ."""

    distance_variance_coeff: float = 0.001
    variance_floor: float = 0.001

    def __post_init__(self) -> None:
        if not (math.isfinite(self.distance_variance_coeff) and self.distance_variance_coeff >= 0.0):
            raise ValueError("distance_variance_coeff must be finite and >= 0")
        if not (math.isfinite(self.variance_floor) and self.variance_floor > 0.0):
            raise ValueError("variance_floor must be finite and > 0")

    def variance(self, distance: np.ndarray | float) -> np.ndarray | float:
        d = np.asarray(distance, dtype=float)
        return self.distance_variance_coeff * d * d + self.variance_floor

    def covariance(self, distance: float) -> np.ndarray:
        return np.eye(3) * float(self.variance(distance))


def pose_measurement(n: int = 6) -> LinearMeasurement:
    """h(s) = [x y θ] (eq. 28); the θ residual is wrapped."""
    return select_rows(n, [0, 1, 2], angle_rows=(2,))
