"""The calibration demo: a miscalibrated simulated robot, its calibration drive, ekf_calibrate.

``bash scripts/demo.sh --calibration`` runs this. It shows the whole loop a team goes through
on the field (docs/ekf_calibrate.md), in the simulator:

1. **The true robot differs from the YAML.** The simulator's world is ``config/sim.yaml`` with
   the gyro miscalibrated (``imu.yaw_rate_scale`` 1.02, ``imu.yaw_rate_bias`` 0.01 rad/s:
   ``--scale``, ``--bias``) and the dead-wheel pods 2 cm and 3 % off (``dead_wheels.pod_*``),
   written to ``OUT/sim_true.yaml``, the one ``--sim-params`` mechanism; the filter's
   ``config/ekf_joint_states.yaml`` still has the nominal values. The camera is turned 2° on its
   mount (``camera.mount_pose``, ``--mount-yaw``) and reports its own pose
   (``camera.pose_of_camera``), which the filter turns into base_link's through the mount it
   believes (``OUT/ekf_params.yaml``: the YAML with ``pose0_pose_frame: camera_link`` and
   ``static_transforms`` base_link -> camera_link at 0). The camera's fixes are as good
   as AprilTags' (σ about 6 mm and 0.3° at 2 m): the demo's wall-image camera is too coarse to
   give the pods' scales in two minutes (docs/ekf_calibrate.md).
2. **The calibration drive is recorded** with the encoders' joint_states: ``sim_bag --drive
   calibration --joint-states`` (turns in place at two rates both ways, pushes facing the
   images; ``--duration`` s, 120 by default) to ``OUT/bag``.
3. **ekf_calibrate fits the geometry** to the camera's fixes and writes
   ``OUT/calibrated.yaml``.
4. **The same bag is replayed** (tools/replay.py, the node's own code) with the YAML as it
   was, with the calibrated one and with the true values, and scored against the bag's ground
   truth: the RMSE table is printed and saved with the plots in ``OUT``.

    python -m ekf_localization.tools.calibration_demo [--out output/calibration] [--seed 1]
           [--duration 120.0] [--scale 1.02] [--bias 0.01] [--mount-yaw 2.0] [--bootstrap 30]
"""

from __future__ import annotations

import argparse
import math
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

from ekf_localization.control.field_path import config_dir
from ekf_localization.ros import extras

PROG = "calibration_demo"
PARAMS = "ekf_joint_states.yaml"  # the filter: joint0 the pods' joint_states, imu0, pose0
SIM_NODE_KEY = "/**/sim_node"
# the true pods (config/sim.yaml and the YAML: W 0.17, D 0.1, scales 1): offsets 2 cm off, scales 3 %
POD_OFFSETS = [0.19, -0.19, 0.12]
POD_ANGLES = [0.0, 0.0, 1.5707963267948966]  # left, right parallel; the lateral pod across
POD_SCALES = [1.03, 0.97, 1.03]
# a camera as good as AprilTag fixes: σ about 6 mm and 0.3° at 2 m
TAG_GRADE_CAMERA = {"position_distance_variance_coeff": 1.0e-5, "yaw_distance_variance_coeff": 1.2e-5,
                    "yaw_variance_floor": 1.0e-6}
CAMERA_FRAME = "camera_link"  # the frame whose pose the camera reports; the filter's believed mount: 0


def mount_entry(yaw: float) -> str:
    """The static_transforms entry of a camera at the centre turned by ``yaw`` rad."""
    return f"0 0 0 {yaw!r} 0 0 base_link {CAMERA_FRAME}"


def write_filter_params(out: Path) -> Path:
    """The filter's YAML with the camera's fixes going through its believed mount (0)."""
    doc = yaml.safe_load((config_dir() / PARAMS).read_text())
    params = next(iter(doc.values()))["ros__parameters"]
    params["static_transforms"] = [mount_entry(0.0)]
    params["pose0_pose_frame"] = CAMERA_FRAME
    path = out / "ekf_params.yaml"
    path.write_text(f"# {PROG}: config/{PARAMS} with pose0 the camera's pose through a mount at 0\n"
                    + yaml.safe_dump(doc, sort_keys=False))
    return path


