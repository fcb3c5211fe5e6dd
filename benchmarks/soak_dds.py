"""Live soak over real DDS: sim_node, ekf_node and pure_pursuit_node (the demo's nodes and
YAMLs, config/ekf.yaml with cmd_vel) driving the FTC cycle path over and over at a real-time
factor, optionally with CPU hogs keeping every core busy.

Every minute of wall time it prints, from this process's subscriptions (sim time): the
longest gap between /odometry/filtered stamps, the outputs more than two publish periods
apart, the position error against /ground_truth/odom at the output's stamp, and ekf_node's
resident memory. The verdict: RSS growth after the first minute <= 10 MB, max position error
<= 0.10 m, no output gap over ``--max-gap-periods`` publish periods (default 2; CI's short
soak, at real time, allows 10: pure_pursuit's odom_timeout; see test/test_soak_fuzz.py), net
of /clock stalls: less the longest step of the simulator's own /clock inside it (a node cannot
publish at a time /clock never reached). Like the error and the
RSS growth, the gaps count from minute 2: minute 1 is the start-up (pure_pursuit_node loads its
path for seconds). The outputs more than two periods apart are printed whatever the limit, raw
and net, every minute. With ``--peer``, the peer in the same run: the gaps of a bare node that
only publishes on a 50 Hz timer (benchmarks/timer_peer.py), what rclpy and the scheduler cost
any Python node under that load. It is one more process on /clock (2000 messages/s at factor
2), so it loads the run too.

Scheduling. ekf_node runs as config/ekf.yaml says (``thread_priority: 40``, SCHED_FIFO). sim_node
stands for the physical world, which a loaded robot computer cannot slow down: it runs at
SCHED_FIFO ``--world-priority`` (60); at normal priority it falls behind the hogs and then moves
/clock in 100 ms batches, a gap in every node's output. This monitor runs at SCHED_FIFO 1 (above
the hogs, below the nodes) so that it does not miss outputs. ``--world-priority 0`` leaves both
at normal priority. The hogs and pure_pursuit_node stay at normal priority.

    python benchmarks/soak_dds.py [--minutes 30] [--rtf 2.0] [--hogs 2] [--max-gap-periods 2] [--peer]
"""

from __future__ import annotations

import argparse
import bisect
import math
import multiprocessing
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections import deque
from pathlib import Path

RSS_GROWTH_MB = 10.0
MAX_ERROR_M = 0.10
PERIOD_NS = 20_000_000  # config/ekf.yaml frequency 50 Hz
TRUTH_GAP_NS = 30_000_000  # truth samples further apart (100 Hz: 10 ms) give no error there
PEER = Path(__file__).resolve().parent / "timer_peer.py"


def _hog(niceness: int = 0) -> None:
    """A busy core at ``niceness``, until its parent is gone (a killed soak leaves no hog behind).
    Forked after rclpy.init, it would inherit rclpy's SIGTERM handler, which does not exit:
    restore the default."""
    os.nice(niceness)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    parent = os.getppid()
    while os.getppid() == parent:
        for _ in range(1_000_000):
            pass


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return math.nan


