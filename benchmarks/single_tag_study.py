"""One or two tags without the ambiguity: corner fusion, the IPPE solution nearest the filter's
yaw, or the yaw held at the filter's; per distance and tag count (ROS-free, seeded).

The simulator's camera (config/sim.yaml ``camera_images``: 640x480, 70°, the renderer with the
photographs' noise and lens blur, motion blur over a 4 ms exposure) looks at one or two of the
simulated field's 12.7 cm tags (0.3 m apart, 0.15 m up, as config/tags/ftc_seed000.yaml) on a
wall from d = 1..5 m, up to about 22° off the tags' axis, turned up to 15° away from them,
moving (0.3 m/s, 0.5 rad/s std): tracks of 10 frames at 20 Hz. The AprilRobotics detector
reads every frame. Each frame gets a filter estimate drawn around the truth from its own
covariance P = diag(σ_xy², σ_xy², σ_ψ²) (a consistent filter), and the methods turn it and the
frame into a new estimate, as ekf_node would:

* ``ambiguity``: tag_localizer's unconstrained solve, single tags above ``max_ambiguity``
  rejected (the shipped default before the heading methods);
* ``(a) corners``: each tag's corners fused at the estimate as ``tag_cornersN`` fuses them
  (inputs/tag_corners.py's measurement, R and residual check, through core/ekf.py), R the
  corner noise model's own 8x8 covariance of the tag (``corners iid``: the input's
  ``diagonal_covariance``, ``pixel_variance`` the model's mean per-coordinate variance);
* ``(b) heading``: tag_pnp.solve with the IPPE solution nearest the filter's yaw;
* ``(c) fixed_heading``: the yaw held at the filter's, its variance carried into x, y
  (vision/tag_pnp.py), fused as published (x, y's marginal, the yaw uninformative:
  tag_pnp.published_covariance); ``(c) yaw fused again``: the fix's own covariance fused, the
  filter's yaw (and its correlation with x, y) counted a second time.

(b) and (c) run vision/tag_pnp.localize, the node's own code. Printed per distance and tag
count: frames with the tags detected, fixes used, the fix's position and yaw RMSE and NEES
(x, y, θ against the truth with the covariance solved with it, χ²(3): 3 if honest; for (c) its
yaw is the filter's and the covariance holds its variance), and after the
EKF update from the drawn estimate: position RMSE and NEES (χ²(3)).

    python benchmarks/single_tag_study.py [--tracks 12] [--yaw-std-deg 0.1] [--xy-std 0.005] [--doc]

(the defaults: the images demo's filter, median std of odometry/filtered on seed 1).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ekf_localization.core.angles import wrap_angle  # noqa: E402
from ekf_localization.core.ekf import ExtendedKalmanFilter  # noqa: E402
from ekf_localization.core.linear import LinearMeasurement, LinearProcessModel  # noqa: E402
from ekf_localization.inputs.tag_corners import TagCornerMeasurement, model_covariance  # noqa: E402
from ekf_localization.ros.parameters import parameters_from_yaml  # noqa: E402
from ekf_localization.vision import tag_pnp  # noqa: E402
from ekf_localization.vision.corner_noise import CornerNoise, residual_bound  # noqa: E402
from ekf_localization.vision.detectors.apriltag_lib import AprilTagLibDetector  # noqa: E402
from ekf_localization.vision.heading_prior import AMBIGUITY, FIXED_HEADING, HEADING, Heading  # noqa: E402
from ekf_localization.vision.tag_layout import tag_layout_from_dict  # noqa: E402
from sim_robot.ros.sim_params import parse_parameters  # noqa: E402
from sim_robot.world.camera_image_sensor import CameraImageSensor  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PERIOD_NS = 50_000_000
FRAMES_PER_TRACK = 10
NOISE = CornerNoise(0.10, 0.10, 0.05, 0.004, 4.0)   # config/tag_localizer.yaml
MAX_AMBIGUITY = 0.1
METHODS = ("ambiguity", "(a) corners", "(a) corners iid", "(b) heading", "(c) fixed_heading",
           "(c) yaw fused again")


def layout(tags: int):
    """One tag at y = 0, or two at y = -0.15, 0.15, on the wall x = 0 facing +x."""
    ys = (0.0,) if tags == 1 else (-0.15, 0.15)
    return tag_layout_from_dict({
        "tag_family": "tag36h11", "field": {"length": 7.0, "width": 6.0, "origin": [0.0, -3.0]},
        "tags": [{"id": i + 1, "size": 0.127, "position": [0.0, y, 0.15], "yaw": 0.0}
                 for i, y in enumerate(ys)]})


def camera_config(tags: int):
    values = parameters_from_yaml(REPO / "config" / "sim.yaml", "sim_node")
    values["camera_images.enabled"] = True
    config = parse_parameters(values)[1].camera_images
    return dataclasses.replace(config, layout=layout(tags))


def tracks(distance: float, count: int, rng: np.random.Generator):
    """``count`` tracks: per frame the true state [x y yaw vx vy wz] (body velocity)."""
    out = []
    for _ in range(count):
        y0 = rng.uniform(-0.4, 0.4) * distance
        yaw0 = math.pi + math.atan2(y0, distance) + math.radians(rng.uniform(-15.0, 15.0))
        v = rng.normal(0.0, [0.3, 0.3, 0.5])
        states, s = [], np.array([distance, y0, yaw0, *v])
        dt = PERIOD_NS * 1e-9
        for _ in range(FRAMES_PER_TRACK):
            states.append(s.copy())
            c, si = math.cos(s[2]), math.sin(s[2])
            s[0] += (c * v[0] - si * v[1]) * dt
            s[1] += (si * v[0] + c * v[1]) * dt
            s[2] = wrap_angle(s[2] + v[2] * dt)
        out.append(states)
    return out


def _nees(e: np.ndarray, P: np.ndarray) -> float:
    return float(e @ np.linalg.solve(P, e))


def _err(x: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.array([x[0] - truth[0], x[1] - truth[1], wrap_angle(x[2] - truth[2])])


class Filter:
    """The estimate (x, y, yaw) and P before a frame, updated by core/ekf.py."""

    def __init__(self, x: np.ndarray, P: np.ndarray) -> None:
        model = LinearProcessModel(np.zeros((3, 1)), x_is_angle=np.array([False, False, True]))
        self.ekf = ExtendedKalmanFilter(model, x, P)

    def fuse_pose(self, fix: tag_pnp.TagFix, published: bool = True) -> bool:
        """x, y, yaw of the fix, as pose0 fuses it (its published covariance, or its own)."""
        cov = tag_pnp.published_covariance(fix) if published else fix.covariance
        z = np.array([fix.pose[0], fix.pose[1], fix.pose[5]])
        R = cov[np.ix_([0, 1, 5], [0, 1, 5])]
        return self.ekf.update(LinearMeasurement(np.eye(3), np.array([False, False, True])), z, R).accepted


def corner_update(f: Filter, problem: tag_pnp.PnPProblem, lay, velocity, iid: bool) -> tuple[bool, int]:
    """Each tag's corners fused at the estimate as ekf_node's tag_cornersN fuses them
    (inputs/tag_corners.py's h and R, its residual check): R the corner noise model's 8x8, its
    blur the corners' motion at the estimate (``velocity``: map frame; None: the model's
    unknown-motion blur), or (``iid``) the model's mean variance per coordinate times I.
    (whether one was fused, how many the residual check widened)"""
    cam = problem.camera
    R_bc, t_bc = problem.base_to_camera[:3, :3], problem.base_to_camera[:3, 3]
    ok, widened = False, 0
    for k, tag_id in enumerate(problem.tag_ids):
        model = TagCornerMeasurement(lay.tags[tag_id].corners_map(), (cam.fx, cam.fy, cam.cx, cam.cy),
                                     R_bc, t_bc, (0, 1, 2), 3)
        R = model_covariance(NOISE, model, f.ekf.x.copy(), velocity)
        if iid:
            R = np.mean(np.diag(R)) * np.eye(8)
        ok |= f.ekf.update(model, problem.image_points[4 * k:4 * k + 4].reshape(8), R,
                           widen_above=residual_bound(8)).accepted
        widened += f.ekf.last_widening > 1.0
    return ok, widened


def run_cell(distance: float, tags: int, n_tracks: int, xy_std: float, yaw_std: float,
             seed: int) -> dict[str, dict[str, list]]:
    rng = np.random.default_rng(seed)
    config = camera_config(tags)
    sensor = CameraImageSensor(config, seed=seed)
    mount, lay, cam = sensor.base_to_optical(), config.layout, config.camera
    detector = AprilTagLibDetector()
    P = np.diag([xy_std**2, xy_std**2, yaw_std**2])
    out = {m: {"frames": 0, "fix": [], "fix_nees": [], "post": [], "post_nees": [], "widened": 0}
           for m in METHODS}
    for track in tracks(distance, n_tracks, rng):
        last: dict[str, tuple[int, np.ndarray] | None] = dict.fromkeys(METHODS)
        for i, state in enumerate(track):
            stamp = (i + 1) * PERIOD_NS
            detections = [d for d in detector.detect(sensor.capture(stamp, state).image)
                          if d.tag_id in lay.tags]
            if len(detections) != tags:
                continue
            truth = state[:3]
            prior = truth + rng.multivariate_normal(np.zeros(3), P)
            prior[2] = wrap_angle(prior[2])
            heading = Heading(float(prior[2]), yaw_std**2)
            for m in METHODS:
                o = out[m]
                o["frames"] += 1
                f = Filter(prior, P)
                if m.startswith("(a)"):
                    problem, _ = tag_pnp.build_problem(detections, lay, cam, mount)
                    # the filter's velocity (the odometry's: the true body velocity), map frame
                    c, si = math.cos(prior[2]), math.sin(prior[2])
                    vel = np.array([c * state[3] - si * state[4], si * state[3] + c * state[4], state[5]])
                    used, widened = corner_update(f, problem, lay, vel, m.endswith("iid"))
                    o["widened"] += widened
                else:
                    method = {"ambiguity": AMBIGUITY, "(b) heading": HEADING}.get(m, FIXED_HEADING)
                    fix, _ = tag_pnp.localize(detections, lay, cam, mount, NOISE, MAX_AMBIGUITY, 0.5,
                                              last[m], stamp, method, heading)
                    if not isinstance(fix, tag_pnp.TagFix):
                        continue
                    last[m] = (stamp, fix.pose)
                    x = np.array([fix.pose[0], fix.pose[1], fix.pose[5]])
                    cov = fix.covariance[np.ix_([0, 1, 5], [0, 1, 5])]
                    o["fix"].append(_err(x, truth))
                    o["fix_nees"].append(_nees(_err(x, truth), cov))
                    used = f.fuse_pose(fix, published=m != "(c) yaw fused again")
                if used:
                    e = _err(f.ekf.x, truth)
                    o["post"].append(e)
                    o["post_nees"].append(_nees(e, f.ekf.P))
    return out


def _rms_xy(errs: list) -> str:
    if not errs:
        return "-"
    e = np.array(errs)
    return f"{100 * math.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)):.1f}"


def _rms_yaw(errs: list) -> str:
    if not errs:
        return "-"
    return f"{math.degrees(math.sqrt(np.mean(np.array(errs)[:, 2] ** 2))):.2f}"


def _mean(v: list) -> str:
    return f"{np.mean(v):.2f} / {np.median(v):.2f}" if v else "-"


def _mean_median(v: list) -> str:
    return f"{np.mean(v):.2f} ({np.median(v):.2f})" if v else "-"


def _cell(o: dict, fix: bool = True, after: bool = False) -> str:
    parts = [f"{len(o['post'])}", _rms_xy(o["fix"]), _mean_median(o["fix_nees"])] if fix else []
    if after:
        parts.append(_mean_median(o["post_nees"]))
    return " / ".join(parts)


def doc_row(tags: int, d: float, res: dict) -> str:
    """One row of docs/tag_localizer.md's table: per method fixes used / fix position RMSE (cm) /
    fix NEES mean (median); (a) and (c) also the NEES after the update, (a) the updates widened."""
    a, a_iid = res["(a) corners"], res["(a) corners iid"]
    return (f"| {tags} | {d:g} | {res['ambiguity']['frames']} | {_cell(res['ambiguity'])} | "
            f"{_rms_xy(a['post'])} / {_cell(a, False, True)} / {a['widened']} / "
            f"{_cell(a_iid, False, True)} | "
            f"{_cell(res['(b) heading'])} | {_cell(res['(c) fixed_heading'], True, True)} | "
            f"{_cell(res['(c) yaw fused again'], False, True)} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracks", type=int, default=12, help="tracks of 10 frames per distance and tag count")
    ap.add_argument("--yaw-std-deg", type=float, default=0.1, help="the filter's yaw std (deg)")
    ap.add_argument("--xy-std", type=float, default=0.005, help="the filter's x, y std (m)")
    ap.add_argument("--distances", type=float, nargs="+", default=[1.0, 2.0, 3.0, 4.0, 5.0])
    ap.add_argument("--doc", action="store_true", help="the compact table of docs/tag_localizer.md")
    args = ap.parse_args(argv)
    yaw_std = math.radians(args.yaw_std_deg)
    print(f"filter before each frame: x, y std {args.xy_std} m, yaw std {args.yaw_std_deg} deg; "
          f"{args.tracks} tracks of {FRAMES_PER_TRACK} frames per row")
    if args.doc:
        print("| tags | d (m) | frames | ambiguity | "
              "(a) corners: pos after / NEES after, model R / widened / iid R | (b) heading | "
              "(c) fixed_heading | (c), yaw fused again: NEES after |")
        print("|---|---|---|---|---|---|---|---|")
    else:
        print("| tags | d (m) | method | fixes used / frames | fix pos RMSE (cm) | fix yaw RMSE (deg) | "
              "fix NEES mean / median | after the update: pos RMSE (cm) | NEES mean / median |")
        print("|---|---|---|---|---|---|---|---|---|")
    for tags in (1, 2):
        for d in args.distances:
            res = run_cell(d, tags, args.tracks, args.xy_std, yaw_std, seed=int(100 * d) + tags)
            if args.doc:
                print(doc_row(tags, d, res), flush=True)
                continue
            for m in METHODS:
                o = res[m]
                fix_cols = ("-", "-", "-") if m.startswith("(a)") else (
                    _rms_xy(o["fix"]), _rms_yaw(o["fix"]), _mean(o["fix_nees"]))
                print(f"| {tags} | {d:g} | {m} | {len(o['post'])} / {o['frames']} | {' | '.join(fix_cols)} | "
                      f"{_rms_xy(o['post'])} | {_mean(o['post_nees'])} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
