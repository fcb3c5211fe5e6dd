"""Localizer.add_measurement per message on the demo's stream, against a C++ (Eigen) peer.

    python benchmarks/bench_localizer.py [--duration 9.56] [--repeats 5] [--profile] [--doc]

The stream: the simulator world configured by the demo's config/sim.yaml
(``sim_robot.ros.sim_bag.simulated_messages``: the demo's topics and rates, dead-wheel odometry and
IMU at 100 Hz, camera poses 50 ms late; a fixed wobbling-circle drive) converted with the node's
own ``ros.conversions.message_to_measurement``, fed to a Localizer built from config/ekf.yaml
in receive order with the receive time as the clock (as ekf_node and bag_replay do).

The peer (``benchmarks/peer/ekf15.cpp``): a 15-state EKF core in C++ with Eigen, with a
history and rewind like the Localizer's, fed the same fused values (twist vx vy vyaw, IMU yaw
and yaw rate, camera x y yaw with its 5-sigma gate) from a file. It has no validation, frames
or diagnostics: it is the cost of the filter itself at the size robot_localization runs. It is
compiled here when g++ and Eigen are present (``apt-get install g++ libeigen3-dev``), else
skipped with a line saying so.

Each message's time is the minimum over ``--repeats`` passes with a fresh filter (the machine
is shared); p50/p99 per kind. ``--profile`` prints the top of a cProfile of one pass.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import math
import pstats
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
PEER_SOURCE = REPO / "benchmarks" / "peer" / "ekf15.cpp"
EIGEN_INCLUDE = Path("/usr/include/eigen3")
TOPICS = {"/odometry/dead_wheels": ("odom0", "odom"), "/imu/data": ("imu0", "imu"),
          "/camera/pose": ("pose0", "pose")}
KIND_NAMES = {"odom0": "odometry (twist)", "imu0": "IMU", "pose0": "camera pose (lagged)"}
PEER_KIND = {"odom0": "o", "imu0": "i", "pose0": "p"}
# what config/ekf.yaml fuses from each input: (part, indices within the part, RL state fields)
FUSED = {"odom0": ("twist", [0, 1, 5], [6, 7, 11]), "imu0": (None, None, [5, 11]),
         "pose0": ("pose", [0, 1, 5], [0, 1, 5])}


def demo_stream(duration_s: float) -> list[tuple[int, str, object]]:
    """(receive ns, input name, Measurement) of the simulated demo drive, in receive order."""
    from ekf_localization.ros.conversions import message_to_measurement
    from ekf_localization.ros.parameters import parameters_from_yaml
    from sim_robot.ros.sim_bag import simulated_messages
    from sim_robot.ros.sim_params import parse_parameters

    world, _ = parse_parameters(parameters_from_yaml(REPO / "config" / "sim.yaml", "sim_node"))
    out = []
    for topic, now, msg in simulated_messages(duration_s, seed=0, world_config=world):
        if topic in TOPICS:
            name, kind = TOPICS[topic]
            out.append((now, name, message_to_measurement(kind, msg)))
    return out


def load_config():
    from ekf_localization.models.registry import MODELS
    from ekf_localization.ros.ekf_parameters import parse_ekf_config
    from ekf_localization.ros.parameters import parameters_from_yaml
    from sim_robot.ros.sim_bag import START_POSE

    values = parameters_from_yaml(REPO / "config" / "ekf.yaml")
    values["initial_state"] = [START_POSE[0], START_POSE[1], 0.0, 0.0, 0.0, START_POSE[2]] + [0.0] * 9
    return parse_ekf_config(values, MODELS)


def time_localizer(stream, config, repeats: int) -> tuple[np.ndarray, object]:
    """Per-message ns (minimum over the repeats) and the last pass's localizer."""
    from ekf_localization.models.registry import make_localizer

    best = np.full(len(stream), np.iinfo(np.int64).max, dtype=np.int64)
    clock = time.perf_counter_ns
    loc = None
    for _ in range(repeats):
        loc = make_localizer(config)
        add = loc.add_measurement
        ns = np.empty(len(stream), dtype=np.int64)
        for k, (now, name, meas) in enumerate(stream):
            t0 = clock()
            add(name, meas, now)
            ns[k] = clock() - t0
        np.minimum(best, ns, out=best)
    return best, loc


def _imu_fused(meas) -> tuple[np.ndarray, np.ndarray]:
    z = np.array([meas.orientation[2], meas.angular_velocity[2]])
    R = np.diag([meas.orientation_covariance[2, 2], meas.angular_velocity_covariance[2, 2]])
    return z, R


