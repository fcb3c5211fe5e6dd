"""The AprilRobotics C library (apriltag 3) through the ``dt_apriltags`` binding.

PyPI ``dt-apriltags``, rosdep key ``python-dt-apriltags-pip`` (ubuntu: pip), a ctypes binding
of the library with its own build of it inside the wheel.

Its corners already come in the AprilRobotics order (bl, br, tr, tl as the camera sees the
upright tag). The library puts a pixel's top-left edge at integer coordinates (its centre at
+0.5; AprilRobotics/apriltag#334); they are shifted by -0.5 px into this package's
convention (pixel centres at integers), which the renderer's tests check.

The binding's ``Detector.__del__`` (dt-apriltags 3.1.7, the newest on PyPI) frees the tag
family before the detector, whose teardown then reads the freed family: an intermittent
segmentation fault whenever a detector is released (duckietown/lib-dt-apriltags#33).
:func:`release` frees them in the library's order instead; every detector built here is
released through it.
"""

from __future__ import annotations

import weakref

import numpy as np

from ekf_localization.vision.detection import TagDetection


def release(detector: object) -> None:
    """Free a ``dt_apriltags.Detector``'s C detector, then its tag families; its own
    ``__del__`` then does nothing. Safe to call twice."""
    ptr = getattr(detector, "tag_detector_ptr", None)
    if ptr is None:
        return
    detector.tag_detector_ptr = None
    libc = detector.libc
    libc.apriltag_detector_destroy.restype = None
    libc.apriltag_detector_destroy(ptr)
    for family, tf in detector.tag_families.items():
        destroy = getattr(libc, f"{family}_destroy")
        destroy.restype = None
        destroy(tf)
    detector.tag_families = {}


class AprilTagLibDetector:
    """tag36h11 through the AprilRobotics library; its ``quad_decimate`` etc. as keywords.

    The defaults are the library's own at full resolution: ``quad_decimate`` 1 (the library's
    2 halves the image before the quads are found and loses the small tags) and no blur
    (``quad_sigma`` 0). On real photographs they find every tag the library finds, at
    ~11 ms CPU per 640x480 frame (docs/apriltags.md, benchmarks/bench_tag_real_images.py).
    A blur (``quad_sigma`` 0.8) loses a third of the real tags; it only pays on images with
    uncorrelated pixel noise of a few grey levels, which makes the quad search slow.
    """

    name = "apriltag"

    def __init__(self, threads: int = 1, quad_decimate: float = 1.0, quad_sigma: float = 0.0,
                 refine_edges: bool = True, decode_sharpening: float = 0.25,
                 max_hamming: int = 0) -> None:
        from dt_apriltags import Detector

        self._max_hamming = int(max_hamming)
        self._detector = Detector(families="tag36h11", nthreads=threads,
                                  quad_decimate=quad_decimate, quad_sigma=quad_sigma,
                                  refine_edges=int(refine_edges),
                                  decode_sharpening=decode_sharpening)
        # the finalizer holds the binding's detector until this one is collected (or the
        # process exits) and then frees it in the library's order
        weakref.finalize(self, release, self._detector)

    def detect(self, image: np.ndarray) -> list[TagDetection]:
        """The tag36h11 tags in a mono8 image."""
        found = self._detector.detect(np.ascontiguousarray(image, dtype=np.uint8))
        return [TagDetection(int(d.tag_id), np.asarray(d.corners, dtype=float).reshape(4, 2) - 0.5,
                             int(d.hamming), float(d.decision_margin))
                for d in found if d.hamming <= self._max_hamming]
