"""tag_detect: find tag36h11 AprilTags in image files, and their poses.

    tag_detect IMAGE... [--detector apriltag|opencv] [--draw DIR]
                        [--camera CAMERA_INFO.yaml --tag-size S]

Prints one line per detection: ``<file> <id> x1 y1 x2 y2 x3 y3 x4 y4`` (pixels, pixel centres
at integers; corners bottom-left, bottom-right, top-right, top-left of the upright tag as the
camera sees it, the AprilRobotics order). With ``--camera`` (a calibration YAML,
vision/camera_yaml.py) and ``--tag-size`` (m, the black square's edge) a second line per tag,
``<file> <id> pose x y z qx qy qz qw ambiguity a rms r``, gives the tag's frame (+x out of its
face, +z up, as in the layouts) in the camera's optical frame (m, quaternion), solved by
vision/tag_pnp.py (IPPE, then Levenberg-Marquardt; ``a`` is the ratio of the two IPPE
solutions' errors, near 1 when the tilt is undecidable; ``r`` the reprojection RMS, px).
``--draw DIR`` writes each image to DIR with the tags outlined, the first corner marked and
the id written. Images are read with OpenCV (PNG, JPEG, ...) as greyscale. Exit 0; 2 when an
image cannot be read or DIR cannot be written (the other images are still processed), when
the camera file is not a calibration, or when an image's size is not the camera's (its
corners are printed, its poses not).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ekf_localization.core.angles import matrix_to_rpy, rpy_to_quaternion
from ekf_localization.vision import tag_pnp
from ekf_localization.vision.camera_yaml import load_camera_yaml
from ekf_localization.vision.corner_noise import CornerNoise
from ekf_localization.vision.detection import TagDetection
from ekf_localization.vision.detectors import DEFAULT_DETECTOR, DETECTORS, make_detector
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import Tag, TagLayout


def tag_pose(detection: TagDetection, camera: PinholeCamera, tag_size: float
             ) -> tuple[np.ndarray, float, float] | str:
    """(4x4 camera optical <- tag, ambiguity, reprojection RMS px) of one detection, or why not.

    The tag is a one-tag layout at the map's origin and the camera is ``base_link``: the
    solved robot pose is the camera in the tag's frame, inverted here."""
    layout = TagLayout({detection.tag_id: Tag(detection.tag_id, tag_size, np.eye(4))})
    problem, _ = tag_pnp.build_problem([detection], layout, camera, np.eye(4))
    fix = tag_pnp.solve(problem, layout, CornerNoise(), max_ambiguity=1.0)
    if isinstance(fix, tag_pnp.TagRejection):
        return f"{fix.reason}: {fix.detail}"
    return np.linalg.inv(tag_pnp.pose_matrix(fix.pose)), fix.ambiguity, fix.reprojection_rms


def format_pose(path: str, tag_id: int, camera_from_tag: np.ndarray, ambiguity: float,
                rms: float) -> str:
    """``<file> <id> pose x y z qx qy qz qw ambiguity a rms r`` (module docstring)."""
    q = np.array(rpy_to_quaternion(*matrix_to_rpy(camera_from_tag[:3, :3])))  # x, y, z, w
    if q[3] < 0.0:
        q = -q
    return (f"{path} {tag_id} pose " + " ".join(f"{v:.4f}" for v in camera_from_tag[:3, 3])
            + " " + " ".join(f"{v:.5f}" for v in q) + f" ambiguity {ambiguity:.3f} rms {rms:.2f}")


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
    parser.add_argument("--camera", metavar="CAMERA_INFO.yaml",
                        help="calibration YAML: print each tag's pose in the camera frame")
    parser.add_argument("--tag-size", type=float, metavar="S", help="tag edge (m, black square)")
    args = parser.parse_args(argv)
    if (args.camera is None) != (args.tag_size is None):
        parser.error("--camera and --tag-size go together")
    camera = None
    if args.camera is not None:
        if not (args.tag_size > 0.0 and np.isfinite(args.tag_size)):
            parser.error(f"--tag-size must be a positive length (m), got {args.tag_size}")
        try:
            camera = load_camera_yaml(args.camera)
        except ValueError as e:
            print(f"tag_detect: {e}", file=sys.stderr)
            return 2
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
        if camera is not None and image.shape != (camera.height, camera.width):
            print(f"tag_detect: '{path}' is {image.shape[1]}x{image.shape[0]}, the camera "
                  f"{camera.width}x{camera.height}: no poses", file=sys.stderr)
            status = 2
        for d in found:
            print(format_detection(path, d))
            if camera is not None and image.shape == (camera.height, camera.width):
                pose = tag_pose(d, camera, args.tag_size)
                if isinstance(pose, str):
                    print(f"tag_detect: {path} tag {d.tag_id}: no pose ({pose})", file=sys.stderr)
                else:
                    print(format_pose(path, d.tag_id, *pose))
        if args.draw:
            target = Path(args.draw) / Path(path).name
            if not cv2.imwrite(str(target), draw(image, found)):
                print(f"tag_detect: cannot write '{target}'", file=sys.stderr)
                status = 2
    sys.stdout.flush()
    return status


if __name__ == "__main__":
    sys.exit(main())
