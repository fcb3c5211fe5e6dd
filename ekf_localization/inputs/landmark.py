"""``landmarkN``: range and bearing to a known landmark (seed 001 eq. 3, corrected per the seeds
README), e.g. an FRC speaker or a beacon that a detector sees.

The message is geometry_msgs/PointStamped: where the landmark is in the robot's frame
(``base_link_frame``: x forward, y left, REP-103). It is fused as

    z = [r, b] = [hypot(p_x, p_y), atan2(p_y, p_x)]
    h(x) = [hypot(l_x - x, l_y - y), atan2(l_y - y, l_x - x) - θ]   (bearing residual wrapped)

with the landmark at ``landmarkN_position`` [l_x, l_y] in the world frame, R = diag(range
variance, bearing variance) (``landmarkN_range_variance``, ``landmarkN_bearing_variance``).
The Jacobian (d = hypot(l_x - x, l_y - y), checked against finite differences in the tests):

    ∂r/∂(x, y, θ) = [-(l_x - x)/d, -(l_y - y)/d, 0]
    ∂b/∂(x, y, θ) = [(l_y - y)/d², -(l_x - x)/d², -1]
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.measurements import REJECT_FRAME, REJECT_IMPLAUSIBLE, REJECT_NONFINITE
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.inputs.kind import ParameterSpec, fusion_kind
from ekf_localization.inputs.parts import VARIANCE_SCALE

MIN_RANGE = 0.05  # m: closer, the bearing is meaningless (a detection on the robot itself)
_X, _Y, _YAW = 0, 1, 5  # RL fields the measurement needs in the state


@dataclass(frozen=True, eq=False)
class LandmarkObservation:
    """The landmark's position [x, y] in ``frame_id`` (the robot's frame), at ``stamp_ns``."""

    stamp_ns: int
    frame_id: str
    point: np.ndarray  # (2,)


def read(msg) -> LandmarkObservation:
    p = msg.point
    return LandmarkObservation(stamp_to_ns(msg.header.stamp), str(msg.header.frame_id),
                               np.array([p.x, p.y], dtype=float))


class RangeBearingMeasurement:
    """h(x) and its Jacobian on a planar state whose x, y, θ are the columns ``cols`` (module docstring)."""

    m = 2
    z_is_angle = np.array([False, True])

    def __init__(self, landmark: np.ndarray, cols: tuple[int, int, int], n: int) -> None:
        self.landmark = np.asarray(landmark, dtype=float)
        self.cols = cols
        self.n = n

    def _offsets(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ix, iy, _ = self.cols
        dx, dy = self.landmark[0] - X[:, ix], self.landmark[1] - X[:, iy]
        return dx, dy, np.hypot(dx, dy)

    def h(self, X: np.ndarray) -> np.ndarray:
        dx, dy, d = self._offsets(X)
        return np.stack([d, wrap_angles(np.arctan2(dy, dx) - X[:, self.cols[2]])], axis=1)

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        dx, dy, d = self._offsets(X)
        ix, iy, ith = self.cols
        H = np.zeros((X.shape[0], 2, self.n))
        H[:, 0, ix], H[:, 0, iy] = -dx / d, -dy / d
        H[:, 1, ix], H[:, 1, iy], H[:, 1, ith] = dy / d**2, -dx / d**2, -1.0
        return H


@dataclass(frozen=True)
class RangeBearing:
    """The fusion of one landmarkN input (its parameters' values)."""

    position: tuple[float, float]
    range_variance: float
    bearing_variance: float
    part: str = "range_bearing"

    def measurement_model(self, field_to_state: Mapping[int, int],
                          n: int) -> tuple[RangeBearingMeasurement, tuple[int, ...]]:
        missing = [f for f in (_X, _Y, _YAW) if f not in field_to_state]
        if missing:
            raise ValueError("a landmark's range and bearing need x, y and yaw in the state")
        cols = (field_to_state[_X], field_to_state[_Y], field_to_state[_YAW])
        return RangeBearingMeasurement(np.array(self.position), cols, n), (1,)

    def fuse(self, record: LandmarkObservation, base_frame: str) -> tuple[np.ndarray, np.ndarray] | str:
        p = np.asarray(record.point, dtype=float)
        if not np.isfinite(p).all():
            return REJECT_NONFINITE
        if record.frame_id.strip().lstrip("/") != base_frame:
            return REJECT_FRAME
        r = math.hypot(p[0], p[1])
        if r < MIN_RANGE:
            return REJECT_IMPLAUSIBLE
        return np.array([r, math.atan2(p[1], p[0])]), np.diag([self.range_variance, self.bearing_variance])


def fusion(values: Mapping[str, Any]) -> RangeBearing:
    return RangeBearing(tuple(values["position"]), values["range_variance"], values["bearing_variance"])


def _positive(v: float) -> bool:
    return math.isfinite(v) and v > 0.0


KIND = fusion_kind(
    "landmark", "geometry_msgs/msg/PointStamped", read, "range_bearing", fusion, common=(VARIANCE_SCALE,),
    parameters=(
        ParameterSpec("position", "float_list", None, "m", "the landmark's [x, y] in the world frame",
                      lambda v: len(v) == 2 and all(math.isfinite(x) for x in v), "a list of 2 finite floats",
                      required=True),
        ParameterSpec("range_variance", "float", 0.01, "m²", "variance of a measured range", _positive,
                      "a variance > 0"),
        ParameterSpec("bearing_variance", "float", 0.001, "rad²", "variance of a measured bearing", _positive,
                      "a variance > 0"),
    ))