def write_true_world(out: Path, scale: float, bias: float, mount_yaw: float = 0.0) -> Path:
    """config/sim.yaml with the true gyro and pods and the tag-grade camera: what the sensors see."""
    doc = yaml.safe_load((config_dir() / "sim.yaml").read_text())
    params = doc[SIM_NODE_KEY]["ros__parameters"]
    params.setdefault("imu", {}).update(yaw_rate_scale=float(scale), yaw_rate_bias=float(bias))
    params.setdefault("dead_wheels", {}).update(pod_offsets=POD_OFFSETS, pod_angles=POD_ANGLES,
                                                pod_scales=POD_SCALES)
    params.setdefault("camera", {}).update(TAG_GRADE_CAMERA, pose_of_camera=True,
                                           mount_pose=[0.0, 0.0, float(mount_yaw)])
    path = out / "sim_true.yaml"
    path.write_text(f"# {PROG}: config/sim.yaml with a miscalibrated gyro and pods (the true robot)\n"
                    + yaml.safe_dump(doc, sort_keys=False))
    return path


def true_values(scale: float, bias: float, mount_yaw: float = 0.0) -> list[str]:
    """The filter's parameters of the true robot, as bag_replay's --set NAME=VALUE."""
    return [f"imu0_yaw_rate_scale={scale!r}", f"imu0_yaw_rate_bias={bias!r}",
            f"joint0_pod_offsets={POD_OFFSETS}", f"joint0_pod_angles={POD_ANGLES}",
            f"joint0_pod_scales={POD_SCALES}", f'static_transforms=["{mount_entry(mount_yaw)}"]']


def replay_table(bag: Path, out: Path, runs: dict[str, tuple[Path, list[str]]]) -> str:
    """Replay ``bag`` once per (params, overrides) and write the RMSE table and plots to ``out``."""
    from ekf_localization.tools import bag_io
    from ekf_localization.tools.replay import load_settings, read_replay_input, replay
    from ekf_localization.tools.report import write_report

    truth = bag_io.read_odometry(bag, "/ground_truth/odom")
    settings = {name: load_settings(params, overrides=sets) for name, (params, sets) in runs.items()}
    # the runs differ in parameter values only (same inputs): the bag is read once
    source = read_replay_input(bag, next(iter(settings.values())).config)
    estimates = {name: replay(source, s, "grid").trajectory() for name, s in settings.items()}
    return write_report(out, truth, estimates, list(estimates), title="Replayed against /ground_truth/odom",
                        plot_title="Calibration drive")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("output/calibration"))
    parser.add_argument("--seed", type=int, default=1, help="simulator random seed")
    parser.add_argument("--duration", type=float, default=120.0, help="s of the calibration drive")
    parser.add_argument("--scale", type=float, default=1.02, help="the simulated gyro's true yaw-rate scale")
    parser.add_argument("--bias", type=float, default=0.01, help="its true yaw-rate bias, rad/s")
    parser.add_argument("--mount-yaw", type=float, default=2.0, help="the camera's true mount yaw, deg")
    parser.add_argument("--bootstrap", type=int, default=30, help="ekf_calibrate's bootstrap replicates")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if extras.check(PROG, "rosbags"):
        return 2
    from ekf_localization.tools import ekf_calibrate

    args.out.mkdir(parents=True, exist_ok=True)
    params = write_filter_params(args.out)
    yaw = math.radians(args.mount_yaw)
    world = write_true_world(args.out, args.scale, args.bias, yaw)
    bag = args.out / "bag"
    if bag.exists():  # the previous run's (only what this demo writes is replaced)
        shutil.rmtree(bag)
    calibrated = args.out / "calibrated.yaml"
    print(f"== 1. the true robot ({world}): gyro yaw-rate scale {args.scale:g}, bias {args.bias:g} rad/s; "
          f"pod offsets {POD_OFFSETS} m, scales {POD_SCALES}; camera mount yaw {yaw:.6g} rad; {PARAMS} "
          "says 1, 0, [0.17, -0.17, 0.1], 1, 0")
    print(f"== 2. the calibration drive, {args.duration:g} s")
    # the simulator is a process of its own, as in the closed-loop demo (the layers: no import)
    code = subprocess.call([sys.executable, "-m", "sim_robot.ros.sim_bag", str(bag), "--duration",
                            str(args.duration), "--seed", str(args.seed), "--drive", "calibration",
                            "--joint-states", "--sim-params", str(world)])
    if code:
        return code
    print("== 3. ekf_calibrate")
    code = ekf_calibrate.main([str(bag), "--params", str(params), "--out", str(calibrated),
                               "--bootstrap", str(args.bootstrap)])
    if code:
        return code
    print("== 4. the same bag replayed")
    table = replay_table(bag, args.out, {f"as {PARAMS} says": (params, []),
                                         "calibrated": (calibrated, []),
                                         "true values": (params, true_values(args.scale, args.bias, yaw))})
    print(table)
    (args.out / "rmse.txt").write_text(table + "\n")
    print(f"\nwrote {calibrated}, {args.out / 'rmse.txt'}, trajectory.png, errors.png in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
