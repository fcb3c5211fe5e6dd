"""The Localizer per message on the stream the shipped config sees, against filterpy.

    python benchmarks/bench_localizer.py [--duration 9.56] [--repeats 3] [--profile] [--doc]

The stream: the simulator world of the demo's config/sim.yaml driven by sim_bag's command
pattern (``sim_robot.ros.sim_bag.simulated_messages``): dead-wheel odometry and IMU at
100 Hz, camera landmark poses at the camera's rate and 50 ms late, cmd_vel (TwistStamped)
at 50 Hz, in receive order. Each message is converted by the node's own conversion
(``ros.conversions``) and given to a Localizer built from config/ekf.yaml, exactly as
ekf_node and bag_replay do (cmd_vel included: ``use_control`` is on in the shipped config).

The peer: filterpy's ExtendedKalmanFilter with the same process model object (the drive
response of config/ekf.yaml), fed the same fused values (odometry twist vx vy vyaw, IMU yaw
and yaw rate, camera x y yaw) and the same commands, predicting to each message's stamp. It
has no validation, frames, rewinds or diagnostics, and fuses a lagged camera pose at arrival.

Each message's time is the minimum over ``--repeats`` passes with a fresh filter; p50 and p99
over the messages.
"""

from __future__ import annotations

import argparse
import cProfile
import math
import pstats
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
INPUTS = {"/odometry/dead_wheels": ("odom0", "odom"), "/imu/data": ("imu0", "imu"),
          "/camera/pose": ("pose0", "pose")}
KINDS = {"odom0": "odometry", "imu0": "IMU", "pose0": "camera pose (lagged)", "cmd_vel": "cmd_vel"}
# what config/ekf.yaml fuses: (part, indices within the part, state rows of [x y yaw vx vy vyaw])
FUSED = {"odom0": ("twist", [0, 1, 5], [3, 4, 5]), "imu0": (None, None, [2, 5]),
         "pose0": ("pose", [0, 1, 5], [0, 1, 2])}


def shipped_stream(duration_s: float) -> list[tuple[int, str, object]]:
    """(receive ns, input name or "cmd_vel", record) of the simulated demo drive, in receive order."""
    from ekf_localization.ros.conversions import control_from_message, message_to_measurement
    from sim_robot.ros.sim_bag import demo_world_config, simulated_messages

    out = []
    for topic, now, msg in simulated_messages(duration_s, seed=0, world_config=demo_world_config()):
        if topic in INPUTS:
            name, kind = INPUTS[topic]
            out.append((now, name, message_to_measurement(kind, msg)))
        elif topic == "/cmd_vel":
            out.append((now, "cmd_vel", control_from_message(msg, now)))
    return out


def shipped_config():
    from ekf_localization.models.registry import MODELS
    from ekf_localization.ros.ekf_parameters import parse_ekf_config
    from ekf_localization.ros.parameters import parameters_from_yaml
    from sim_robot.ros.sim_bag import START_POSE

    values = parameters_from_yaml(REPO / "config" / "ekf.yaml")
    values["initial_state"] = [START_POSE[0], START_POSE[1], 0.0, 0.0, 0.0, START_POSE[2]] + [0.0] * 9
    return parse_ekf_config(values, MODELS)


def time_localizer(stream, config, repeats: int):
    """Per-message ns (minimum over the repeats), the applied entries each message came before
    (what its insertion replays), and the last pass's Localizer."""
    from ekf_localization.models.registry import make_localizer

    best = np.full(len(stream), np.iinfo(np.int64).max, dtype=np.int64)
    replayed = np.zeros(len(stream), dtype=np.int64)
    loc = None
    for _ in range(repeats):
        loc = make_localizer(config)
        ns = np.empty(len(stream), dtype=np.int64)
        for k, (now, name, record) in enumerate(stream):
            if name == "pose0":  # outside the timing: the applied history after its stamp
                replayed[k] = sum(e.stamp_ns > record.stamp_ns for e in loc.history[:loc.history_size])
            t0 = time.perf_counter_ns()
            if name == "cmd_vel":
                loc.add_control(record, now)
            else:
                loc.add_measurement(name, record, now)
            ns[k] = time.perf_counter_ns() - t0
        np.minimum(best, ns, out=best)
    return best, replayed, loc


def _fused(name: str, record) -> tuple[np.ndarray, np.ndarray]:
    part_name, local, _ = FUSED[name]
    if part_name is None:  # the IMU: yaw and yaw rate
        return (np.array([record.orientation[2], record.angular_velocity[2]]),
                np.diag([record.orientation_covariance[2, 2], record.angular_velocity_covariance[2, 2]]))
    part = next(p for p in record.parts() if p.name == part_name)
    return (np.asarray(part.values, dtype=float)[local],
            np.asarray(part.covariance, dtype=float)[np.ix_(local, local)])


