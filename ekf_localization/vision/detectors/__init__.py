"""tag36h11 detectors behind :class:`ekf_localization.vision.detection.TagDetector`.

``make_detector(name)`` builds one by name: ``apriltag`` (the AprilRobotics C library through
``dt_apriltags``, rosdep key ``python-dt-apriltags-pip``) or ``opencv`` (OpenCV's aruco
``DICT_APRILTAG_36h11``, key ``python3-opencv``). docs/apriltags.md compares them on rendered
images. Each module imports its library only when built.
"""

from __future__ import annotations

from ekf_localization.vision.detection import TagDetector

DETECTORS = ("opencv", "apriltag")
DEFAULT_DETECTOR = "apriltag"


def make_detector(name: str = DEFAULT_DETECTOR, **options: object) -> TagDetector:
    """The detector called ``name`` (one of :data:`DETECTORS`); ValueError otherwise."""
    if name == "opencv":
        from ekf_localization.vision.detectors.opencv_aruco import OpenCvArucoDetector

        return OpenCvArucoDetector(**options)
    if name == "apriltag":
        from ekf_localization.vision.detectors.apriltag_lib import AprilTagLibDetector

        return AprilTagLibDetector(**options)
    raise ValueError(f"unknown tag detector {name!r}: expected one of {', '.join(DETECTORS)}")
