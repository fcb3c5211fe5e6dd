"""The detector interface: an image in, tag36h11 detections (id and four corners) out.

Every detector (``vision/detectors``) returns corners in the AprilRobotics order that
:mod:`ekf_localization.vision.tag_layout` uses: bottom-left, bottom-right, top-right, top-left
of the upright tag as the camera sees it, in pixels (x right, y down, pixel centres at
integers).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class TagDetection:
    """One detected tag: id, (4, 2) corner pixels in detector order, and its quality."""

    tag_id: int
    corners: np.ndarray
    hamming: int = 0
    decision_margin: float = float("nan")


class TagDetector(Protocol):
    """Detects tag36h11 tags in a mono8 image (H x W uint8 array)."""

    name: str

    def detect(self, image: np.ndarray) -> list[TagDetection]:
        """The tags found in ``image``, in no particular order."""
        ...
