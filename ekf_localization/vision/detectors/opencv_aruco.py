"""OpenCV's aruco module with its ``DICT_APRILTAG_36h11`` dictionary.

Works with OpenCV 4.6 (Ubuntu 24.04's python3-opencv: ``cv2.aruco.detectMarkers`` and
``DetectorParameters_create``) and with 4.7+ (``cv2.aruco.ArucoDetector``). Corners are
refined with ``CORNER_REFINE_SUBPIX``. OpenCV returns the corners clockwise from its marker's
top-left, and its 36h11 markers are the printed AprilRobotics tags turned by 180 degrees
(opencv/opencv-python#1195): its (tl, tr, br, bl) are the printed tag's (br, bl, tl, tr),
reordered here into the AprilRobotics order (bl, br, tr, tl).
"""

from __future__ import annotations

import numpy as np

from ekf_localization.vision.detection import TagDetection

# OpenCV's corners 0..3 are the printed tag's br, bl, tl, tr -> (bl, br, tr, tl)
_TO_APRILTAG_ORDER = [1, 0, 3, 2]


class OpenCvArucoDetector:
    """tag36h11 through ``cv2.aruco``; ``max_hamming`` bits of error corrected (default 0)."""

    name = "opencv"

    def __init__(self, max_hamming: int = 0, refine: str = "subpix") -> None:
        import cv2

        aruco = cv2.aruco
        self._aruco = aruco
        dictionary = aruco.getPredefinedDictionary(aruco.DICT_APRILTAG_36h11)
        if hasattr(aruco, "DetectorParameters_create"):   # OpenCV <= 4.6
            params = aruco.DetectorParameters_create()
        else:
            params = aruco.DetectorParameters()
        refinements = {"none": aruco.CORNER_REFINE_NONE, "subpix": aruco.CORNER_REFINE_SUBPIX,
                       "contour": aruco.CORNER_REFINE_CONTOUR,
                       "apriltag": aruco.CORNER_REFINE_APRILTAG}
        if refine not in refinements:
            raise ValueError(f"refine: expected one of {sorted(refinements)}, got {refine!r}")
        params.cornerRefinementMethod = refinements[refine]
        # 36h11 has minimum Hamming distance 11: correcting <= 2 bits keeps false ids rare.
        params.errorCorrectionRate = min(1.0, max_hamming / 5.0) if max_hamming else 0.0
        self._max_hamming = int(max_hamming)
        self._dictionary, self._params = dictionary, params
        self._detector = (aruco.ArucoDetector(dictionary, params)
                          if hasattr(aruco, "ArucoDetector") else None)

    def detect(self, image: np.ndarray) -> list[TagDetection]:
        """The tag36h11 tags in a mono8 image."""
        if self._detector is not None:
            corners, ids, _ = self._detector.detectMarkers(image)
        else:
            corners, ids, _ = self._aruco.detectMarkers(image, self._dictionary,
                                                        parameters=self._params)
        if ids is None:
            return []
        return [TagDetection(int(i), np.asarray(c, dtype=float).reshape(4, 2)[_TO_APRILTAG_ORDER])
                for c, i in zip(corners, ids.ravel(), strict=True)]
