"""Where a tag fix's error comes from, and how honest each corner noise model makes it.

Along the truth of images-demo bags (``ekf_demo --camera images --seed S --out DIR``) it renders
the simulator's camera again at every capture (config/sim.yaml's ``camera_images``, read as
sim_node reads it, with the demo's layout), detects the tags with the AprilRobotics detector,
and

* splits each tag's corner error (against the exact projection at the exposure's middle) into
  the shift shared by its four corners and each corner's own error, by image motion;
* solves every frame as tag_localizer does and prints each noise model's fix NEES (x, y, θ
  against the truth, χ²(3)) per bag, pooled mean and median (docs/tag_localizer.md).

    python benchmarks/tag_noise_study.py DIR [DIR ...]      # DIR: an ekf_demo --out folder
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ekf_localization.core.angles import wrap_angles  # noqa: E402
from ekf_localization.ros.parameters import parameters_from_yaml  # noqa: E402
from ekf_localization.tools import bag_io  # noqa: E402
from ekf_localization.tools.evaluation import interpolate  # noqa: E402
from ekf_localization.vision import tag_pnp  # noqa: E402
from ekf_localization.vision.corner_noise import CornerNoise  # noqa: E402
from ekf_localization.vision.detectors.apriltag_lib import AprilTagLibDetector  # noqa: E402
from sim_robot.ros.sim_params import parse_parameters  # noqa: E402
from sim_robot.world.camera_image_sensor import CameraImageSensor  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
EXPOSURE = 0.004   # config/sim.yaml camera_images.exposure_time: checked in main()
MODELS = {   # name: (corner noise, max_ambiguity)
    "pixel_std 1.0 (before)": (CornerNoise(1.0), 0.2),
    "pixel_std 0.33": (CornerNoise(0.33), 0.2),
    "shift+blur 0.08/0.08/0.05, amb 0.2": (CornerNoise(0.08, 0.08, 0.05, EXPOSURE, 4.0), 0.2),
    "shift+blur 0.08/0.08/0.05, amb 0.1": (CornerNoise(0.08, 0.08, 0.05, EXPOSURE, 4.0), 0.1),
    "shift+blur 0.09/0.09/0.05, amb 0.1": (CornerNoise(0.09, 0.09, 0.05, EXPOSURE, 4.0), 0.1),
    "shift+blur 0.10/0.09/0.05, amb 0.1": (CornerNoise(0.10, 0.09, 0.05, EXPOSURE, 4.0), 0.1),
    "shift+blur 0.10/0.10/0.06, amb 0.1": (CornerNoise(0.10, 0.10, 0.06, EXPOSURE, 4.0), 0.1),
    "shipped 0.10/0.10/0.05, amb 0.1": (CornerNoise(0.10, 0.10, 0.05, EXPOSURE, 4.0), 0.1),
}
BLUR_BINS = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, 8.0))


def _pixels(camera, pose: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(4, 2) pixels of map corners seen from the optical frame at ``pose`` (map <- optical)."""
    return camera.project((corners - pose[:3, 3]) @ pose[:3, :3])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="ekf_demo --camera images --out folders")
    args = parser.parse_args(argv)
    values = parameters_from_yaml(REPO / "config" / "sim.yaml", "sim_node")
    values["camera_images.enabled"] = True     # as ekf_demo --camera images sets it
    config = parse_parameters(values)[1].camera_images
    if config.render.exposure_time != EXPOSURE:
        parser.error(f"config/sim.yaml's exposure_time is {config.render.exposure_time} s; "
                     f"MODELS assume {EXPOSURE} s")
    layout, camera, period_ns = config.layout, config.camera, config.period_ns
    detector = AprilTagLibDetector()
    shifts, owns, blurs = [], [], []
    pooled: dict[str, list[float]] = {name: [] for name in MODELS}
    for k, run in enumerate(args.runs):
        truth = bag_io.read_odometry(run / "bag", "/ground_truth/odom")
        sensor = CameraImageSensor(config, seed=k)
        stamps = np.arange((truth.t_ns[0] // period_ns + 1) * period_ns, truth.t_ns[-1], period_ns)
        nees: dict[str, list[float]] = {name: [] for name in MODELS}
        last: dict[str, tuple[int, np.ndarray] | None] = dict.fromkeys(MODELS)
        mount = sensor.base_to_optical()
        for stamp, state in zip(stamps, interpolate(truth, stamps), strict=True):
            detections = detector.detect(sensor.capture(int(stamp), state).image)
            cam_pose = sensor.camera_pose(state, 0.0)
            start, end = sensor.camera_pose(state, -EXPOSURE / 2), sensor.camera_pose(state, EXPOSURE / 2)
            for d in detections:
                if d.tag_id not in layout.tags:
                    continue
                corners = layout.tags[d.tag_id].corners_map()
                exact = _pixels(camera, cam_pose, corners)
                err = np.asarray(d.corners) - exact
                shifts.append(err.mean(axis=0))
                owns.append(err - err.mean(axis=0))
                motion = _pixels(camera, end, corners) - _pixels(camera, start, corners)
                blurs.append(float(np.hypot(*motion.mean(axis=0))))
            for name, (noise, ambiguity) in MODELS.items():
                fix, _ = tag_pnp.localize(detections, layout, camera, mount, noise, ambiguity, 0.5,
                                          last[name], int(stamp))
                if not isinstance(fix, tag_pnp.TagFix):
                    continue
                last[name] = (int(stamp), fix.pose)
                e = np.array([fix.pose[0] - state[0], fix.pose[1] - state[1], 0.0])
                e[2] = wrap_angles(np.array([fix.pose[5] - state[2]]))[0]
                cov = fix.covariance[np.ix_([0, 1, 5], [0, 1, 5])]
                nees[name].append(float(e @ np.linalg.solve(cov, e)))
        print(f"{run}: " + "; ".join(f"{name} {np.mean(v):.2f}" for name, v in nees.items()), flush=True)
        for name, v in nees.items():
            pooled[name].append(float(np.mean(v)))
            pooled[name + " all"] = pooled.get(name + " all", []) + v
    shifts_a, owns_a, blurs_a = np.array(shifts), np.array(owns), np.array(blurs)
    print(f"\n{len(blurs_a)} tags; across the motion (v): shared {shifts_a[:, 1].std():.3f} px, "
          f"own {owns_a[:, :, 1].std():.3f} px")
    print("| image motion over the exposure | tags | shared shift std (u) | own error std (u) |")
    for lo, hi in BLUR_BINS:
        k = (blurs_a >= lo) & (blurs_a < hi)
        if k.any():
            print(f"| {lo:.0f}-{hi:.0f} px | {k.sum()} | {shifts_a[k, 0].std():.3f} px | "
                  f"{owns_a[k][:, :, 0].std():.3f} px |")
    print("\n| model | fix NEES per bag | pooled mean | pooled median (χ²(3): 2.37) |")
    for name in MODELS:
        per, every = pooled[name], pooled[name + " all"]
        print(f"| {name} | {min(per):.2f}-{max(per):.2f} | {np.mean(every):.2f} | {np.median(every):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
