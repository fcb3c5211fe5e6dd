"""Camera image rendering cost next to the 1 kHz world, on one core.

    python benchmarks/bench_camera_render.py [--seconds 10] [--doc]

Drives the simulated robot (config/sim.yaml's world, one trial) around the field centre,
turning, and renders a 640x480 image of config/tags/ftc_seed000.yaml at 20 Hz from its true
state, as sim_node does with camera_images.enabled (noise 2, 4 ms exposure, motion blur).
Prints the CPU time per rendered frame and, as the peer from the same run, the world's CPU
time per simulated second (1000 physics ticks and its sensors); their sum per simulated second
must stay well under 1 s for real time on one core. CPU time (time.process_time) because
the machine is shared; OpenCV is held to one thread.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from ekf_localization.vision.pinhole import PinholeCamera  # noqa: E402
from ekf_localization.vision.tag_layout import load_tag_layout  # noqa: E402
from sim_robot.world.camera_image_sensor import CameraImageConfig, CameraImageSensor  # noqa: E402
from sim_robot.world.camera_render import RenderSettings  # noqa: E402
from sim_robot.world.world import World, WorldConfig  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    import cv2

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds")
    ap.add_argument("--doc", action="store_true", help="write the figure into docs/performance.md")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    config = CameraImageConfig(PinholeCamera.from_fov(640, 480, math.radians(70.0)),
                               load_tag_layout(ROOT / "config" / "tags" / "ftc_seed000.yaml"),
                               render=RenderSettings(noise_std=2.0))
    sensor = CameraImageSensor(config, seed=1)
    world = World(WorldConfig(), n_trials=1, seed=1)
    world.reset((0.0, 0.0, 0.0))
    world.set_command((0.2, 0.0, 0.6))
    period = config.period_ns
    world_cpu = render_cpu = 0.0
    frames = 0
    for _ in range(int(args.seconds * 1e9) // period):
        t0 = time.process_time()
        world.advance(period)
        t1 = time.process_time()
        sensor.capture(world.t_ns, world.truth[0])
        t2 = time.process_time()
        world_cpu += t1 - t0
        render_cpu += t2 - t1
        frames += 1
    render_ms = 1e3 * render_cpu / frames
    world_ms = 1e3 * world_cpu / args.seconds
    load = os.getloadavg()[0]
    share = (20 * render_ms + world_ms) / 1e3
    print(f"render: {render_ms:.2f} ms/frame CPU (640x480, {len(config.layout.tags)} tags, noise, blur); "
          f"peer: world {world_ms:.0f} ms CPU per simulated second (1 kHz); "
          f"20 Hz images + world = {share:.0%} of one core; load {load:.1f}")
    if args.doc:
        from perf_doc import write_row

        write_row("camera image render, 640x480 (CPU per frame)", f"{render_ms:.2f} ms",
                  f"world at 1 kHz: {world_ms:.0f} ms CPU per sim second")
    return 0


if __name__ == "__main__":
    sys.exit(main())