def write_peer_stream(stream, config, path: Path) -> None:
    """The values the Localizer fuses from each message, one line each (peer/ekf15.cpp's input)."""
    gates = {inp.name: inp.threshold(FUSED[inp.name][0] or "pose") for inp in config.inputs}
    lines = []
    for _, name, meas in stream:
        part_name, local, fields = FUSED[name]
        if part_name is None:
            z, R = _imu_fused(meas)
        else:
            part = next(p for p in meas.parts() if p.name == part_name)
            z = np.asarray(part.values, dtype=float)[local]
            R = np.asarray(part.covariance, dtype=float)[np.ix_(local, local)]
        gate = gates[name]
        vals = [PEER_KIND[name], str(meas.stamp_ns), str(len(fields)), *map(str, fields),
                *(repr(float(v)) for v in z), *(repr(float(v)) for v in R.ravel()),
                "inf" if math.isinf(gate) else repr(float(gate))]
        lines.append(" ".join(vals))
    path.write_text("\n".join(lines) + "\n")


def run_peer(stream, config, repeats: int, workdir: Path) -> dict | str:
    """The peer's per-kind timings, or why it was skipped."""
    cxx = shutil.which("g++")
    if cxx is None or not (EIGEN_INCLUDE / "Eigen" / "Dense").exists():
        return "C++ peer skipped: needs g++ and Eigen (apt-get install g++ libeigen3-dev)"
    exe = workdir / "ekf15"
    build = subprocess.run([cxx, "-O2", "-DNDEBUG", f"-I{EIGEN_INCLUDE}", "-o", str(exe), str(PEER_SOURCE)],
                           capture_output=True, text=True)
    if build.returncode != 0:
        return f"C++ peer skipped: compiling {PEER_SOURCE.name} failed:\n{build.stderr[-2000:]}"
    data = workdir / "stream.txt"
    write_peer_stream(stream, config, data)
    out = subprocess.run([str(exe), str(data), str(repeats)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def _us(a: np.ndarray, q: float) -> float:
    return float(np.percentile(a, q)) / 1e3


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=9.56, help="seconds of simulated driving")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--profile", action="store_true", help="print a cProfile of one pass")
    ap.add_argument("--doc", action="store_true", help="write the result into docs/performance.md")
    args = ap.parse_args(argv)
    config = load_config()
    stream = demo_stream(args.duration)
    names = [name for _, name, _ in stream]
    ours, loc = time_localizer(stream, config, args.repeats)
    with tempfile.TemporaryDirectory() as tmp:
        peer = run_peer(stream, config, args.repeats, Path(tmp))
    counts = {n: names.count(n) for n in KIND_NAMES}
    lines = [f"{args.duration:g} s of the simulated demo drive: "
             + ", ".join(f"{counts[n]} {KIND_NAMES[n]}" for n in KIND_NAMES)
             + f"; {loc.rewinds} rewinds ({loc.stats['pose0'].applied} poses applied); "
             f"per message the minimum of {args.repeats} passes.", ""]
    head = "| kind | ours p50 µs | ours p99 µs | C++ peer p50 µs | C++ peer p99 µs | ours / peer (p50) |"
    lines += [head, "|---|---|---|---|---|---|"]
    sel = {n: np.array([k for k, m in enumerate(names) if m == n]) for n in KIND_NAMES}
    sel["all"] = np.arange(len(names))
    for key in (*KIND_NAMES, "all"):
        a = ours[sel[key]]
        row = [KIND_NAMES.get(key, "all messages"), f"{_us(a, 50):.1f}", f"{_us(a, 99):.1f}"]
        if isinstance(peer, dict):
            p = np.asarray(peer["ns"][PEER_KIND.get(key, "*")], dtype=np.int64)
            row += [f"{_us(p, 50):.1f}", f"{_us(p, 99):.1f}", f"{_us(a, 50) / _us(p, 50):.2f}"]
        else:
            row += ["-", "-", "-"]
        lines.append("| " + " | ".join(row) + " |")
    lines.append("")
    if isinstance(peer, dict):
        lines.append(f"C++ peer (benchmarks/peer/ekf15.cpp, g++ -O2, Eigen): {peer['rewinds']} rewinds, "
                     f"{peer['accepted']} updates accepted.")
    else:
        lines.append(peer)
    p50 = _us(ours, 50)
    lines.append(f"Target p50 <= 10 µs (all messages): {'met' if p50 <= 10.0 else 'NOT met'} ({p50:.1f} µs).")
    text = "\n".join(lines)
    print(text)
    if args.profile:
        from ekf_localization.models.registry import make_localizer

        loc = make_localizer(config)
        prof = cProfile.Profile()
        prof.enable()
        for now, name, meas in stream:
            loc.add_measurement(name, meas, now)
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)
    if args.doc:
        from perf_doc import write_section

        print(f"wrote {write_section('localizer', 'Localizer per message (bench_localizer.py)', text)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
