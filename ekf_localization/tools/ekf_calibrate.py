"""Fit the IMU's yaw-rate scale and bias, the dead-wheel pods' offsets, angles and scales, the
driven wheels' radius, turning lever and strafe scale and the camera's mount from recorded
drives; write a calibrated ekf_node YAML.

    ekf_calibrate BAG [BAG ...] --params config/ekf.yaml --out calibrated.yaml
                  [--imu imu0] [--joint joint0] [--bootstrap 100] [--seed 0] [--block 5.0]
                  [--node-name ekf_node]

The reference is the camera: the poseN inputs' fixes (geometry_msgs/PoseWithCovarianceStamped)
in the bags; the gyro is the imuN input's angular_velocity.z, the pods and the driven wheels the
jointN inputs' joint positions. The fits and their models: :mod:`ekf_localization.tools.calibration`,
:mod:`ekf_localization.tools.pod_calibration`, :mod:`ekf_localization.tools.driven_calibration`
(docs/ekf_calibrate.md, docs/models.md); a poseN input with a ``pose_frame`` has its mount
(``static_transforms``) fitted with the pods or wheels (:mod:`ekf_localization.tools.ekf_calibrate_mount`).
Each group is fitted when the params file has its input
(the groups are independent data, so fitting one after the other is fitting them jointly). Prints one
line per parameter, ``<parameter> <fitted> ± <std> (was <value>)``, and the residual before
and after. A parameter the drives cannot determine is named and left unchanged. Exit status
0; 2 on bad input or when nothing can be fitted (one line on stderr).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.units import NS_PER_S, stamp_to_ns
from ekf_localization.inputs import KINDS
from ekf_localization.inputs.imu import ImuSettings
from ekf_localization.models.registry import MODELS
from ekf_localization.ros import extras
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import (
    ParameterError,
    names_node,
    parameters_from_yaml,
    read_parameter_yaml,
)
from ekf_localization.tools import (
    bag_io,
    calibration,
    ekf_calibrate_driven,
    ekf_calibrate_mount,
    ekf_calibrate_pods,
)
from ekf_localization.tools.calibration import Fixes, Gyro
from ekf_localization.tools.ekf_calibrate_pods import UnavailableError
from ekf_localization.tools.ekf_tune import write_tuned_yaml
from ekf_localization.tools.replay import abs_topic

PROG = "ekf_calibrate"
POSE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
YAW = 5  # yaw in the 6x6 pose covariance, and in the 15 fields


class UsageError(Exception):
    """Bad input: one line for stderr, exit 2."""


def pose_topics(config: EkfConfig) -> list[str]:
    """The topics of the inputs whose messages are camera pose fixes of the robot in the world."""
    return [abs_topic(i.topic) for i in config.inputs
            if KINDS[i.kind].absolute_pose and KINDS[i.kind].message_type == POSE_TYPE]


def imu_input(config: EkfConfig, name: str | None):
    """The imuN input to calibrate (``name``, or the only one; None when there is none and none
    was asked for)."""
    imus = [i for i in config.inputs if isinstance(i.settings, ImuSettings)]
    if name is not None:
        imus = [i for i in imus if i.name == name]
    elif not imus:
        return None
    if len(imus) != 1:
        what = f"an imuN input named {name}" if name else "exactly one imuN input (or --imu NAME)"
        raise UsageError(f"the parameters have {len(imus)} matching IMU inputs; expected {what}")
    return imus[0]


def read_bag(bag: Path, imu_topic: str, fix_topics: list[str]) -> tuple[Fixes, Gyro]:
    """The bag's heading fixes and gyro samples (stamps in s from the bag's first gyro sample)."""
    fix_t, fix_yaw, fix_var, gyro_t, gyro_w, gyro_v = [], [], [], [], [], []
    for m in bag_io.iter_messages(bag, [imu_topic, *fix_topics]):
        if m.topic == imu_topic:
            c = m.msg.angular_velocity_covariance
            gyro_t.append(stamp_to_ns(m.msg.header.stamp))
            gyro_w.append(float(m.msg.angular_velocity.z))
            gyro_v.append(max(float(c[8]), 0.0) if c[0] != -1.0 else 0.0)
        else:
            t, state, cov = bag_io.pose_stamped_state(m.msg)
            if np.isfinite(state[2]) and math.isfinite(cov[2, 2]) and cov[2, 2] > 0.0:
                fix_t.append(t)
                fix_yaw.append(state[2])
                fix_var.append(cov[2, 2])
    if not gyro_t:
        raise UnavailableError(f"{bag}: no messages on the IMU topic {imu_topic}")
    if not fix_t:
        raise UsageError(f"{bag}: no camera pose fixes with a yaw variance on {', '.join(fix_topics)}; "
                         "nothing to calibrate against")
    t0 = min(gyro_t)

    def sec(v: list[int]) -> np.ndarray:
        return (np.asarray(v, dtype=np.int64) - t0) / NS_PER_S

    w = np.asarray(gyro_w, dtype=float)
    ok = np.isfinite(w)
    return (Fixes(sec(fix_t), np.asarray(fix_yaw), np.asarray(fix_var)),
            Gyro(sec(gyro_t)[ok], w[ok], np.asarray(gyro_v)[ok]))


def node_key(params: Path, node_name: str) -> str:
    """The section of ``params`` that names the node (``/**/ekf_node``), else ``node_name``."""
    doc = read_parameter_yaml(params) or {}
    name = node_name.strip("/").split("/")[-1]
    keys = [str(k) for k in doc if names_node(str(k), name)]  # the sections parameters_from_yaml reads
    return keys[-1] if keys else name


def fit_imu(args: argparse.Namespace, config: EkfConfig, values: dict, imu,
            fix_topics: list[str]) -> list[str]:
    """Fit the IMU's yaw-rate scale and bias; print them, set them in ``values``, return their names.
    Raises UnavailableError when the drives determine neither."""
    names = (f"{imu.name}_yaw_rate_scale", f"{imu.name}_yaw_rate_bias")
    was = (float(values.get(names[0], 1.0)), float(values.get(names[1], 0.0)))
    pairs = []
    for bag in args.bags:
        pairs.append(read_bag(bag, abs_topic(imu.topic), fix_topics))
    walk = float(config.process_noise_covariance[YAW, YAW])
    problem = calibration.build_problem(pairs, walk)
    free = calibration.observable(problem, was)
    formal = calibration.design_std(problem, was)
    for i, name in enumerate(names):
        if not free[i]:
            print(f"{name}: not observable from these drives (its std {formal[i]:.2g} > "
                  f"{calibration.MAX_STD[i]:g}: too little rotation, a single turn rate, or too few camera "
                  "fixes); left unchanged")
    if not any(free):
        raise UnavailableError("the drives determine neither the IMU yaw-rate scale nor its bias")
    before = calibration.fit(problem, was, (False, False))
    best = calibration.fit(problem, was, free)
    for i, (lo, hi) in enumerate(calibration.BOUNDS):
        value = (best.scale, best.bias)[i]
        if free[i] and not lo <= value <= hi:
            raise UsageError(f"{names[i]}: the fit gives {value:g}, outside [{lo:g}, {hi:g}]: a broken gyro, "
                             "the wrong IMU axis or topic, or fixes not of this robot; nothing written")
    std = calibration.bootstrap_std(problem, best, free, args.bootstrap, args.seed, args.block)
    fitted = (best.scale, best.bias)
    ekf_calibrate_pods.print_fitted(names, fitted, std, was, free)
    for i, name in enumerate(names):
        if free[i]:
            values[name] = float(fitted[i])
    print(f"residual (RMS, normalised): before {before.rms:.4g}, after {best.rms:.4g} "
          f"({problem.n} camera fixes, {int(problem.link.sum())} gyro links, {len(args.bags)} bag(s))")
    return [n for n, f in zip(names, free, strict=True) if f]


def run(args: argparse.Namespace) -> int:
    try:
        values = parameters_from_yaml(args.params, args.node_name)
        config = parse_ekf_config(values, MODELS)
    except ParameterError as exc:
        raise UsageError(f"--params {args.params}: {exc}".replace("\n", " ")) from None
    fix_topics = pose_topics(config)
    if not fix_topics:
        raise UsageError(f"--params {args.params} has no poseN input: no camera pose fixes to calibrate "
                         "against")
    imu = imu_input(config, args.imu)
    try:
        driven = ekf_calibrate_driven.driven_input(config, args.joint)
        named_driven = driven is not None and args.joint is not None
        joint = None if named_driven else ekf_calibrate_pods.dead_wheel_input(config, args.joint)
    except ValueError as exc:
        named = " (nor a driven-wheel one)" if "named" in str(exc) else ""
        raise UsageError(str(exc) + named) from None
    if imu is None and joint is None and driven is None:
        raise UsageError(f"--params {args.params} has no imuN input and no dead-wheel or driven-wheel jointN "
                         "input: nothing to calibrate")
    fitted, missing = [], []
    try:
        args.camera_mount = ekf_calibrate_mount.camera_mount(config, args.bags, fix_topics)
        args.mount_fitted = False
        for inp, fit, what in ((imu, fit_imu, ""), (joint, ekf_calibrate_pods.calibrate, " pods"),
                               (driven, ekf_calibrate_driven.calibrate, " wheels")):
            if inp is None:
                continue
            try:
                fitted += fit(args, config, values, inp, fix_topics)
            except UnavailableError as exc:
                missing.append(str(exc))
                print(f"{inp.name}{what}: {exc}; left unchanged")
    except (bag_io.BagError, ekf_calibrate_mount.MountError) as exc:
        raise UsageError(str(exc)) from None
    except ValueError as exc:  # a fit out of bounds
        raise UsageError(str(exc)) from None
    cam = args.camera_mount
    if cam is not None and not args.mount_fitted:
        need = "" if joint or driven else ": it needs a dead-wheel or driven-wheel jointN input"
        print(f"static_transforms[{cam.parent} {cam.frame}] (the camera mount of {cam.input_name}): not "
              f"fitted from these drives{need}; left unchanged")
    if not fitted:
        raise UsageError("nothing can be fitted: " + "; ".join(missing))
    header = (f"# {PROG}: {', '.join(fitted)} fitted to "
              f"{', '.join(str(b) for b in args.bags)}; every other parameter as in {args.params}\n")
    write_tuned_yaml(args.out, values, node_key(args.params, args.node_name), header)
    parse_ekf_config(parameters_from_yaml(args.out, args.node_name), MODELS)  # loads as ekf_node's
    print(f"wrote {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bags", type=Path, nargs="+", metavar="BAG", help="recorded drives")
    parser.add_argument("--params", type=Path, required=True, help="ekf_node YAML to start from")
    parser.add_argument("--out", type=Path, required=True, help="the calibrated YAML to write")
    parser.add_argument("--node-name", default="ekf_node")
    parser.add_argument("--imu", default=None, help="the imuN input (default: the only one)")
    parser.add_argument("--joint", default=None,
                        help="the dead-wheel or driven-wheel jointN input (default: each kind's only one)")
    parser.add_argument("--bootstrap", type=int, default=100, help="bootstrap replicates for the std")
    parser.add_argument("--seed", type=int, default=0, help="the bootstrap's random seed")
    parser.add_argument("--block", type=float, default=calibration.BLOCK_S,
                        help="bootstrap block length, s (the pods' and wheels' fits: the longest, shorter "
                        "when the camera errors decorrelate sooner)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if extras.check(PROG, "rosbags"):
        return 2
    try:
        if args.bootstrap < 0 or not (math.isfinite(args.block) and args.block > 0):
            raise UsageError("--bootstrap must be >= 0 and --block > 0")
        return run(args)
    except UsageError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