def time_filterpy(stream, config, repeats: int) -> np.ndarray:
    """Per-message ns of filterpy's EKF on the same stream and process model (see the docstring)."""
    from filterpy.kalman import ExtendedKalmanFilter as FilterpyEKF

    from ekf_localization.models.registry import make_localizer

    model = make_localizer(config).model
    H = {name: np.eye(6)[rows] for name, (_, _, rows) in FUSED.items()}
    fields = [0, 1, 5, 6, 7, 11]  # the state's RL fields
    x0 = np.asarray(config.initial_state, dtype=float)[fields]
    P0 = np.asarray(config.initial_estimate_covariance, dtype=float)[np.ix_(fields, fields)]
    best = np.full(len(stream), np.iinfo(np.int64).max, dtype=np.int64)
    for _ in range(repeats):
        ekf = FilterpyEKF(dim_x=6, dim_z=3)
        ekf.x = x0.copy()
        ekf.P = P0.copy()
        t_ns, u = None, None
        ns = np.empty(len(stream), dtype=np.int64)
        for k, (_, name, record) in enumerate(stream):
            t0 = time.perf_counter_ns()
            stamp = record.stamp_ns
            if t_ns is not None and stamp > t_ns:  # predict to the stamp: x = f(x, u), P = F P Fᵀ + Q
                dt = (stamp - t_ns) / 1e9
                U = None if u is None else u[None]
                X, F = model.f_and_jacobian(ekf.x[None], U, dt)
                ekf.F, ekf.Q = F[0], np.asarray(model.noise(ekf.x[None], U, dt)).reshape(6, 6)
                ekf.predict()  # P = F P Fᵀ + Q (and x = F x, replaced below by f(x, u))
                ekf.x = X[0]
            t_ns = stamp if t_ns is None else max(t_ns, stamp)
            if name == "cmd_vel":
                u = record.twist[[0, 1, 5]]
            else:
                z, R = _fused(name, record)
                Hn = H[name]
                ekf.update(z, lambda x, Hn=Hn: Hn, lambda x, Hn=Hn: Hn @ x, R=R)
            ns[k] = time.perf_counter_ns() - t0
        np.minimum(best, ns, out=best)
    return best


def _us(a: np.ndarray, q: float) -> float:
    return float(np.percentile(a, q)) / 1e3


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=9.56, help="seconds of simulated driving")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="print a cProfile of one pass")
    ap.add_argument("--doc", action="store_true", help="write the figures into docs/performance.md")
    args = ap.parse_args(argv)
    config = shipped_config()
    if not config.use_control:
        print("config/ekf.yaml does not fuse cmd_vel: this is not the shipped stream", file=sys.stderr)
        return 2
    stream = shipped_stream(args.duration)
    names = [name for _, name, _ in stream]
    ours, replayed, loc = time_localizer(stream, config, args.repeats)
    peer = time_filterpy(stream, config, args.repeats)
    counts = {n: names.count(n) for n in KINDS}
    print(f"{args.duration:g} s of the simulated demo drive: "
          + ", ".join(f"{counts[n]} {KINDS[n]}" for n in KINDS)
          + f"; {loc.rewinds} rewinds, {loc.stats['pose0'].applied} camera poses applied; "
          f"per message the minimum of {args.repeats} passes")
    print(f"{'kind':<24}{'ours p50 us':>13}{'ours p99 us':>13}{'filterpy p50':>14}{'filterpy p99':>14}")
    for key in (*KINDS, "all"):
        sel = np.array([k for k, n in enumerate(names) if key in ("all", n)])
        print(f"{KINDS.get(key, 'all messages'):<24}{_us(ours[sel], 50):>13.1f}{_us(ours[sel], 99):>13.1f}"
              f"{_us(peer[sel], 50):>14.1f}{_us(peer[sel], 99):>14.1f}")
    p50, p99 = _us(ours, 50), _us(ours, 99)
    print(f"shipped config (config/ekf.yaml: odometry, IMU, camera fixes, cmd_vel) p50 {p50:.1f} us "
          f"p99 {p99:.1f} us")
    print(f"filterpy EKF, same stream and process model, no lag handling: p50 {_us(peer, 50):.1f} us "
          f"p99 {_us(peer, 99):.1f} us")
    peer50 = _us(peer, 50)
    mean, peer_mean = float(ours.mean()) / 1e3, float(peer.mean()) / 1e3
    lagged = np.array([k for k, n in enumerate(names) if n == "pose0"])
    entries = float(np.median(replayed[lagged])) if lagged.size else math.nan
    lag50 = _us(ours[lagged], 50) if lagged.size else math.nan
    print(f"p50 {p50:.1f} / {peer50:.1f} us = {p50 / peer50:.2f}x filterpy (goal <= 1.5x); "
          f"mean {mean:.1f} / {peer_mean:.1f} us = {mean / peer_mean:.2f}x (goal <= 2.5x)")
    print(f"lagged camera pose: p50 {lag50:.1f} us, median {entries:.0f} entries replayed; "
          f"entries x filterpy p50 = {entries * peer50:.1f} us: {lag50 / (entries * peer50):.2f}x "
          "(goal <= 1.0x)")
    if args.profile:
        from ekf_localization.models.registry import make_localizer

        loc = make_localizer(config)
        prof = cProfile.Profile()
        prof.enable()
        for now, name, record in stream:
            loc.add_control(record, now) if name == "cmd_vel" else loc.add_measurement(name, record, now)
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)
    if args.doc:
        from perf_doc import write_row

        write_row("Localizer per message, shipped config (all messages)",
                  f"p50 {p50:.1f} µs ({p50 / peer50:.2f}x), mean {mean:.1f} µs ({mean / peer_mean:.2f}x), "
                  f"p99 {p99:.1f} µs; lagged camera pose p50 {lag50:.0f} µs for {entries:.0f} entries "
                  f"replayed ({lag50 / (entries * peer50):.2f}x entries x filterpy p50)",
                  f"filterpy EKF p50 {peer50:.1f} µs, mean {peer_mean:.1f} µs, p99 {_us(peer, 99):.1f} µs")
        print(f"wrote {REPO / 'docs' / 'performance.md'}")
    return 0 if math.isfinite(p50) else 1


if __name__ == "__main__":
    sys.exit(main())
