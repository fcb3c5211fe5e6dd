"""The calibration demo: a miscalibrated simulated robot, its calibration drive, ekf_calibrate.

``bash scripts/demo.sh --calibration`` runs this. It shows the whole loop a team goes through
on the field (docs/ekf_calibrate.md), in the simulator:

1. **The true robot differs from the YAML.** The simulator's world is ``config/sim.yaml`` with
   the gyro miscalibrated (``imu.yaw_rate_scale`` 1.02, ``imu.yaw_rate_bias`` 0.01 rad/s:
   ``--scale``, ``--bias``), written to ``OUT/sim_true.yaml``, the one ``--sim-params``
   mechanism; the filter's ``config/ekf.yaml`` still says 1 and 0.
2. **The calibration drive is recorded:** ``sim_bag --drive calibration`` (turns in place at
   two rates both ways, straight pushes; ``--duration`` s, 120 by default) to ``OUT/bag``.
3. **ekf_calibrate fits the geometry** to the camera's fixes and writes
   ``OUT/calibrated.yaml``.
4. **The same bag is replayed** (tools/replay.py, the node's own code) with the YAML as it
   was, with the calibrated one and with the true values, and scored against the bag's ground
   truth: the RMSE table is printed and saved with the plots in ``OUT``.

    python -m ekf_localization.tools.calibration_demo [--out output/calibration] [--seed 1]
           [--duration 120.0] [--scale 1.02] [--bias 0.01]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

from ekf_localization.control.field_path import config_dir
from ekf_localization.ros import extras

PROG = "calibration_demo"
IMU = "imu0"  # config/ekf.yaml's gyro input
SIM_NODE_KEY = "/**/sim_node"


def write_true_world(out: Path, scale: float, bias: float) -> Path:
    """config/sim.yaml with the gyro's true scale and bias set: the world the sensors see."""
    doc = yaml.safe_load((config_dir() / "sim.yaml").read_text())
    imu = doc[SIM_NODE_KEY]["ros__parameters"].setdefault("imu", {})
    imu["yaw_rate_scale"] = float(scale)
    imu["yaw_rate_bias"] = float(bias)
    path = out / "sim_true.yaml"
    path.write_text(f"# {PROG}: config/sim.yaml with a miscalibrated gyro (the true robot)\n"
                    + yaml.safe_dump(doc, sort_keys=False))
    return path


def replay_table(bag: Path, out: Path, runs: dict[str, tuple[Path, list[str]]]) -> str:
    """Replay ``bag`` once per (params, overrides) and write the RMSE table and plots to ``out``."""
    from ekf_localization.tools import bag_io
    from ekf_localization.tools.replay import load_settings, replay
    from ekf_localization.tools.report import write_report

    truth = bag_io.read_odometry(bag, "/ground_truth/odom")
    estimates = {name: replay(bag, load_settings(params, overrides=sets), "grid").trajectory()
                 for name, (params, sets) in runs.items()}
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
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if extras.check(PROG, "rosbags"):
        return 2
    from ekf_localization.tools import ekf_calibrate

    args.out.mkdir(parents=True, exist_ok=True)
    params = config_dir() / "ekf.yaml"
    world = write_true_world(args.out, args.scale, args.bias)
    bag = args.out / "bag"
    if bag.exists():  # the previous run's (only what this demo writes is replaced)
        shutil.rmtree(bag)
    calibrated = args.out / "calibrated.yaml"
    print(f"== 1. the true gyro: yaw-rate scale {args.scale:g}, bias {args.bias:g} rad/s ({world}); "
          f"{params.name} says 1 and 0")
    print(f"== 2. the calibration drive, {args.duration:g} s")
    # the simulator is a process of its own, as in the closed-loop demo (the layers: no import)
    code = subprocess.call([sys.executable, "-m", "sim_robot.ros.sim_bag", str(bag), "--duration",
                            str(args.duration), "--seed", str(args.seed), "--drive", "calibration",
                            "--sim-params", str(world)])
    if code:
        return code
    print("== 3. ekf_calibrate")
    code = ekf_calibrate.main([str(bag), "--params", str(params), "--out", str(calibrated)])
    if code:
        return code
    print("== 4. the same bag replayed")
    true_values = [f"{IMU}_yaw_rate_scale={args.scale!r}", f"{IMU}_yaw_rate_bias={args.bias!r}"]
    table = replay_table(bag, args.out, {f"as {params.name} says": (params, []),
                                         "calibrated": (calibrated, []),
                                         "true values": (params, true_values)})
    print(table)
    (args.out / "rmse.txt").write_text(table + "\n")
    print(f"\nwrote {calibrated}, {args.out / 'rmse.txt'}, trajectory.png, errors.png in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
