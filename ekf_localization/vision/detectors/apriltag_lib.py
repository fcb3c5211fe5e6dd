"""The AprilRobotics C library (apriltag 3) through the ``dt_apriltags`` binding.

PyPI ``dt-apriltags``, rosdep key ``python-dt-apriltags-pip`` (ubuntu: pip), a ctypes binding
of the library with its own build of it inside the wheel.

Its corners already come in the AprilRobotics order (bl, br, tr, tl as the camera sees the
upright tag). The library puts a pixel's top-left edge at integer coordinates (its centre at
+0.5; AprilRobotics/apriltag#334); they are shifted by -0.5 px into this package's
convention (pixel centres at integers), which the renderer's tests check.
"""

from __future__ import annotations

import numpy as np

from ekf_localization.vision.detection import TagDetection


class AprilTagLibDetector:
    """tag36h11 through the AprilRobotics library; its ``quad_decimate`` etc. as keywords.

    ``quad_sigma`` 0.8 px (a Gaussian blur before the quads are found): with 2 grey levels of
    noise the library takes ~260 ms per 640x480 frame without it and ~20 ms with it
    (docs/apriltags.md).
    """

    name = "apriltag"

    def __init__(self, threads: int = 1, quad_decimate: float = 1.0, quad_sigma: float = 0.8,
                 refine_edges: bool = True, max_hamming: int = 0) -> None:
        from dt_apriltags import Detector

        self._max_hamming = int(max_hamming)
        self._detector = Detector(families="tag36h11", nthreads=threads,
                                  quad_decimate=quad_decimate, quad_sigma=quad_sigma,
                                  refine_edges=int(refine_edges))

    def detect(self, image: np.ndarray) -> list[TagDetection]:
        """The tag36h11 tags in a mono8 image."""
        found = self._detector.detect(np.ascontiguousarray(image, dtype=np.uint8))
        return [TagDetection(int(d.tag_id), np.asarray(d.corners, dtype=float).reshape(4, 2) - 0.5,
                             int(d.hamming), float(d.decision_margin))
                for d in found if d.hamming <= self._max_hamming]
