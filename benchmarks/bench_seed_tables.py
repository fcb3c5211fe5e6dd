"""The 100-trial seed 000 tables (VI B and VI C) against the per-trial follower loop as the peer.

    python benchmarks/bench_seed_tables.py [--trials 100] [--repeats 3] [--no-cli] [--doc]

What ``ekf_experiments --only tables`` computes (``seed000_tables.compute``: 100 trials, six
estimators, seed 2000; docs/results.md's "tables VI B + VI C" wall time is this), timed in
one process after a warm-up run, with the two follower loops of ``seed000_sim.simulate``
interleaved: ``follower_kind="batched"`` (``control/batched_pure_pursuit.py``, the product)
and ``"per_trial"`` (one ``PurePursuitFollower`` per trial, the loop before it: the peer).
Each figure is the minimum over ``--repeats`` (the machine is shared); CPU seconds are the
process's, the better figure on a busy machine. Both loops must give the same numbers to a
floating-point tolerance (relative 1e-9 on the squared-error sums; the benchmark checks it).
Rendering the section's four PNGs is timed separately, and the whole command
(``ekf_experiments --only tables --no-progress``: imports, warm-up, tables, PNGs) once as a
child process. One more batched run with timers on its parts says where the time
goes (the timers add a little).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
# plain numpy everywhere (no JIT at run time): the 100-trial tables in reasonable time
TARGET_S = 15.0


def timed(fn):
    """(result, wall s, CPU s) of fn()."""
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


@contextlib.contextmanager
def cpu_per_part(parts: dict[str, tuple[type, str]], acc: dict[str, float]):
    """Add the CPU seconds spent in each (class, method) to ``acc`` while the block runs."""
    saved = []
    for key, (cls, name) in parts.items():
        fn = getattr(cls, name)
        saved.append((cls, name, fn))

        def timed_fn(*a, _fn=fn, _key=key, **k):
            c0 = time.process_time()
            try:
                return _fn(*a, **k)
            finally:
                acc[_key] = acc.get(_key, 0.0) + time.process_time() - c0
        setattr(cls, name, timed_fn)
    try:
        yield acc
    finally:
        for cls, name, fn in saved:
            setattr(cls, name, fn)


def breakdown(simulate_once) -> tuple[float, dict[str, float]]:
    """CPU seconds of one batched run and of its parts (a nested part is inside its parent)."""
    from ekf_localization.control.batched_pure_pursuit import BatchedPurePursuit
    from ekf_localization.core.ekf import BatchedEKF
    from seed_experiments.experiments import seed000_estimators as est
    from sim_robot.world.world import World

    parts = {"follower (BatchedPurePursuit.update)": (BatchedPurePursuit, "update"),
             "simulated world and sensors (World.advance)": (World, "advance"),
             "the five filters' steps (Seed000Filter.step)": (est.Seed000Filter, "step"),
             "  of which BatchedEKF.predict": (BatchedEKF, "predict"),
             "  of which BatchedEKF.update": (BatchedEKF, "update")}
    acc: dict[str, float] = {}
    with cpu_per_part(parts, acc):
        _, _, total = timed(simulate_once)
    return total, {k: acc.get(k, 0.0) for k in parts}


def cli_run(trials: int) -> tuple[float, float]:
    """Wall and CPU seconds (the child's user + system) of the whole ekf_experiments command."""
    with tempfile.TemporaryDirectory() as tmp:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "seed_experiments.experiments.cli", "--only", "tables",
                        "--no-progress", "--trials", str(trials), "--out", tmp], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
        wall = time.perf_counter() - w0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-cli", action="store_true", help="skip the whole-command run")
    ap.add_argument("--doc", action="store_true", help="write the result into docs/performance.md")
    args = ap.parse_args(argv)

    from ekf_localization.control.field_path import load_preset
    from seed_experiments.experiments import seed000_tables as tables
    from seed_experiments.experiments.seed000_sim import simulate

    tables.warm_up()
    path = load_preset(tables.PATH_NAME)
    load0 = os.getloadavg()
    best: dict[str, list[float]] = {"per_trial": [np.inf, np.inf], "batched": [np.inf, np.inf]}
    runs = {}
    for _ in range(args.repeats):
        for kind in ("per_trial", "batched"):
            run, wall, cpu = timed(lambda kind=kind: simulate(path, tables.SPECS, args.trials, tables.SEED,
                                                             record_trials=20, follower_kind=kind))
            best[kind] = [min(best[kind][0], wall), min(best[kind][1], cpu)]
            runs[kind] = run
    a, b = runs["per_trial"], runs["batched"]
    same = (all(np.allclose(b.sq_err[n], a.sq_err[n], rtol=1e-9, atol=0.0) for n in a.names)
            and np.array_equal(a.steps, b.steps))
    render = [np.inf, np.inf]
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            _, wall, cpu = timed(lambda: tables.render(b, Path(tmp), Path(tmp) / "results"))
            render = [min(render[0], wall), min(render[1], cpu)]
    total, parts = breakdown(lambda: simulate(path, tables.SPECS, args.trials, tables.SEED, record_trials=20))
    cli = None if args.no_cli else cli_run(args.trials)
    load1 = os.getloadavg()

    peer_cpu = best["per_trial"][1]
    rows = [("peer: one PurePursuitFollower per trial (the loop before the batched follower)",
             *best["per_trial"]),
            ("ours: BatchedPurePursuit (ekf_experiments' tables)", *best["batched"]),
            ("rendering the section's four PNGs (not in the tables' time)", *render)]
    lines = [f"{args.trials} trials, 6 estimators, seed {tables.SEED}; minimum of {args.repeats} "
             f"interleaved runs after a warm-up run; load average "
             f"{' '.join(f'{v:.1f}' for v in load0)} at the start, "
             f"{' '.join(f'{v:.1f}' for v in load1)} at the end.", "",
             "| case | wall s | CPU s | CPU / peer's |", "|---|---|---|---|"]
    for name, wall, cpu in rows:
        lines.append(f"| {name} | {wall:.2f} | {cpu:.2f} | {cpu / peer_cpu:.2f} |")
    if cli is not None:
        cmd = f"ekf_experiments --only tables --no-progress --trials {args.trials}"
        lines.append(f"| `{cmd}` (whole command: imports, warm-up, tables, PNGs) | {cli[0]:.2f} | "
                     f"{cli[1]:.2f} | - |")
    ours = best["batched"][1]
    lines += ["", f"Where the batched run's CPU goes (one more run, {total:.2f} s CPU with the timers):", "",
              "| part | CPU s | share |", "|---|---|---|"]
    lines += [f"| {k} | {v:.2f} | {100 * v / total:.0f} % |" for k, v in parts.items()]
    rest = total - sum(v for k, v in parts.items() if not k.startswith(" "))
    lines.append(f"| the loop itself (errors, records, the odometry integrator) | {rest:.2f} | "
                 f"{100 * rest / total:.0f} % |")
    lines += ["", "Same numbers from both loops (squared errors to 1e-9 relative): "
              f"{'yes' if same else 'NO'}.",
              f"Target <= {TARGET_S:.0f} s for the {args.trials}-trial tables (CPU s, the figure the "
              f"machine's load does not stretch): {'met' if ours <= TARGET_S else 'NOT met'} "
              f"({ours:.2f} s; wall {best['batched'][0]:.2f} s)."]
    text = "\n".join(lines)
    print(text)
    if args.doc:
        from perf_doc import write_section  # benchmarks/ is on sys.path when run as a script
        title = f"Seed 000 tables, {args.trials} trials (bench_seed_tables.py)"
        print(f"wrote {write_section('seed_tables', title, text)}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
