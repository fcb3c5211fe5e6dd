"""ekf_tune on one 20 s bag from a bad start: wall time of the whole command (target < 60 s, 2 jobs).

    python benchmarks/bench_ekf_tune.py [--bag BAG] [--params config/ekf.yaml] [--jobs 2]
                                        [--out output/bench_ekf_tune] [--max-evals N]
                                        [--objective truth|likelihood]

Without ``--bag``, records a 20 s drive of the simulator world (sim_robot/ros/sim_bag.py, no DDS).
The start config is ``--params`` with every process noise entry ×100 and every input's
variance scale ×0.01 (the acceptance start of docs/ekf_tune.md), the truth objective unless
``--objective likelihood``; ekf_tune's own defaults otherwise. Prints the wall time and CPU
seconds, and as the peer measured in the same run the
wall time of one replay of the bag (the median of 3 before and 3 after), so the figure can be
read as "replays' worth" on a loaded machine; then the evaluations and the RMSE / NEES before
and after (from the report).
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children (the worker pool)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _replay_seconds(bag: Path, params: Path, n: int) -> list[float]:
    """Wall seconds of ``n`` replays of ``bag`` (read once, as ekf_tune does) with ``params``."""
    from ekf_localization.tools.replay import load_settings, read_replay_input, replay

    settings = load_settings(params)
    source = read_replay_input(bag, settings.config)
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        replay(source, settings)
        out.append(time.perf_counter() - t0)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bag", type=Path, default=None)
    parser.add_argument("--params", type=Path, default=REPO / "config" / "ekf.yaml")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--max-evals", type=int, default=None, help="default: ekf_tune's")
    parser.add_argument("--objective", choices=("truth", "likelihood"), default="truth")
    parser.add_argument("--out", type=Path, default=REPO / "output" / "bench_ekf_tune")
    args = parser.parse_args()

    from ekf_localization.tools import ekf_tune
    from sim_robot.ros.sim_bag import write_sim_bag

    args.out.mkdir(parents=True, exist_ok=True)
    bag = args.bag
    if bag is None:
        bag = args.out / "sim_bag"
        if not bag.exists():
            write_sim_bag(bag, 20.0, seed=1)
    budget = [] if args.max_evals is None else ["--max-evals", str(args.max_evals)]
    load0 = os.getloadavg()[0]
    peer = _replay_seconds(bag, args.params, 3)
    cpu0 = _cpu_seconds()
    t0 = time.perf_counter()
    rc = ekf_tune.main([str(bag), "--params", str(args.params), "--scale-start", "100,0.01",
                        "--out", str(args.out / "tuned"), "--jobs", str(args.jobs), *budget,
                        "--objective", args.objective])
    wall = time.perf_counter() - t0
    cpu = _cpu_seconds() - cpu0
    peer = sorted(peer + _replay_seconds(bag, args.params, 3))[2:4]
    replay_s = sum(peer) / 2
    print(f"bench_ekf_tune: exit {rc}, {wall:.1f} s wall for ekf_tune with --jobs {args.jobs} "
          f"(target < 60 s on 2 cores); {cpu:.1f} CPU s in this process and its workers; "
          f"load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after, on {os.cpu_count()} cores")
    print(f"bench_ekf_tune: peer: one replay of the bag {replay_s:.2f} s wall (median in the same run): "
          f"ekf_tune took {wall / replay_s:.0f} replays' worth of wall time")
    report = (args.out / "tuned" / "report.md")
    if report.exists():
        for line in report.read_text().splitlines():
            if line.startswith(("| RMSE xy", "| mean NEES", "- ")):
                print("  " + line)
    return rc


if __name__ == "__main__":
    sys.exit(main())
