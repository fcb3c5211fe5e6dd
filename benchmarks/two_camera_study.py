"""One camera or two: the images demo (``ekf_demo --camera images``) with ``--cameras 1`` and
``--cameras 2`` on the same seeds, one run after the other per seed (so both see about the same
machine load). Prints per seed and camera count the EKF's (x, y) RMSE and the live pose NEES
(``/odometry/filtered`` against the truth with its published covariance, chi²(3)), the fixes
accepted, and the means over the seeds; the two-camera mean RMSE should be no worse. A run whose
bag lost ground truth (a gap over 50 ms: the recorder starved of CPU) is marked ``*``: the errors
there are against truth interpolated across the gap, which overstates them.

The two runs of a seed drive different paths (the follower steers by the estimate) on a machine
whose load differs, so each two-camera bag is also replayed offline (``bag_replay``'s engine,
following ekf_node's fusion log) twice: with both cameras and with ``pose1`` left out. That
isolates what the second camera's fixes add, on the same drive and the same first-camera fixes.

    python benchmarks/two_camera_study.py --seeds 1 2 3 4 5 [--rtf 0.5] --out output/two_cameras

``--parse DIR`` prints the table of runs already made (DIR/c<cameras>_s<seed>/stdout.txt).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

RMSE = re.compile(r"^EKF /odometry/filtered\s+([0-9.]+)", re.MULTILINE)
NEES = re.compile(r"^NEES live pose mean ([0-9.]+)", re.MULTILINE)
FIXES = re.compile(r"^(?:camera1 )?tag fixes: (\d+) accepted.* of (\d+) frames", re.MULTILINE)


def run(seed: int, cameras: int, out: Path, rtf: float = 1.0) -> Path:
    """One demo run; its stdout is kept as ``out/c<cameras>_s<seed>/stdout.txt``."""
    d = out / f"c{cameras}_s{seed}"
    d.mkdir(parents=True, exist_ok=True)
    cmd = ["ekf_demo", "--camera", "images", "--cameras", str(cameras), "--seed", str(seed), "--out", str(d),
           "--rtf", repr(rtf)]
    load = os.getloadavg()[0]
    with open(d / "stdout.txt", "w") as fh:
        rc = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT).returncode
    print(f"seed {seed}, {cameras} camera(s): exit {rc}, load {load:.1f} at the start", flush=True)
    return d / "stdout.txt"


def truth_gap_s(bag: Path) -> float:
    """The longest gap between the bag's ground-truth messages (s; 0.01 at 100 Hz)."""
    import numpy as np

    from ekf_localization.tools import bag_io

    t = bag_io.read_odometry(bag, "/ground_truth/odom").t_ns
    return float(np.diff(t).max()) * 1e-9 if len(t) > 1 else float("inf")


def parse(path: Path) -> tuple[float, float, int, int] | None:
    """(RMSE m, live pose NEES, fixes accepted, frames received) of one run's stdout (the cameras'
    sums), None if it has no table."""
    text = path.read_text() if path.exists() else ""
    r, n = RMSE.search(text), NEES.search(text)
    if r is None or n is None:
        return None
    counts = FIXES.findall(text)
    return (float(r.group(1)), float(n.group(1)), sum(int(f) for f, _ in counts),
            sum(int(n) for _, n in counts))


def replayed_rmse(run_dir: Path) -> tuple[float, float]:
    """(x, y) RMSE of the run's bag replayed with its parameters, and without ``pose1``."""
    import numpy as np
    import yaml

    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.tools import bag_io
    from ekf_localization.tools.evaluation import errors
    from ekf_localization.tools.replay import load_settings, replay

    bag = run_dir / "bag"
    truth = bag_io.read_odometry(bag, "/ground_truth/odom")
    values = parameters_from_yaml(run_dir / "ekf_params.yaml")
    one = {k: v for k, v in values.items() if k != "pose1" and not k.startswith("pose1_")}
    one_file = run_dir / "ekf_params_pose0_only.yaml"
    one_file.write_text(yaml.safe_dump({"ekf_node": {"ros__parameters": one}}, sort_keys=False))
    out = []
    for params in (run_dir / "ekf_params.yaml", one_file):
        _, e = errors(replay(bag, load_settings(params), "recorded").trajectory(), truth)
        out.append(float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))))
    return out[0], out[1]


def ablation(out: Path, seeds: list[int]) -> str:
    """The two-camera bags replayed with both cameras and with pose1 left out."""
    rows = ["| seed | two-camera bag replayed: both cameras | the same, pose1 left out |", "|---|---|---|"]
    both, first = [], []
    for seed in seeds:
        d = out / f"c2_s{seed}"
        if parse(d / "stdout.txt") is None:
            rows.append(f"| {seed} | failed | - |")
            continue
        b, f = replayed_rmse(d)
        both.append(b)
        first.append(f)
        rows.append(f"| {seed} | {b * 100:.2f} cm | {f * 100:.2f} cm |")
    if both:
        mb, mf = (sum(v) / len(v) * 100 for v in (both, first))
        rows.append(f"| mean | **{mb:.2f} cm** | **{mf:.2f} cm** |")
    return "\n".join(rows)


def table(out: Path, seeds: list[int]) -> str:
    rows = ["| seed | 1 camera: (x,y) RMSE | live pose NEES | fixes / frames | 2 cameras: (x,y) RMSE "
            "| live pose NEES | fixes / frames |", "|---|---|---|---|---|---|---|"]
    sums: dict[int, list[tuple[float, float, int, int]]] = {1: [], 2: []}
    for seed in seeds:
        cells = []
        for cameras in (1, 2):
            got = parse(out / f"c{cameras}_s{seed}" / "stdout.txt")
            if got is None:
                cells += ["failed", "-", "-"]
                continue
            sums[cameras].append(got)
            gap = "*" if truth_gap_s(out / f"c{cameras}_s{seed}" / "bag") > 0.05 else ""
            cells += [f"{got[0] * 100:.2f} cm{gap}", f"{got[1]:.2f}{gap}", f"{got[2]} / {got[3]}"]
        rows.append(f"| {seed} | " + " | ".join(cells) + " |")
    means = []
    for cameras in (1, 2):
        v = sums[cameras]
        if not v:
            means += ["-", "-", "-"]
            continue
        rmse, nees, fixes, frames = (sum(x[i] for x in v) / len(v) for i in range(4))
        means += [f"**{rmse * 100:.2f} cm**", f"**{nees:.2f}**", f"{fixes:.0f} / {frames:.0f}"]
    rows.append("| mean | " + " | ".join(means) + " |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--out", type=Path, default=Path("output/two_cameras"))
    parser.add_argument("--rtf", type=float, default=1.0,
                        help="the demo's real-time factor (0.5 on a loaded machine: the nodes keep up)")
    parser.add_argument("--parse", type=Path, default=None,
                        help="only print the table of the runs in this directory")
    args = parser.parse_args(argv)
    out = args.parse or args.out
    if args.parse is None:
        for seed in args.seeds:
            for cameras in (1, 2):
                run(seed, cameras, out, args.rtf)
    print(table(out, args.seeds))
    print()
    print(ablation(out, args.seeds))
    if args.parse is None:
        print(f"\npython benchmarks/two_camera_study.py --seeds {' '.join(map(str, args.seeds))} "
              f"--rtf {args.rtf:g} --out {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
