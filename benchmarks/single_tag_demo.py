"""The images demo with each single-tag method: ``ekf_demo --camera images --single-tag M``.

For each seed, one run per method, one after the other (so the runs of a seed see about the same
machine load), each at ``--rtf``. Prints per seed and method the EKF's (x, y) RMSE against the
truth, the live pose NEES (``/odometry/filtered`` against the truth with its published covariance,
chi²(3), the demo's ``NEES live pose mean``) with its number of estimates, the tag fixes accepted,
the single-tag frames sent as corners and the frames, and the load average at the run's start;
then per method the mean RMSE and the live pose NEES pooled over the seeds' estimates.

    python benchmarks/single_tag_demo.py --seeds 1 2 3 4 5 --methods ambiguity corners \\
        --rtf 0.5 --out output/single_tag_demo

``--parse`` prints the table of runs already made (OUT/<method>_s<seed>/stdout.txt).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

NEES = re.compile(r"^NEES live pose mean ([0-9.]+) \(chi2\(3\), (\d+) of", re.MULTILINE)
FIXES = re.compile(r"^tag fixes: (\d+) accepted.*?(?:, (\d+) single-tag frames sent as corners)? "
                   r"of (\d+) frames", re.MULTILINE)
LOAD = re.compile(r"^load ([0-9.]+)$", re.MULTILINE)


def run(seed: int, method: str, out: Path, rtf: float) -> None:
    """One demo run; its stdout (and the load average at its start) in OUT/<method>_s<seed>/stdout.txt."""
    d = out / f"{method}_s{seed}"
    d.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "ekf_localization.tools.demo", "--camera", "images", "--single-tag", method,
           "--seed", str(seed), "--rtf", repr(rtf), "--out", str(d)]
    load = os.getloadavg()[0]
    with open(d / "stdout.txt", "w") as fh:
        fh.write(f"load {load:.2f}\n")
        fh.flush()
        rc = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT).returncode
    print(f"seed {seed}, {method}: exit {rc}, load {load:.1f} at the start", flush=True)


def result(run_dir: Path) -> dict | None:
    """RMSE (m), live NEES and its estimates, fixes, corner frames, frames and load of one run."""
    text = (run_dir / "stdout.txt").read_text() if (run_dir / "stdout.txt").exists() else ""
    nees, fixes = NEES.search(text), FIXES.search(text)
    if nees is None or fixes is None or not (run_dir / "bag").exists():
        return None
    from ekf_localization.tools import bag_io
    from ekf_localization.tools.evaluation import rmse

    truth = bag_io.read_odometry(run_dir / "bag", "/ground_truth/odom")
    xy = rmse(bag_io.read_odometry(run_dir / "bag", "/odometry/filtered"), truth)["xy"]
    load = LOAD.search(text)
    return {"rmse": xy, "nees": float(nees.group(1)), "n": int(nees.group(2)), "fixes": int(fixes.group(1)),
            "corners": int(fixes.group(2) or 0), "frames": int(fixes.group(3)),
            "load": float(load.group(1)) if load else float("nan")}


def table(out: Path, seeds: list[int], methods: list[str]) -> str:
    rows = ["| seed | method | (x, y) RMSE | live pose NEES (estimates) | fixes / corner frames / frames "
            "| load |", "|---|---|---|---|---|---|"]
    pooled: dict[str, list[dict]] = {m: [] for m in methods}
    for seed in seeds:
        for m in methods:
            r = result(out / f"{m}_s{seed}")
            if r is None:
                rows.append(f"| {seed} | {m} | no result | | | |")
                continue
            pooled[m].append(r)
            rows.append(f"| {seed} | {m} | {100 * r['rmse']:.2f} cm | {r['nees']:.2f} ({r['n']}) | "
                        f"{r['fixes']} / {r['corners']} / {r['frames']} | {r['load']:.1f} |")
    for m, rs in pooled.items():
        if rs:
            n = sum(r["n"] for r in rs)
            nees = sum(r["nees"] * r["n"] for r in rs) / n
            mean = sum(r["rmse"] for r in rs) / len(rs)
            rows.append(f"| mean of {len(rs)} | {m} | **{100 * mean:.2f} cm** | **{nees:.2f}** ({n}, pooled) "
                        "| | |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--methods", nargs="+", default=["ambiguity", "corners"])
    ap.add_argument("--rtf", type=float, default=0.5)
    ap.add_argument("--out", type=Path, default=Path("output/single_tag_demo"))
    ap.add_argument("--parse", action="store_true", help="only print the table of runs already made")
    args = ap.parse_args(argv)
    if not args.parse:
        for seed in args.seeds:
            for m in args.methods:
                run(seed, m, args.out, args.rtf)
    print(table(args.out, args.seeds, args.methods))
    return 0


if __name__ == "__main__":
    sys.exit(main())
