"""Speed of tag_localizer's per-frame work: tag36h11 detection + multi-tag PnP at 640x480, one core.

The frames are the tag tests' scene (three 16.5 cm tags on a wall, 1.2-2.2 m away, a moving
robot; test/helpers/tag_images.py, over 4 s) with the noise and lens blur of real photographs
(``PHOTO_NOISE_STD``, ``PHOTO_BLUR_STD``; docs/apriltags.md), rendered before the clock starts.
Each frame: the detector (``vision/detectors``) then ``vision/tag_pnp.localize`` with
config/tag_localizer.yaml's corner noise, ambiguity gate and field margin and the previous fix
(the blur's motion), what tag_localizer does per image besides reading the message. OpenCV is
held to one thread (``cv2.setNumThreads(1)``). Printed: ``<X> frames/s`` for the shipped
detector, the other detectors' figure, and the bare AprilRobotics library with its own settings
at full resolution (test/helpers/real_tags.py) through the same PnP, all from the same run,
with the shipped detector's time relative to the bare library's.

    python benchmarks/bench_tag_localizer.py [--frames 200] [--doc]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from helpers import real_tags, tag_images  # noqa: E402

from ekf_localization.core.units import seconds_to_ns  # noqa: E402
from ekf_localization.ros.parameters import parameters_from_yaml  # noqa: E402
from ekf_localization.ros.tag_localizer_parameters import parse_settings  # noqa: E402
from ekf_localization.vision import tag_pnp  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DURATION_S = 4.0   # frames() spreads the poses over this time
SHIPPED = parse_settings(parameters_from_yaml(REPO / "config" / "tag_localizer.yaml", "tag_localizer"))


def frames(n: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    rng = np.random.default_rng(0)
    images, truths = [], []
    for i in range(n):
        t = DURATION_S * i / n
        truth = np.array([1.7 + 0.4 * math.sin(0.6 * t), 1.6 + 0.1 * t, 0.0, 0.0, 0.0,
                          math.pi - 0.1 * math.sin(0.9 * t)])
        images.append(tag_images.render(truth, (1, 2, 3), noise_std=tag_images.PHOTO_NOISE_STD,
                                        rng=rng, blur_std=tag_images.PHOTO_BLUR_STD))
        truths.append(truth)
    return images, truths


def measure(detector, images: list[np.ndarray], truths: list[np.ndarray]) -> tuple[float, int, float]:
    """(frames/s, fixes, max position error m) of detection + PnP over ``images``."""
    mount = tag_images.mount()
    fixes, worst = 0, 0.0
    stamps = [seconds_to_ns(DURATION_S * i / len(images)) for i in range(len(images))]
    detector.detect(images[0])  # warm-up (first-call allocations)
    t0 = time.perf_counter()
    results, previous = [], None
    for i, image in enumerate(images):
        dets = detector.detect(image)
        fix = tag_pnp.localize(dets, tag_images.LAYOUT, tag_images.CAMERA, mount, SHIPPED.corner_noise,
                               SHIPPED.max_ambiguity, SHIPPED.field_margin, previous, stamps[i])[0]
        if isinstance(fix, tag_pnp.TagFix):
            previous = (stamps[i], fix.pose)
        results.append(fix)
    elapsed = time.perf_counter() - t0
    for fix, truth in zip(results, truths, strict=True):
        if isinstance(fix, tag_pnp.TagFix):
            fixes += 1
            worst = max(worst, float(np.hypot(*(fix.pose[:2] - truth[:2]))))
    return len(images) / elapsed, fixes, worst


def main(argv: list[str] | None = None) -> int:
    import cv2

    from ekf_localization.vision import detectors

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--doc", action="store_true", help="write the row in docs/performance.md")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    images, truths = frames(args.frames)
    figures = {}
    for name in detectors.DETECTORS:
        try:
            det = detectors.make_detector(name)
        except (ImportError, ValueError) as exc:
            print(f"{name}: not available ({exc})")
            continue
        figures[name] = measure(det, images, truths)
    bare = None
    try:
        bare = measure(real_tags.ReferenceDetector(), images, truths)
    except ImportError as exc:
        print(f"bare library: not available ({exc})")
    default = detectors.DEFAULT_DETECTOR
    for name, (fps, fixes, worst) in sorted(figures.items(), key=lambda kv: kv[0] != default):
        tag = " (shipped)" if name == default else ""
        print(f"{name}{tag}: {fps:.1f} frames/s detection + PnP at 640x480, one core; "
              f"{fixes}/{len(images)} fixes, worst position error {worst:.3f} m")
    if bare is not None:
        print(f"bare AprilRobotics library, its own settings (quad_decimate 1, quad_sigma 0): "
              f"{bare[0]:.1f} frames/s with the same PnP; {bare[1]}/{len(images)} fixes, worst "
              f"position error {bare[2]:.3f} m")
        if default in figures:
            print(f"shipped time per frame / bare library's: {bare[0] / figures[default][0]:.2f}")
    if args.doc and default in figures:
        from perf_doc import write_row  # benchmarks/ is on sys.path when run as a script

        peers = ", ".join([f"{n}: {f[0]:.1f} frames/s" for n, f in figures.items() if n != default]
                          + ([f"bare library: {bare[0]:.1f} frames/s"] if bare else []))
        write_row("tag_localizer: detection + PnP at 640x480, one core",
                  f"{figures[default][0]:.1f} frames/s ({default})", peers or "no other detector installed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
