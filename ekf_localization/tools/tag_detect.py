"""tag_detect: find tag36h11 AprilTags in image files.

    tag_detect IMAGE... [--detector apriltag|opencv] [--draw DIR]

Prints one line per detection: ``<file> <id> x1 y1 x2 y2 x3 y3 x4 y4`` (pixels, pixel centres
at integers; corners bottom-left, bottom-right, top-right, top-left of the upright tag as the
camera sees it, the AprilRobotics order). ``--draw DIR`` writes each image to DIR with the
tags outlined, the first corner marked and the id written. Images are read with OpenCV (PNG,
JPEG, ...) as greyscale. Exit 0; 2 when an image cannot be read or DIR cannot be written
(the other images are still processed).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ekf_localization.vision.detection import TagDetection
from ekf_localization.vision.detectors import DEFAULT_DETECTOR, DETECTORS, make_detector


def draw(image: np.ndarray, detections: list[TagDetection]) -> np.ndarray:
    """A BGR copy of the mono8 ``image`` with the detections outlined and labelled."""
    import cv2

    out = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    for d in detections:
        pts = np.rint(d.corners).astype(np.int32)
        cv2.polylines(out, [pts.reshape(-1, 1, 2)], True, (0, 255, 0), 1, cv2.LINE_AA)
        cv2.circle(out, tuple(int(v) for v in pts[0]), 3, (0, 0, 255), -1, cv2.LINE_AA)
        centre = tuple(int(v) for v in np.rint(d.corners.mean(axis=0)))
        cv2.putText(out, str(d.tag_id), centre, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 0, 0), 1,
                    cv2.LINE_AA)
    return out


def format_detection(path: str, d: TagDetection) -> str:
    """``<file> <id> x1 y1 ... x4 y4`` with 0.01 px resolution."""
    return f"{path} {d.tag_id} " + " ".join(f"{v:.2f}" for v in d.corners.ravel())


def main(argv: list[str] | None = None) -> int:
    import cv2

    parser = argparse.ArgumentParser(prog="tag_detect", description=__doc__.split("\n")[0])
    parser.add_argument("images", nargs="+", metavar="IMAGE")
    parser.add_argument("--detector", choices=DETECTORS, default=DEFAULT_DETECTOR)
    parser.add_argument("--draw", metavar="DIR", help="write the images with the tags drawn")
    args = parser.parse_args(argv)
    detector = make_detector(args.detector)
    status = 0
    if args.draw:
        Path(args.draw).mkdir(parents=True, exist_ok=True)
    for path in args.images:
        image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if image is None:
            print(f"tag_detect: cannot read image '{path}'", file=sys.stderr)
            status = 2
            continue
        found = sorted(detector.detect(image), key=lambda d: d.tag_id)
        for d in found:
            print(format_detection(path, d))
        if args.draw:
            target = Path(args.draw) / Path(path).name
            if not cv2.imwrite(str(target), draw(image, found)):
                print(f"tag_detect: cannot write '{target}'", file=sys.stderr)
                status = 2
    sys.stdout.flush()
    return status


if __name__ == "__main__":
    sys.exit(main())
