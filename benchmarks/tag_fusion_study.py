"""PnP pose vs tag-corner fusion on the same runs (ROS-free, seeded): which feeds the EKF better?

Each run drives the robot along the tag wall of the tag tests' scene (three 16.5 cm tags on
the wall x = 0, a 640x480 70° camera 10 cm ahead of base_link, pitched up 5°): x from 1.2 to
2.2 m away, y 1.2 -> 2.6 m at 0.3 m/s, facing the wall with a slow yaw sway. A 10 Hz camera
sees each tag whose corners fall inside the image; the corner pixels get N(0, sigma_px²) noise.
The same noisy corners go to two filters with the same process noise:

* ``pnp``: vision/tag_pnp.localize -> a PoseWithCovarianceStamped (x, y, yaw fused, the
  covariance from the PnP Jacobian) -> the ``pose`` input;
* ``corners``: each visible tag's corners -> its ``tag_corners`` input (inputs/tag_corners.py).

No odometry: the constant-velocity model between frames, so the figures show the camera
fusion itself. Printed per method: position and yaw RMSE over the run (after 1 s), the mean
NEES of (x, y, yaw) (chi²(3): 3 if honest), and the frames used.

    python benchmarks/tag_fusion_study.py --runs 20 --pixel-std 1.0
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from helpers import tag_images  # noqa: E402

from ekf_localization.core.angles import rpy_to_quaternion, wrap_angle  # noqa: E402
from ekf_localization.core.units import ns_to_sec_nanosec, ns_to_seconds  # noqa: E402
from ekf_localization.inputs.pose import read as read_pose  # noqa: E402
from ekf_localization.inputs.tag_corners import TagCornerObservation  # noqa: E402
from ekf_localization.models.registry import MODELS, make_localizer  # noqa: E402
from ekf_localization.ros.ekf_parameters import parse_ekf_config  # noqa: E402
from ekf_localization.vision import tag_pnp  # noqa: E402
from ekf_localization.vision.corner_noise import CornerNoise  # noqa: E402
from ekf_localization.vision.detection import TagDetection  # noqa: E402

CAM = tag_images.CAMERA
IDS = tuple(sorted(tag_images.LAYOUT.tags))
FRAME_NS = 100_000_000
DURATION_S = 4.7


def _diag15(values: dict[int, float]) -> list[float]:
    m = np.zeros((15, 15))
    for f, v in values.items():
        m[f, f] = v
    return m.ravel().tolist()


def _params(method: str, start: np.ndarray, pixel_std: float) -> dict:
    p = {"model": "mecanum", "world_frame": "map", "frequency": 50.0,
         "initial_state": [start[0], start[1], 0.0, 0.0, 0.0, start[2]] + [0.0] * 9,
         "initial_estimate_covariance": _diag15({0: 0.04, 1: 0.04, 5: 0.04, 6: 0.1, 7: 0.1, 11: 0.1}),
         "process_noise_covariance": _diag15({0: 1e-4, 1: 1e-4, 5: 1e-4, 6: 0.05, 7: 0.05, 11: 0.05})}
    if method == "pnp":
        p["pose0"] = "camera/pose"
        p["pose0_config"] = [True, True, False, False, False, True] + [False] * 9
    else:
        for k, tag_id in enumerate(IDS):
            p[f"tag_corners{k}"] = f"tag_corners/tag_{tag_id}"
            p[f"tag_corners{k}_corners"] = tag_images.LAYOUT.tags[tag_id].corners_map().reshape(-1).tolist()
            p[f"tag_corners{k}_camera"] = [CAM.fx, CAM.fy, CAM.cx, CAM.cy]
            p[f"tag_corners{k}_camera_mount"] = list(tag_images.MOUNT_XYZ_RPY)
            p[f"tag_corners{k}_pixel_std"] = pixel_std   # the model with only own noise: R = std² I
    return p


def truth_at(t: float) -> np.ndarray:
    """x, y, yaw of the drive at t seconds."""
    return np.array([1.7 + 0.5 * math.sin(0.6 * t), 1.2 + 0.3 * t, math.pi - 0.15 * math.sin(0.9 * t)])


def _pose_msg(fix: tag_pnp.TagFix, stamp_ns: int):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    msg = PoseWithCovarianceStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    msg.header.frame_id = "map"
    p = msg.pose.pose
    p.position.x, p.position.y, p.position.z = (float(v) for v in fix.pose[:3])
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = rpy_to_quaternion(
        *(float(v) for v in fix.pose[3:]))
    msg.pose.covariance = [float(v) for v in fix.covariance.reshape(-1)]
    return msg


def run(seed: int, pixel_std: float) -> dict[str, tuple[float, float, float, int]]:
    """One drive: per method (position RMSE m, yaw RMSE rad, mean NEES, frames fused)."""
    rng = np.random.default_rng(seed)
    start = truth_at(0.0) + rng.normal(0, [0.1, 0.1, 0.1])
    frames = []
    for i in range(1, int(DURATION_S * 10) + 1):
        truth = truth_at(ns_to_seconds(i * FRAME_NS))
        pose6 = np.array([truth[0], truth[1], 0.0, 0.0, 0.0, truth[2]])
        seen = {}
        for tag_id in IDS:
            uv = tag_images.project_tag(pose6, tag_id)
            if np.all((uv > 0) & (uv < [CAM.width - 1, CAM.height - 1])):
                seen[tag_id] = uv + rng.normal(0, pixel_std, uv.shape)
        frames.append((i * FRAME_NS, truth, seen))
    out = {}
    for method in ("pnp", "corners"):
        loc = make_localizer(parse_ekf_config(_params(method, start, pixel_std), MODELS))
        errs, nees, used = [], [], 0
        for stamp, truth, seen in frames:
            applied = False
            if method == "pnp" and seen:
                fix, _ = tag_pnp.localize([TagDetection(i, uv) for i, uv in seen.items()],
                                          tag_images.LAYOUT, CAM, tag_images.mount(), CornerNoise(pixel_std))
                if isinstance(fix, tag_pnp.TagFix):
                    record = read_pose(_pose_msg(fix, stamp))
                    applied = bool(loc.add_measurement("pose0", record, stamp).applied)
            elif method == "corners":
                for k, tag_id in enumerate(IDS):
                    if tag_id in seen:
                        obs = TagCornerObservation(stamp, "camera_optical", seen[tag_id])
                        applied |= bool(loc.add_measurement(f"tag_corners{k}", obs, stamp).applied)
            used += applied
            est = loc.estimate_at(stamp)
            if est is None or stamp < FRAME_NS * 10:
                continue
            x = est.state
            e = np.array([x[0] - truth[0], x[1] - truth[1], wrap_angle(x[2] - truth[2])])
            P = est.covariance[np.ix_([0, 1, 2], [0, 1, 2])]
            errs.append(e)
            nees.append(float(e @ np.linalg.solve(P, e)))
        E = np.array(errs)
        out[method] = (float(np.sqrt(np.mean(E[:, 0] ** 2 + E[:, 1] ** 2))),
                       float(np.sqrt(np.mean(E[:, 2] ** 2))), float(np.mean(nees)), used)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--pixel-std", type=float, default=1.0)
    args = ap.parse_args(argv)
    results = [run(seed, args.pixel_std) for seed in range(args.runs)]
    print(f"{args.runs} runs of {DURATION_S} s, 10 Hz camera, corner noise {args.pixel_std} px "
          "(mean over runs; NEES of x, y, yaw: 3 if honest)")
    print(f"{'method':8s} {'pos RMSE m':>11s} {'yaw RMSE deg':>13s} {'mean NEES':>10s} {'frames':>7s}")
    for method in ("pnp", "corners"):
        r = np.array([res[method] for res in results])
        print(f"{method:8s} {r[:, 0].mean():11.4f} {math.degrees(r[:, 1].mean()):13.3f} "
              f"{r[:, 2].mean():10.2f} {r[:, 3].mean():7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
