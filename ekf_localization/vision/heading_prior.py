"""The filter's heading at an image's stamp: a short history of (stamp, yaw, variance).

A single tag seen from afar gives PnP two mirrored solutions (IPPE's two, their tilt flipped)
that fit the corners about equally well. The robot's own filter knows its heading: the
``odometry/filtered`` estimates give (stamp, yaw, yaw variance), kept here for a short time,
and :meth:`HeadingHistory.at` returns the heading at an image's stamp, interpolated linearly
between the two estimates around it (the yaw unwrapped first), or held from the newest one when
the image is newer. It returns None when the heading is missing or stale: no estimate at most
``max_age_ns`` from the stamp on the side it is taken from. The caller then falls back to the
unconstrained solve.

Single-tag methods (tag_localizer's ``single_tag``):

* ``ambiguity``: the lower-error IPPE solution, rejected above ``max_ambiguity``;
* ``heading``: the IPPE solution whose robot yaw is nearest the filter's (:func:`nearest_yaw`);
* ``fixed_heading``: the yaw held at the filter's, the other five unknowns solved, the
  heading's variance carried into the covariance (vision/tag_pnp.py);
* ``corners``: no PnP pose at all: tag_localizer publishes the tag's corner pixels and the
  filter fuses them at its own prediction (ekf_node's ``tag_cornersN``, inputs/tag_corners.py).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

from ekf_localization.core.angles import wrap_angle

AMBIGUITY = "ambiguity"
HEADING = "heading"
FIXED_HEADING = "fixed_heading"
CORNERS = "corners"
SINGLE_TAG_METHODS = (AMBIGUITY, HEADING, FIXED_HEADING, CORNERS)
HEADING_METHODS = (HEADING, FIXED_HEADING)   # the methods that read the filter's heading


@dataclass(frozen=True)
class Heading:
    """The filter's yaw (rad) and its variance (rad²) at one stamp."""

    yaw: float
    variance: float


class HeadingHistory:
    """The newest ``capacity`` (stamp, yaw, variance) samples, in stamp order (module docstring)."""

    def __init__(self, max_age_ns: int, capacity: int = 200) -> None:
        if max_age_ns <= 0 or capacity < 2:
            raise ValueError("max_age_ns must be > 0 and capacity >= 2")
        self.max_age_ns = int(max_age_ns)
        self.capacity = int(capacity)
        self._t: list[int] = []
        self._yaw: list[float] = []
        self._var: list[float] = []

    def __len__(self) -> int:
        return len(self._t)

    def add(self, stamp_ns: int, yaw: float, variance: float) -> bool:
        """Keep one estimate; False (ignored) if its yaw or variance is not finite or the variance
        is negative. A stamp already held is replaced; an older one is inserted in order."""
        if not (math.isfinite(yaw) and math.isfinite(variance) and variance >= 0.0):
            return False
        i = bisect.bisect_left(self._t, stamp_ns)
        if i < len(self._t) and self._t[i] == stamp_ns:
            self._yaw[i], self._var[i] = yaw, variance
            return True
        self._t.insert(i, stamp_ns)
        self._yaw.insert(i, yaw)
        self._var.insert(i, variance)
        if len(self._t) > self.capacity:
            del self._t[0], self._yaw[0], self._var[0]
        return True

    def at(self, stamp_ns: int) -> Heading | None:
        """The heading at ``stamp_ns``, or None when missing or stale (module docstring)."""
        if not self._t:
            return None
        i = bisect.bisect_left(self._t, stamp_ns)
        if i < len(self._t) and self._t[i] == stamp_ns:
            return Heading(wrap_angle(self._yaw[i]), self._var[i])
        if i == len(self._t):                              # newer than every estimate: hold the newest
            if stamp_ns - self._t[-1] > self.max_age_ns:
                return None
            return Heading(wrap_angle(self._yaw[-1]), self._var[-1])
        if i == 0:                                         # older than the history
            return None
        t0, t1 = self._t[i - 1], self._t[i]
        if min(stamp_ns - t0, t1 - stamp_ns) > self.max_age_ns:
            return None
        w = (stamp_ns - t0) / (t1 - t0)
        y0 = self._yaw[i - 1]
        dy = wrap_angle(self._yaw[i] - y0)
        return Heading(wrap_angle(y0 + w * dy), (1.0 - w) * self._var[i - 1] + w * self._var[i])


def nearest_yaw(yaws: Sequence[float], yaw: float) -> int:
    """Index of the candidate yaw nearest ``yaw`` on the circle."""
    if not yaws:
        raise ValueError("no candidate yaw")
    return min(range(len(yaws)), key=lambda k: abs(wrap_angle(yaws[k] - yaw)))
