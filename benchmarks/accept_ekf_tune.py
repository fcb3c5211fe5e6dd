"""ekf_tune acceptance: recovery from a bad start, known noise, no ground truth.

    python benchmarks/accept_ekf_tune.py [--out output/accept_ekf_tune] [--jobs 2] [--duration 20]
                                         [--seeds N]

Records the demo world's bags with sim_robot/ros/sim_bag.py (no DDS): bag 1 (seed 1), bag 2 (seed 2),
bag 1 without the truth topic, and a seed-3 bag whose dead wheels are 4× noisier in variance
than their messages say. Then, each a plain ekf_tune command (printed as it runs):

1. recovery: ekf_tune on bag 1 from config/ekf.yaml with every process noise ×100 and every
   input scale ×0.01 (``--scale-start 100,0.01``, truth objective); on bag 2 the tuned RMSE
   must be ≤ 1.10× the hand-tuned config/ekf.yaml's and the mean NEES inside its band;
2. no truth: the same on bag 1 without truth (the likelihood objective); on bag 2 its RMSE must
   be ≤ 1.20× the truth-tuned config's;
3. known noise: ekf_tune (likelihood) on the noisy bag from config/ekf.yaml: the fitted
   ``odom0_variance_scale`` must be within 25 % of 4.

With ``--seeds N`` also replays the hand-tuned and both tuned configs on N more held-out bags
(seeds 2 .. N+1) and reports, per config, on how many of them the RMSE is within 1.10× the
hand-tuned's and the mean NEES inside its band: one bag 2 is one draw.

Prints one line per criterion (measured, target, met / NOT met) and writes them to
``OUT/acceptance.md``. Exit status 0 whether or not the targets are met (it measures); 1 if
a command failed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HAND_TUNED = REPO / "config" / "ekf.yaml"
TRUTH_TOPIC = "/ground_truth/odom"


def _bag(out: Path, name: str, seed: int, duration: float, *extra: str) -> Path:
    from sim_robot.ros import sim_bag

    path = out / name
    if not path.exists():
        sim_bag.main([str(path), "--duration", str(duration), "--seed", str(seed), *extra])
    return path


def _tune(argv: list[str]) -> float:
    """Run ekf_tune with ``argv``; wall seconds. RuntimeError unless it exits 0."""
    from ekf_localization.tools import ekf_tune

    print("$ ekf_tune " + " ".join(argv), flush=True)
    t0 = time.perf_counter()
    rc = ekf_tune.main(argv)
    if rc != 0:
        raise RuntimeError(f"ekf_tune exited {rc}")
    return time.perf_counter() - t0


def _on_bag(params: Path, bag: Path) -> tuple[float, float, tuple[float, float]]:
    """(x, y) RMSE, mean pose NEES and its band of ``params`` replayed on ``bag``."""
    from ekf_localization.tools import bag_io
    from ekf_localization.tools.consistency import pose_nees
    from ekf_localization.tools.evaluation import rmse
    from ekf_localization.tools.replay import load_settings, replay

    traj = replay(bag, load_settings(params)).trajectory()
    truth = bag_io.read_odometry(bag, TRUTH_TOPIC)
    nees = pose_nees(traj, truth)
    return rmse(traj, truth)["xy"], nees.mean, nees.band


def _scale(tuned: Path, name: str) -> float:
    from ekf_localization.ros.parameters import parameters_from_yaml

    return float(parameters_from_yaml(tuned).get(name, 1.0))


def _over_seeds(out: Path, duration: float, n: int) -> list[str]:
    """Markdown rows: each config over the held-out seeds 2..n+1 against the hand-tuned."""
    import numpy as np

    configs = {"hand-tuned config/ekf.yaml": HAND_TUNED, "truth-tuned": out / "truth" / "tuned.yaml",
               "likelihood-tuned (no truth)": out / "no_truth" / "tuned.yaml"}
    runs = {name: [] for name in configs}
    for seed in range(2, n + 2):
        bag = _bag(out, f"seed{seed}", seed, duration)
        for name, params in configs.items():
            runs[name].append(_on_bag(params, bag))
    hand = np.array([r[0] for r in runs["hand-tuned config/ekf.yaml"]])
    lines = [f"Over {n} held-out bags (seeds 2-{n + 1}):", "",
             "| config | RMSE / hand-tuned: geometric mean, range | ≤ 1.10× "
             "| mean NEES: median, range | in band |",
             "|---|---|---|---|---|"]
    for name, rows in runs.items():
        ratio = np.array([r[0] for r in rows]) / hand
        nees = np.array([r[1] for r in rows])
        inside = sum(b[0] <= v <= b[1] for v, (_, _, b) in zip(nees, rows, strict=True))
        geo = float(np.exp(np.mean(np.log(ratio))))
        lines.append(f"| {name} | {geo:.3f}, {ratio.min():.2f}-{ratio.max():.2f} | "
                     f"{int(np.sum(ratio <= 1.10))}/{n} | {np.median(nees):.2f}, "
                     f"{nees.min():.2f}-{nees.max():.2f} | {inside}/{n} |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=REPO / "output" / "accept_ekf_tune")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--duration", type=float, default=20.0, help="s of each bag")
    parser.add_argument("--seeds", type=int, default=0, help="also this many held-out bags (seeds 2..N+1)")
    args = parser.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    d = args.duration
    bag1 = _bag(out, "bag1", 1, d)
    bag2 = _bag(out, "bag2", 2, d)
    bag1_nt = _bag(out, "bag1_no_truth", 1, d, "--no-truth")
    noisy = _bag(out, "noise4", 3, d, "--dead-wheel-variance-factor", "4")
    load0 = os.getloadavg()[0]
    common = ["--params", str(HAND_TUNED), "--jobs", str(args.jobs)]
    bad = ["--scale-start", "100,0.01"]
    try:
        t_truth = _tune([str(bag1), *common, *bad, "--objective", "truth", "--holdout", str(bag2),
                         "--out", str(out / "truth")])
        t_lik = _tune([str(bag1_nt), *common, *bad, "--holdout", str(bag2), "--out", str(out / "no_truth")])
        t_noise = _tune([str(noisy), *common, "--objective", "likelihood", "--out", str(out / "noise4")])
    except RuntimeError as exc:
        print(f"accept_ekf_tune: {exc}", file=sys.stderr)
        return 1
    hand = _on_bag(HAND_TUNED, bag2)
    truth = _on_bag(out / "truth" / "tuned.yaml", bag2)
    lik = _on_bag(out / "no_truth" / "tuned.yaml", bag2)
    odom_scale = _scale(out / "noise4" / "tuned.yaml", "odom0_variance_scale")

    def met(ok: bool) -> str:
        return "met" if ok else "NOT met"

    band = truth[2]
    rows = [
        ("recovery: bag 2 RMSE, truth-tuned / hand-tuned", f"{truth[0]:.5f} / {hand[0]:.5f} m = "
         f"{truth[0] / hand[0]:.3f}×", "≤ 1.10×", met(truth[0] <= 1.10 * hand[0])),
        ("recovery: bag 2 mean NEES, truth-tuned", f"{truth[1]:.2f} (hand-tuned {hand[1]:.2f})",
         f"in [{band[0]:.2f}, {band[1]:.2f}]", met(band[0] <= truth[1] <= band[1])),
        ("no truth: bag 2 RMSE, likelihood-tuned / truth-tuned", f"{lik[0]:.5f} / {truth[0]:.5f} m = "
         f"{lik[0] / truth[0]:.3f}× (NEES {lik[1]:.2f})", "≤ 1.20×", met(lik[0] <= 1.20 * truth[0])),
        ("known noise: odom0_variance_scale", f"{odom_scale:.3f}", "4 ± 25 % [3.0, 5.0]",
         met(3.0 <= odom_scale <= 5.0)),
    ]
    lines = ["| criterion | measured | target | |", "|---|---|---|---|"]
    lines += [f"| {a} | {b} | {c} | {e} |" for a, b, c, e in rows]
    lines += ["", f"ekf_tune wall s: truth {t_truth:.1f}, no truth {t_lik:.1f}, known noise {t_noise:.1f} "
              f"(--jobs {args.jobs}); load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after, "
              f"{os.cpu_count()} cores; bags {d:g} s"]
    if args.seeds > 0:
        lines += ["", *_over_seeds(out, d, args.seeds)]
    text = "\n".join(lines) + "\n"
    (out / "acceptance.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
