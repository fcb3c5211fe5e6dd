"""Time tag_localizer spends turning one 640x480 frame into grey, per format (ros/image_io.py).

The frames are bench_tag_localizer's (the tag tests' scene, 2 grey levels of sensor noise),
encoded before the clock starts: sensor_msgs/Image in mono8, mono16, yuv422 and rgb8, and
sensor_msgs/CompressedImage as JPEG (quality 95 and 80) and PNG (OpenCV's encoder defaults).
Each is read as tag_localizer reads it (``image_to_mono8``, ``compressed_to_mono8``: OpenCV's
decoder straight to grey), OpenCV held to one thread. Printed per format: ms per frame (the
fastest of the passes), the share of the shipped detector's time on the same frames (the rest of
tag_localizer's work on a frame), and the message's size.

    python benchmarks/bench_image_decode.py [--frames 50] [--passes 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_tag_localizer import SHIPPED, frames  # noqa: E402

from ekf_localization.ros.image_io import compressed_to_mono8, image_to_mono8  # noqa: E402


def messages(images: list[np.ndarray]) -> dict[str, tuple[list, object]]:
    """format -> (messages, reader)."""
    import cv2

    def raw(encoding: str, pixels: np.ndarray) -> SimpleNamespace:
        h, w = images[0].shape
        data = pixels.tobytes()
        return SimpleNamespace(encoding=encoding, height=h, width=w, step=len(data) // h, data=data,
                               is_bigendian=0)

    def yuv(g: np.ndarray) -> np.ndarray:
        out = np.full((g.shape[0], 2 * g.shape[1]), 128, dtype=np.uint8)
        out[:, 1::2] = g
        return out

    def compressed(fmt: str, ext: str, g: np.ndarray, opts: list[int]) -> SimpleNamespace:
        return SimpleNamespace(format=fmt, data=cv2.imencode(ext, g, opts)[1].tobytes())

    return {
        "Image mono8": ([raw("mono8", g) for g in images], image_to_mono8),
        "Image mono16": ([raw("mono16", g.astype("<u2") << 8) for g in images], image_to_mono8),
        "Image yuv422": ([raw("yuv422", yuv(g)) for g in images], image_to_mono8),
        "Image rgb8": ([raw("rgb8", np.dstack([g] * 3)) for g in images], image_to_mono8),
        "CompressedImage JPEG q95": ([compressed("jpeg", ".jpg", g, [cv2.IMWRITE_JPEG_QUALITY, 95])
                                     for g in images], compressed_to_mono8),
        "CompressedImage JPEG q80": ([compressed("jpeg", ".jpg", g, [cv2.IMWRITE_JPEG_QUALITY, 80])
                                     for g in images], compressed_to_mono8),
        "CompressedImage PNG": ([compressed("png", ".png", g, []) for g in images], compressed_to_mono8),
    }


def main(argv: list[str] | None = None) -> int:
    import cv2

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--passes", type=int, default=5)
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    images, _ = frames(args.frames)
    table = messages(images)
    from ekf_localization.vision.detectors import make_detector

    def best_ms(work, items: list) -> float:
        """ms per item of the fastest of ``passes`` passes (the least disturbed by other load)."""
        work(items[0])  # warm-up
        per_pass = []
        for _ in range(args.passes):
            t0 = time.perf_counter()
            for item in items:
                work(item)
            per_pass.append((time.perf_counter() - t0) / len(items) * 1e3)
        return min(per_pass)

    ms = {name: best_ms(reader, msgs) for name, (msgs, reader) in table.items()}
    detect_ms = best_ms(make_detector(SHIPPED.detector).detect, images)
    h, w = images[0].shape
    print(f"{w}x{h}, {args.frames} frames x {args.passes} passes, one OpenCV thread, cv2 {cv2.__version__}")
    print(f"detection ({SHIPPED.detector}, shipped settings): {detect_ms:.2f} ms per frame")
    print("| message | ms per frame | of the detection's time | size |")
    print("|---|---|---|---|")
    for name, (msgs, _) in table.items():
        size = statistics.mean(len(m.data) for m in msgs) / 1e3
        print(f"| {name} | {ms[name]:.3f} | {100 * ms[name] / detect_ms:.1f} % | {size:.0f} kB |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