def clock_stall_ns(a: int, b: int, clock: list[int], normal_step_ns: int) -> int:
    """How much of the output gap (a, b) the simulator's own clock skipped: the longest /clock step
    overlapping it, less the normal step (a node cannot publish at a time /clock never reached)."""
    i, j = max(bisect.bisect_right(clock, a) - 1, 0), bisect.bisect_left(clock, b)
    steps = [min(c1, b) - max(c0, a) for c0, c1 in zip(clock[i:j], clock[i + 1:j + 1], strict=False)]
    return max(max(steps, default=0) - normal_step_ns, 0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=30.0, help="wall-clock minutes")
    parser.add_argument("--rtf", type=float, default=2.0)
    parser.add_argument("--hogs", type=int, default=os.cpu_count() or 2, help="busy-loop processes")
    parser.add_argument("--hog-nice", type=int, default=0,
                        help="the hogs' niceness: 0 competes with the nodes as equals; 10 is background "
                             "work below the robot's own processes")
    parser.add_argument("--world-priority", type=int, default=60,
                        help="SCHED_FIFO priority of sim_node, the physical world (this monitor gets 1); "
                             "0: both at normal priority")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--peer", action="store_true",
                        help="also run benchmarks/timer_peer.py and print its gaps beside ekf_node's")
    parser.add_argument("--max-gap-periods", type=float, default=2.0,
                        help="the verdict's longest allowed gap between outputs, in publish periods")
    args = parser.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from rosgraph_msgs.msg import Clock as ClockMsg
    from std_msgs.msg import Empty

    from ekf_localization.core.units import ns_to_seconds, stamp_to_ns
    from ekf_localization.ros.node_runner import init_rclpy, running
    from ekf_localization.ros.scheduling import use_fifo
    from ekf_localization.tools import demo

    if "ROS_DOMAIN_ID" not in os.environ:
        lock = demo.choose_domain()  # noqa: F841 - held until exit
    out = Path(tempfile.mkdtemp(prefix="soak_dds_"))
    ns = argparse.Namespace(path="cycle", path_file=None, cycles=100000, rtf=args.rtf, seed=args.seed,
                            joint_states=None, ramp=False, dropout=None, view=False, drive="mecanum",
                            sim_params=None, cameras=1, bump_push=None)
    init_rclpy([])  # Ctrl-C / SIGTERM end the loop; the nodes and hogs are then stopped
    node = Node("soak_dds", parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    truth_t: deque[int] = deque(maxlen=5000)
    truth_xy: deque[tuple[float, float]] = deque(maxlen=5000)
    window = {"stamps": [], "errors": [], "clock": [], "peer": []}

    pending: deque[tuple[int, float, float]] = deque(maxlen=5000)  # estimates awaiting later truth

    def truth_at(t: int) -> tuple[float, float] | None:
        """The truth at ``t``, linear between the samples around it (10 ms apart at 100 Hz)."""
        i = bisect.bisect_left(truth_t, t)  # deque: O(n) index, bounded
        if i == 0 or i == len(truth_t) or truth_t[i] - truth_t[i - 1] > TRUTH_GAP_NS:
            return None
        a, b = truth_t[i - 1], truth_t[i]
        s = (t - a) / (b - a)
        (x0, y0), (x1, y1) = truth_xy[i - 1], truth_xy[i]
        return x0 + s * (x1 - x0), y0 + s * (y1 - y0)

    def on_truth(m) -> None:
        truth_t.append(stamp_to_ns(m.header.stamp))
        truth_xy.append((m.pose.pose.position.x, m.pose.pose.position.y))
        while pending and pending[0][0] <= truth_t[-1]:  # an estimate may arrive before its truth
            t, x, y = pending.popleft()
            xy = truth_at(t)
            if xy is not None:
                window["errors"].append(math.hypot(x - xy[0], y - xy[1]))

    def on_estimate(m) -> None:
        t = stamp_to_ns(m.header.stamp)
        window["stamps"].append(t)
        pending.append((t, m.pose.pose.position.x, m.pose.pose.position.y))

    node.create_subscription(ClockMsg, "/clock", lambda m: window["clock"].append(stamp_to_ns(m.clock)), 1000)
    node.create_subscription(Odometry, demo.TOPIC_TRUTH, on_truth, 100)
    node.create_subscription(Odometry, demo.TOPIC_FILTERED, on_estimate, 100)
    node.create_subscription(Odometry, "soak_peer/odometry",
                             lambda m: window["peer"].append(stamp_to_ns(m.header.stamp)), 100)
    ready = node.create_publisher(Empty, demo.RECORDER_READY,
                                  QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    ready.publish(Empty())
    procs = demo.start_nodes(ns, out)
    peer = None
    if args.peer:
        with (out / "timer_peer.log").open("w") as peer_log:  # the child keeps its own descriptor
            peer = subprocess.Popen([sys.executable, str(PEER)], stdout=peer_log, stderr=subprocess.STDOUT)
    ekf = next(p for p in procs if p.name == "ekf_node")
    hogs = [multiprocessing.Process(target=_hog, args=(args.hog_nice,), daemon=True)
            for _ in range(args.hogs)]
    for h in hogs:
        h.start()
    sim = next(p for p in procs if p.name == "sim_node")
    # after the hogs are forked (they would inherit it); this process measures the gaps, so it must
    # not miss outputs either
    monitor_priority = 1 if args.world_priority else 0
    world = [use_fifo(priority, pid) or "ok"
             for priority, pid in ((args.world_priority, sim.proc.pid), (monitor_priority, None))]
    print(f"soak_dds: rtf {args.rtf:g}, {args.hogs} CPU hogs (nice {args.hog_nice}), {args.minutes:g} min "
          f"wall, ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID')}, logs {out}; load {os.getloadavg()}; "
          f"SCHED_FIFO {args.world_priority} for sim_node, {monitor_priority} for the monitor (0: normal): "
          f"{', '.join(world)}",
          flush=True)
    # rss MB, longest gap s, gaps > 2 periods, max error m, outputs, load, longest gap net of /clock
    # stalls s, the peer's gaps > 2 periods, the peer's longest gap s, gaps > 2 periods net of stalls
    minutes: list[tuple[float, float, int, float, int, float, float, int, float, int]] = []
    last_stamp: int | None = None
    last_peer: list[int] = []
    last_clock: list[int] = []
    t0 = time.monotonic()
    ok = True
    try:
        while time.monotonic() - t0 < args.minutes * 60:
            t_min = time.monotonic() + 60.0
            while time.monotonic() < t_min and running(ex):
                ex.spin_once(timeout_sec=0.05)
                dead = [p for p in procs if not p.alive()]
                if dead:
                    raise RuntimeError("; ".join(f"{p.name} exited:\n{p.tail()}" for p in dead))
            if not running(ex):  # a signal: the partial minute is not counted
                print("soak_dds: stopped by a signal", flush=True)
                ok = False
                break
            stamps = ([last_stamp] if last_stamp is not None else []) + window["stamps"]
            gaps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
            last_stamp = stamps[-1] if stamps else last_stamp
            clock = last_clock + window["clock"]
            last_clock = clock[-1:]
            steps = [b - a for a, b in zip(clock, clock[1:], strict=False)]
            normal = statistics.median_low(steps) if steps else 0
            net = [g - clock_stall_ns(a, a + g, clock, normal)
                   for a, g in zip(stamps, gaps, strict=False) if g > 2 * PERIOD_NS]
            errs = window["errors"]
            peer_stamps = last_peer + window["peer"]
            last_peer = peer_stamps[-1:]
            peer_gaps = [b - a for a, b in zip(peer_stamps, peer_stamps[1:], strict=False)]
            row = (rss_mb(ekf.proc.pid), ns_to_seconds(max(gaps, default=0)),
                   sum(g > 2 * PERIOD_NS for g in gaps), max(errs, default=math.nan),
                   len(window["stamps"]), os.getloadavg()[0], ns_to_seconds(max(net, default=0)),
                   sum(g > 2 * PERIOD_NS for g in peer_gaps), ns_to_seconds(max(peer_gaps, default=0)),
                   sum(n > 2 * PERIOD_NS for n in net))
            minutes.append(row)
            print(f"  minute {len(minutes):3d}: ekf_node RSS {row[0]:.1f} MB, outputs {row[4]}, longest gap "
                  f"{row[1]:.3f} s ({row[6]:.3f} s net of /clock stalls), gaps > 2 periods {row[2]} "
                  f"({row[9]} net), "
                  f"max error {row[3]:.3f} m, load {row[5]:.1f}"
                  + (f"; peer: gaps > 2 periods {row[7]}, longest {row[8]:.3f} s" if peer else ""),
                  flush=True)
            window["stamps"], window["errors"], window["clock"], window["peer"] = [], [], [], []
    except RuntimeError as exc:
        print(f"soak_dds: stopped: {exc}", flush=True)
        ok = False
    finally:
        for h in hogs:
            h.kill()
            h.join(timeout=5.0)
        for p in procs:
            p.stop()
        if peer is not None:
            peer.send_signal(signal.SIGINT)
            try:
                peer.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                peer.kill()
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    if len(minutes) < 2:
        print("soak_dds: too short for a verdict")
        return 1
    growth = max(r[0] for r in minutes[1:]) - minutes[0][0]
    max_err = max(r[3] for r in minutes[1:])  # the first minute includes the start-up
    unmeasured = [k + 1 for k, r in enumerate(minutes) if math.isnan(r[3])]
    if unmeasured:  # no estimate matched to the truth: no verdict on the error
        max_err = math.nan
        print(f"soak_dds: no position error measured in minute(s) {unmeasured}")
    gaps = sum(r[2] for r in minutes)
    print(f"soak_dds: {len(minutes)} min wall at rtf {args.rtf:g} with {args.hogs} hogs: ekf_node RSS "
          f"{minutes[0][0]:.1f} MB after minute 1, growth {growth:+.1f} MB; max position error after "
          f"minute 1 {max_err:.3f} m; outputs more than 2 periods apart {gaps}, {sum(r[9] for r in minutes)} "
          f"net of /clock stalls (longest "
          f"{max(r[1] for r in minutes):.3f} s, {max(r[6] for r in minutes):.3f} s net of /clock stalls); "
          f"load {os.getloadavg()}")
    if args.peer:
        print(f"soak_dds: peer (a bare 50 Hz timer node, same run): outputs more than 2 periods apart "
              f"{sum(r[7] for r in minutes)} (longest {max(r[8] for r in minutes):.3f} s)")
    # no output can come at a time /clock never reached; minute 1 is the start-up (pure_pursuit_node
    # loads its 400 000-vertex path for seconds, the simulator's first batches), as for the error
    longest = max(r[6] for r in minutes[1:])
    gap_ok = longest <= ns_to_seconds(round(args.max_gap_periods * PERIOD_NS))
    if not gap_ok:
        print(f"soak_dds: an output gap of {longest:.3f} s net of /clock stalls after minute 1 is over "
              f"{args.max_gap_periods:g} periods")
    ok &= growth <= RSS_GROWTH_MB and max_err <= MAX_ERROR_M and gap_ok
    print("soak_dds: " + ("ok" if ok else "FAILED"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
