"""The single-tag methods along images-demo runs: the simulator's drive, its filter's heading.

Along the truth of ``ekf_demo --camera images --seed S --out DIR`` bags it renders the
simulator's camera again at every capture (as benchmarks/tag_noise_study.py does: config/sim.yaml
``camera_images``, the demo's layout), detects the tags, and solves each frame by every
single-tag method of vision/tag_pnp.py with the heading that the run's own ``odometry/filtered``
gives at the frame's stamp (vision/heading_prior.HeadingHistory, tag_localizer's default
``heading_max_age``), each method with its own previous fix for the blur, as the node runs.
``(a) corners`` fuses each tag's corners into the recorded estimate at the stamp (its x, y, yaw
and their covariance) as benchmarks/single_tag_study.py does. Printed per number of tags seen:
frames, fixes, position and yaw RMSE of the fixes, their NEES (x, y, θ with the covariance solved
with them, χ²(3); for (c) the filter's yaw and its variance), and for (a) the NEES after the
update.

    python benchmarks/single_tag_bags.py DIR [DIR ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from single_tag_study import (  # noqa: E402
    MAX_AMBIGUITY,
    NOISE,
    Filter,
    _err,
    _mean,
    _nees,
    _rms_xy,
    _rms_yaw,
    corner_update,
)

from ekf_localization.core.angles import wrap_angle  # noqa: E402
from ekf_localization.core.units import seconds_to_ns  # noqa: E402
from ekf_localization.ros.parameters import parameters_from_yaml  # noqa: E402
from ekf_localization.tools import bag_io  # noqa: E402
from ekf_localization.tools.evaluation import interpolate  # noqa: E402
from ekf_localization.vision import tag_pnp  # noqa: E402
from ekf_localization.vision.detectors.apriltag_lib import AprilTagLibDetector  # noqa: E402
from ekf_localization.vision.heading_prior import AMBIGUITY, FIXED_HEADING, HEADING, HeadingHistory  # noqa: E402
from sim_robot.ros.sim_params import parse_parameters  # noqa: E402
from sim_robot.world.camera_image_sensor import CameraImageSensor  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
METHODS = {"ambiguity": AMBIGUITY, "(b) heading": HEADING, "(c) fixed_heading": FIXED_HEADING}
HEADING_MAX_AGE_S = 0.2   # tag_localizer's default heading_max_age


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="ekf_demo --camera images --out folders")
    args = ap.parse_args(argv)
    values = parameters_from_yaml(REPO / "config" / "sim.yaml", "sim_node")
    values["camera_images.enabled"] = True
    config = parse_parameters(values)[1].camera_images
    lay, cam, period_ns = config.layout, config.camera, config.period_ns
    detector = AprilTagLibDetector()
    names = [*METHODS, "(a) corners"]
    out: dict[tuple[str, str], dict] = {}
    for k, run in enumerate(args.runs):
        truth = bag_io.read_odometry(run / "bag", "/ground_truth/odom")
        filt = bag_io.read_odometry(run / "bag", "/odometry/filtered")
        headings = HeadingHistory(seconds_to_ns(HEADING_MAX_AGE_S), capacity=len(filt) + 2)
        for t, x, c in zip(filt.t_ns, filt.states, filt.covariances, strict=True):
            headings.add(int(t), float(x[2]), float(c[2, 2]))
        sensor = CameraImageSensor(config, seed=k)
        mount = sensor.base_to_optical()
        stamps = np.arange((truth.t_ns[0] // period_ns + 1) * period_ns, truth.t_ns[-1], period_ns)
        stamps = stamps[(stamps >= filt.t_ns[0]) & (stamps <= filt.t_ns[-1])]
        last: dict[str, tuple[int, np.ndarray] | None] = dict.fromkeys(names)
        frames = zip(stamps, interpolate(truth, stamps), interpolate(filt, stamps), strict=True)
        for stamp, state, est in frames:
            image = sensor.capture(int(stamp), state).image
            detections = [d for d in detector.detect(image) if d.tag_id in lay.tags]
            if not detections:
                continue
            seen = "1" if len(detections) == 1 else "2" if len(detections) == 2 else "3+"
            truth3 = state[:3]
            for m in names:
                o = out.setdefault((seen, m), {"frames": 0, "fix": [], "fix_nees": [], "post_nees": [],
                                               "fallbacks": 0})
                o["frames"] += 1
                if m == "(a) corners":
                    j = min(int(np.searchsorted(filt.t_ns, stamp)), len(filt) - 1)
                    prior = np.array([est[0], est[1], wrap_angle(est[2])])
                    f = Filter(prior, filt.covariances[j])
                    problem, _ = tag_pnp.build_problem(detections, lay, cam, mount)
                    vel = tag_pnp.pose_velocity(np.array([*prior[:2], 0.0, 0.0, 0.0, prior[2]]), int(stamp),
                                                last[m], tag_pnp.MOTION_MAX_GAP_NS)
                    if corner_update(f, problem, lay, vel, iid=False):
                        e = _err(f.ekf.x, truth3)
                        o["post_nees"].append(_nees(e, f.ekf.P))
                        o["fix"].append(e)
                    last[m] = (int(stamp), np.array([f.ekf.x[0], f.ekf.x[1], 0.0, 0.0, 0.0, f.ekf.x[2]]))
                    continue
                fix, _ = tag_pnp.localize(detections, lay, cam, mount, NOISE, MAX_AMBIGUITY, 0.5, last[m],
                                          int(stamp), METHODS[m], headings.at(int(stamp)))
                if not isinstance(fix, tag_pnp.TagFix):
                    continue
                last[m] = (int(stamp), fix.pose)
                o["fallbacks"] += fix.heading_fallback
                x = np.array([fix.pose[0], fix.pose[1], fix.pose[5]])
                o["fix"].append(_err(x, truth3))
                o["fix_nees"].append(_nees(_err(x, truth3), fix.covariance[np.ix_([0, 1, 5], [0, 1, 5])]))
        print(f"{run}: {len(stamps)} frames", flush=True)
    print("| tags seen | method | fixes / frames (fallbacks) | pos RMSE (cm) | yaw RMSE (deg) | "
          "fix NEES mean / median | (a): NEES after the update |")
    print("|---|---|---|---|---|---|---|")
    for seen in ("1", "2", "3+"):
        for m in names:
            o = out.get((seen, m))
            if o is None:
                continue
            print(f"| {seen} | {m} | {len(o['fix'])} / {o['frames']} ({o['fallbacks']}) | "
                  f"{_rms_xy(o['fix'])} | {_rms_yaw(o['fix'])} | {_mean(o['fix_nees'])} | "
                  f"{_mean(o['post_nees'])} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
