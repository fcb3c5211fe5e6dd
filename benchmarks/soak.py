"""Offline soak: hours of simulated driving, closed loop, no DDS (a benchmark, not a test).

The ROS-free simulator world (seed 000's mecanum robot, 1 kHz) drives the FTC cycle path
over and over with pure pursuit following the *EKF's* estimate; the world's readings go
through the same message conversions and Localizer as ekf_node (config/ekf.yaml, told the
start pose). The follower's command goes to the Localizer as cmd_vel (a TwistStamped through
``control_from_message``, as ekf_node: config/ekf.yaml fuses it). Every simulated minute it
records the position error against the truth, the process's resident memory and the mean
wall-clock cost of one message (add_measurement / add_control) per kind. Prints per-window
figures and the verdict: no divergence (every estimate finite), bounded error, flat memory,
and a cost per message that does not grow with the run (minute 2 against the last minute,
at most +20 %: every message is O(1) in the length of the run).

    python benchmarks/soak.py [--hours 1.0] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ekf_localization.control.field_path import load_preset
from ekf_localization.control.pure_pursuit import FollowerConfig, PurePursuitFollower
from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.conversions import control_from_message, message_to_measurement
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import parameters_from_yaml
from sim_robot.ros import sim_messages
from sim_robot.world.camera_sensor import CameraReading
from sim_robot.world.dead_wheel_sensor import DeadWheelReading
from sim_robot.world.drives import DriveLimits
from sim_robot.world.field import Field
from sim_robot.world.imu_sensor import ImuReading
from sim_robot.world.world import World, WorldConfig

REPO = Path(__file__).resolve().parents[1]
CONTROL_NS = 20_000_000  # pure_pursuit_node's 50 Hz
COMMAND_LATENCY_NS = 20_000_000  # config/sim.yaml cmd_vel_latency (config/ekf.yaml control_latency)
COST_TOLERANCE = 0.20  # growth of the cost per message, last minute against minute 2
LIMITS = DriveLimits(wheel_speed_limit=32.7, wheel_acceleration_limit=60.0)  # goBILDA 312 rpm


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return math.nan


def cmd_vel(cmd: np.ndarray, t_ns: int):
    """The follower's command as pure_pursuit_node publishes it (TwistStamped, stamped now)."""
    from geometry_msgs.msg import TwistStamped

    msg = TwistStamped()
    msg.header.stamp = sim_messages.stamp(t_ns)
    msg.header.frame_id = "base_link"
    msg.twist.linear.x, msg.twist.linear.y, msg.twist.angular.z = (float(c) for c in cmd)
    return msg


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    path = load_preset("ftc_cycle")
    world = World(replace(WorldConfig(), limits=LIMITS, field=Field.preset("freight_frenzy"),
                          command_latency_ns=COMMAND_LATENCY_NS), n_trials=1,
                  seed=args.seed)
    world.reset(np.array(path.start))
    values = parameters_from_yaml(REPO / "config" / "ekf.yaml")
    values["initial_state"] = [path.start[0], path.start[1], 0.0, 0.0, 0.0, path.start[2]] + [0.0] * 9
    loc = make_localizer(parse_ekf_config(values, MODELS))
    follower = PurePursuitFollower(path, FollowerConfig())
    end_ns = int(args.hours * 3600 * SEC)
    window_ns = 60 * SEC
    errors: list[float] = []
    windows: list[tuple[float, float, float, float]] = []  # minute, rms error, max error, rss MB
    costs: list[dict[str, float]] = []  # per minute: kind -> mean seconds per message
    cost_sum: dict[str, list] = {}  # kind -> [seconds, messages] in the current minute
    nonfinite = laps = measurements = 0
    t_wall = time.perf_counter()
    while world.t_ns < end_ns:
        for r in world.advance(CONTROL_NS):
            now = world.t_ns
            if isinstance(r, DeadWheelReading):
                msg = sim_messages.dead_wheel_odometry(r, r.stamp_ns, "odom", "base_link")
                kind, source = "odom", "odom0"
            elif isinstance(r, CameraReading):
                if not r.visible[0]:
                    continue
                msg, kind, source = sim_messages.camera_pose(r, r.stamp_ns, "map"), "pose", "pose0"
            elif isinstance(r, ImuReading):
                msg, kind, source = sim_messages.imu(r, r.stamp_ns, "base_link"), "imu", "imu0"
            else:
                continue
            t0 = time.perf_counter()
            loc.add_measurement(source, message_to_measurement(kind, msg), now)
            acc = cost_sum.setdefault(kind, [0.0, 0])
            acc[0] += time.perf_counter() - t0
            acc[1] += 1
            measurements += 1
        est = loc.advance_to(world.t_ns)
        if est is None:
            continue
        if not est.is_finite():
            nonfinite += 1
            continue
        truth = world.truth[0]
        errors.append(math.hypot(est.state[0] - truth[0], est.state[1] - truth[1]))
        cmd = follower.update(float(est.state[0]), float(est.state[1]), float(est.state[2]), est.stamp_ns)
        world.set_command(np.array(cmd))
        t0 = time.perf_counter()
        loc.add_control(control_from_message(cmd_vel(cmd, world.t_ns), world.t_ns), world.t_ns)
        acc = cost_sum.setdefault("cmd_vel", [0.0, 0])
        acc[0] += time.perf_counter() - t0
        acc[1] += 1
        if follower.done:  # one more lap from where the robot is
            laps += 1
            follower.reset()
        if world.t_ns % window_ns < CONTROL_NS and errors:
            e = np.array(errors)
            windows.append((world.t_ns / 60e9, float(np.sqrt(np.mean(e * e))), float(e.max()), rss_mb()))
            costs.append({k: a[0] / a[1] for k, a in cost_sum.items() if a[1]})
            m, rms, mx, mem = windows[-1]
            cost = ", ".join(f"{k} {c * 1e3:.3f}" for k, c in sorted(costs[-1].items()))
            print(f"  minute {m:5.1f}: error rms {rms:.4f} m, max {mx:.4f} m, RSS {mem:.1f} MB; "
                  f"ms per message: {cost}", flush=True)
            errors = []
            cost_sum = {}
    wall = time.perf_counter() - t_wall
    rms = np.array([w[1] for w in windows])
    mx = np.array([w[2] for w in windows])
    mem = np.array([w[3] for w in windows])
    half = len(mem) // 2
    growth = float(mem[half:].mean() - mem[:half].mean()) if half else 0.0
    print(f"soak: {world.t_ns / 3600e9:.2f} h simulated in {wall:.0f} s wall, {measurements} measurements, "
          f"{laps} laps, {loc.resets} resets, {loc.pose_recoveries} recoveries, "
          f"{nonfinite} non-finite estimates")
    print(f"  position error per minute: rms median {np.median(rms):.4f} m, worst {rms.max():.4f} m; "
          f"max {mx.max():.4f} m")
    print(f"  RSS first minute {mem[0]:.1f} MB, last {mem[-1]:.1f} MB, second half minus first half "
          f"{growth:+.2f} MB")
    flat = True
    if len(costs) >= 3:  # minute 1 warms up (imports, caches): from minute 2 to the last
        for kind in sorted(costs[1]):
            first, last = costs[1][kind], costs[-1].get(kind, math.nan)
            change = last / first - 1.0
            flat &= change <= COST_TOLERANCE  # grows at most 20 % (a busy machine may only slow minute 2)
            print(f"  cost per {kind} message: minute 2 {first * 1e3:.3f} ms, minute {len(costs)} "
                  f"{last * 1e3:.3f} ms ({change:+.0%})")
    ok = nonfinite == 0 and mx.max() < 0.5 and abs(growth) < 20.0 and flat
    print("soak: " + ("ok (no divergence, bounded error, flat memory)" if ok else "FAILED"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
