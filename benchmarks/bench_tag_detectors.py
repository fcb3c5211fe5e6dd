"""Tag detectors compared on rendered 640x480 images: detection rate, corner error, time.

    python benchmarks/bench_tag_detectors.py [--frames 40] [--seed 1] [--write]

Each condition changes one thing from the base (one 16.51 cm tag36h11 tag at 2 m, seen head-on,
the real photographs' noise (0.42 grey levels) and lens blur (0.52 px), 4 ms exposure, no
motion): distance, the tag's angle to the optical axis, motion blur (camera yaw rate over the 4
ms exposure), noise, lighting (dim exposure and a left-right illumination gradient). Each frame
draws a random id, a random lateral offset that keeps the tag in view and a random camera
height. Corner error: max over the 4 corners of the distance to the renderer's projection
(``PinholeCamera.project`` of ``Tag.corners_map()``), for the tags found with the right id;
wrong ids are counted apart. Time: CPU time (``time.process_time``) of ``detect()`` on one
thread, the mean over the condition's frames.
``--write`` replaces the table in docs/apriltags.md.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ekf_localization.vision.detectors import make_detector  # noqa: E402
from ekf_localization.vision.pinhole import PinholeCamera  # noqa: E402
from ekf_localization.vision.tag_layout import tag_layout_from_dict  # noqa: E402
from sim_robot.world.camera_render import CameraRenderer, RenderSettings, optical_pose, planar_pose  # noqa: E402

DOC = Path(__file__).resolve().parents[1] / "docs" / "apriltags.md"
BEGIN, END = "<!-- bench_tag_detectors: begin -->", "<!-- bench_tag_detectors: end -->"
CAMERA = PinholeCamera.from_fov(640, 480, math.radians(70.0))
TAG_SIZE = 0.1651
# column -> (detector, options): the two detectors as shipped, and AprilRobotics variants
VARIANTS = {"opencv": ("opencv", {}), "apriltag": ("apriltag", {}),
            "apriltag quad_sigma 0.8": ("apriltag", {"quad_sigma": 0.8}),
            "apriltag decimate 2": ("apriltag", {"quad_decimate": 2.0})}


@dataclass(frozen=True)
class Condition:
    label: str
    distance: float = 2.0          # m, camera to tag centre along the optical axis
    angle_deg: float = 0.0         # tag yawed away from facing the camera
    yaw_rate: float = 0.0          # rad/s of the camera during the exposure
    exposure_time: float = 0.004   # s (0.004 is the reference: nominal brightness)
    noise_std: float = 0.42        # grey levels } config/sim.yaml camera_images: the noise
    optics_blur_std: float = 0.52  # px          } and lens blur of real photographs
    gradient: float = 0.0


CONDITIONS = [
    Condition("base: 2 m, head-on, the photographs' noise and blur"),
    Condition("noise 2", noise_std=2.0),
    Condition("1 m", distance=1.0),
    Condition("4 m", distance=4.0),
    Condition("6 m", distance=6.0),
    Condition("8 m", distance=8.0),
    Condition("angle 45 deg", angle_deg=45.0),
    Condition("angle 70 deg", angle_deg=70.0),
    Condition("blur: turning 1 rad/s (1.8 px in 4 ms)", yaw_rate=1.0),
    Condition("blur: turning 2 rad/s (3.7 px in 4 ms)", yaw_rate=2.0),
    Condition("blur: turning 4 rad/s (7.3 px in 4 ms)", yaw_rate=4.0),
    Condition("noise 8", noise_std=8.0),
    Condition("noise 16", noise_std=16.0),
    Condition("dim (exposure x0.3), noise 4", exposure_time=0.0012, noise_std=4.0),
    Condition("gradient 0.6, 4 m, 45 deg", distance=4.0, angle_deg=45.0, gradient=0.6),
]


def _frame(cond: Condition, rng: np.random.Generator):
    """(image, tag id, true corners) of one random frame of ``cond``."""
    tag_id = int(rng.integers(0, 587))
    half_fov = math.atan(0.5 * CAMERA.width / CAMERA.fx)
    lateral = rng.uniform(-0.5, 0.5) * math.tan(half_fov) * cond.distance * 0.8
    z = rng.uniform(0.2, 0.4)
    yaw = math.pi + math.radians(cond.angle_deg) * rng.choice([-1.0, 1.0])
    layout = tag_layout_from_dict({"tags": [{"id": tag_id, "size": TAG_SIZE,
                                             "position": [cond.distance, lateral, z + rng.uniform(-0.1, 0.1)],
                                             "yaw": yaw}]})
    settings = RenderSettings(exposure_time=cond.exposure_time, noise_std=cond.noise_std,
                              illumination_gradient=cond.gradient,
                              optics_blur_std=cond.optics_blur_std)
    renderer = CameraRenderer(CAMERA, layout, settings)
    start = optical_pose(planar_pose(0.0, 0.0, z, 0.0))
    end = optical_pose(planar_pose(0.0, 0.0, z, cond.yaw_rate * cond.exposure_time))
    image = renderer.render(start, end if cond.yaw_rate else None, rng)
    # the truth at the exposure's middle (the blur kernel is centred on it)
    mid = optical_pose(planar_pose(0.0, 0.0, z, 0.5 * cond.yaw_rate * cond.exposure_time))
    corners = layout.tags[tag_id].corners_map()
    truth = CAMERA.project((corners - mid[:3, 3]) @ mid[:3, :3])
    return image, tag_id, truth


def run(frames: int, seed: int) -> list[dict]:
    detectors = {col: make_detector(name, **options) for col, (name, options) in VARIANTS.items()}
    rows = []
    for cond in CONDITIONS:
        rng = np.random.default_rng(seed)
        stats = {n: {"found": 0, "wrong": 0, "err": [], "t": 0.0} for n in detectors}
        render_t = 0.0
        for _ in range(frames):
            t0 = time.perf_counter()
            image, tag_id, truth = _frame(cond, rng)
            render_t += time.perf_counter() - t0
            for name, det in detectors.items():
                t0 = time.process_time()
                found = det.detect(image)
                stats[name]["t"] += time.process_time() - t0
                for d in found:
                    if d.tag_id == tag_id:
                        stats[name]["found"] += 1
                        stats[name]["err"].append(float(np.linalg.norm(d.corners - truth, axis=1).max()))
                    else:
                        stats[name]["wrong"] += 1
        rows.append({"cond": cond.label, "render_ms": 1e3 * render_t / frames,
                     **{n: s for n, s in stats.items()}})
    return rows


def table(rows: list[dict], frames: int) -> str:
    """Rows: conditions; a cell per detector: found / frames, corner error mean / max, time."""
    lines = ["| condition | " + " | ".join(VARIANTS) + " |", "|" + "---|" * (1 + len(VARIANTS))]
    for r in rows:
        cells = [r["cond"]]
        for n in VARIANTS:
            s, e = r[n], r[n]["err"]
            wrong = f" ({s['wrong']} wrong id)" if s["wrong"] else ""
            err = f"{np.mean(e):.2f} / {np.max(e):.2f} px" if e else "-"
            cells.append(f"{s['found']}/{frames}{wrong}, {err}, {1e3 * s['t'] / frames:.1f} ms")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--write", action="store_true", help="replace the table in docs/apriltags.md")
    args = parser.parse_args(argv)
    import cv2

    cv2.setNumThreads(1)
    rows = run(args.frames, args.seed)
    render_ms = np.mean([r["render_ms"] for r in rows])
    cmd = "python benchmarks/bench_tag_detectors.py " + " ".join(argv or sys.argv[1:])
    text = (f"{table(rows, args.frames)}\n\n`{cmd.strip()}`, {time.strftime('%Y-%m-%d')}, "
            f"load {os.getloadavg()[0]:.1f}; rendering (one tag, layout built per frame): "
            f"{render_ms:.1f} ms/frame mean.")
    print(text)
    if args.write:
        doc = DOC.read_text()
        start, stop = doc.index(BEGIN) + len(BEGIN), doc.index(END)
        DOC.write_text(doc[:start] + "\n" + text + "\n" + doc[stop:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
