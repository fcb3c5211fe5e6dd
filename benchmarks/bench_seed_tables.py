"""The 100-trial seed 000 tables (VI B and VI C): their compute time, against the per-trial loop.

    python benchmarks/bench_seed_tables.py [--trials 100] [--repeats 3] [--doc]

What ``ekf_experiments --only tables`` computes (``seed000_tables``: 100 trials, six
estimators, seed 2000, ``record_trials=20``), timed in one process after a warm-up run:
``seed000_sim.simulate`` with the batched follower (``seed_experiments.batched.pure_pursuit``,
``follower_kind="batched"``, what the command runs) and, interleaved, the peer: the same simulation with one
``PurePursuitFollower`` per trial (``"per_trial"``). Both are plain numpy. Each figure is the
minimum over ``--repeats``; CPU seconds are the process's, the better figure on a busy
machine. Both loops must give the same numbers (squared-error sums to 1e-9 relative).
Rendering the PNGs and the command's imports are not in the figure.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def timed(fn):
    """(result, wall s, CPU s) of fn()."""
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--doc", action="store_true", help="write the figure into docs/performance.md")
    args = ap.parse_args(argv)

    from ekf_localization.control.field_path import load_preset
    from seed_experiments.experiments import seed000_tables as tables
    from seed_experiments.experiments.seed000_sim import simulate

    tables.warm_up()
    path = load_preset(tables.PATH_NAME)
    best = {"batched": [np.inf, np.inf], "per_trial": [np.inf, np.inf]}
    runs = {}
    for _ in range(args.repeats):
        for kind in best:
            run, wall, cpu = timed(lambda kind=kind: simulate(path, tables.SPECS, args.trials, tables.SEED,
                                                             record_trials=20, follower_kind=kind))
            best[kind] = [min(best[kind][0], wall), min(best[kind][1], cpu)]
            runs[kind] = run
    a, b = runs["per_trial"], runs["batched"]
    same = (all(np.allclose(b.sq_err[n], a.sq_err[n], rtol=1e-9, atol=0.0) for n in a.names)
            and np.array_equal(a.steps, b.steps))
    load = " ".join(f"{v:.1f}" for v in os.getloadavg())
    print(f"{args.trials} trials, 6 estimators, seed {tables.SEED}; minimum of {args.repeats} interleaved "
          f"runs after a warm-up; load average {load}")
    for kind, label in (("batched", "tables (batched follower)"), ("per_trial", "peer: per-trial followers")):
        print(f"  {label:<28} wall {best[kind][0]:6.2f} s   CPU {best[kind][1]:6.2f} s")
    print(f"  same numbers from both loops: {'yes' if same else 'NO'}")
    if args.doc:
        sys.path.insert(0, str(REPO / "benchmarks"))
        from perf_doc import write_row

        write_row(f"seed 000 tables VI B + VI C, {args.trials} trials (compute)",
                  f"{best['batched'][1]:.2f} CPU s, {best['batched'][0]:.2f} s wall",
                  f"one PurePursuitFollower per trial: {best['per_trial'][1]:.2f} CPU s, "
                  f"{best['per_trial'][0]:.2f} s wall")
        print(f"wrote {REPO / 'docs' / 'performance.md'}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
