"""What one publish of ekf_node's output costs: thread time of ``Publisher.publish`` at 1 kHz.

    python benchmarks/bench_publish.py [--count 10000] [--rate 1000] [--busy-us 0,200] [--doc]

Two processes on this machine's DDS (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a private
ROS_DOMAIN_ID): this script publishes nav_msgs/Odometry at ``--rate`` Hz and subscribes to
the relay's output (reliable, as a consumer of /odometry/filtered would); the relay, on the
EventsExecutor (ekf_node's), takes each message as CDR bytes, busy-waits ``--busy-us`` (the
work ekf_node does before it publishes), then publishes, and times the publish alone with
``time.thread_time()``. "ours" publishes the bytes as ekf_node does (``ros/cdr.py``); the
peer publishes an rclpy message (rclpy serialises it in the call), the way a node without
rosbags publishes. Reported per case: the publish's mean and p50/p99 thread time, the relay's
CPU %, and the messages that came back.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

RELAY = r"""
import copy, json, sys, time
import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from nav_msgs.msg import Odometry
from ekf_localization.ros.node_runner import make_executor
mode, busy, count = sys.argv[1], float(sys.argv[2]) * 1e-6, int(sys.argv[3])
rclpy.init()
node = Node("bench_publish_relay")
pub = node.create_publisher(Odometry, "bench_publish/out", 10)
qos = copy.copy(qos_profile_sensor_data)
qos.depth = 100
took = np.zeros(count)
n = [0]
last = [0.0]
def on_bytes(b):
    until = time.perf_counter() + busy
    while time.perf_counter() < until:
        pass
    out = b if mode == "bytes" else deserialize_message(b, Odometry)
    t0 = time.thread_time()
    pub.publish(out)
    if n[0] < count:
        took[n[0]] = time.thread_time() - t0
    n[0] += 1
    last[0] = time.monotonic()
node.create_subscription(Odometry, "bench_publish/in", on_bytes, qos, raw=True)
ex = make_executor("events")
ex.add_node(node)
c0 = w0 = None
while rclpy.ok():
    ex.spin_once(timeout_sec=0.05)
    if n[0] and c0 is None:
        c0, w0 = time.process_time(), time.monotonic()
    if n[0] >= count or (n[0] and time.monotonic() - last[0] > 1.0):  # all, or the rest was lost
        break
cpu = 100.0 * (time.process_time() - c0) / max(last[0] - w0, 1e-9)  # idle after the last: ~0
t = took[:min(n[0], count)] * 1e6
print(json.dumps({"n": n[0], "mean_us": float(t.mean()), "p50_us": float(np.percentile(t, 50)),
                  "p99_us": float(np.percentile(t, 99)), "cpu_percent": cpu}), flush=True)
"""


def run(mode: str, busy_us: float, args: argparse.Namespace) -> dict:
    """One relay process: ``args.count`` messages through it; its figures and the messages back."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    relay = subprocess.Popen([sys.executable, "-c", RELAY, mode, str(busy_us), str(args.count)],
                             stdout=subprocess.PIPE, text=True, cwd=REPO)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node("bench_publish_driver", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    back = [0]

    def on_back(_msg) -> None:
        back[0] += 1

    node.create_subscription(Odometry, "bench_publish/out", on_back, 10000)
    pub = node.create_publisher(Odometry, "bench_publish/in", 100)
    try:
        deadline = time.monotonic() + 60.0  # a late DDS peer: wait on the matches, not a sleep
        while (pub.get_subscription_count() < 1 or node.count_publishers("bench_publish/out") < 1) \
                and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        msg = Odometry()
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.pose.pose.orientation.w = 1.0
        period = 1.0 / args.rate
        t0 = time.monotonic()
        for k in range(args.count):
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(time.time_ns(), 1_000_000_000)
            pub.publish(msg)
            while time.monotonic() < t0 + (k + 1) * period:
                ex.spin_once(timeout_sec=0.0002)
        out, _ = relay.communicate(timeout=90.0)
        t1 = time.monotonic()
        while time.monotonic() - t1 < 0.5:
            ex.spin_once(timeout_sec=0.01)
    finally:
        if relay.poll() is None:
            relay.kill()
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    result = json.loads(out.strip().splitlines()[-1])
    result["back"] = back[0]
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=10000)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--busy-us", default="0,200", help="comma-separated busy work before each publish, µs")
    ap.add_argument("--doc", action="store_true", help="write the result into docs/performance.md")
    args = ap.parse_args(argv)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random().randrange(101, 200)))
    sys.path.insert(0, str(REPO / "benchmarks"))
    from perf_doc import machine_line

    busy = [float(b) for b in args.busy_us.split(",")]
    rows = []
    for b in busy:
        for mode, name in (("bytes", "ours: CDR bytes (ekf_node)"), ("message", "peer: rclpy message")):
            r = run(mode, b, args)
            rows.append((name, b, r))
    print(f"Machine: {machine_line()}.\n")
    lines = [f"{args.count} nav_msgs/Odometry at {args.rate:.0f} Hz through a relay on the EventsExecutor "
             "to one reliable reader in another process; thread time of `Publisher.publish` alone.", "",
             "| publish | busy before it, µs | mean µs | p50 µs | p99 µs | relay CPU % | relayed | back |",
             "|---|---|---|---|---|---|---|---|"]
    for name, b, r in rows:
        lines.append(f"| {name} | {b:.0f} | {r['mean_us']:.1f} | {r['p50_us']:.1f} | {r['p99_us']:.1f} | "
                     f"{r['cpu_percent']:.1f} | {r['n']} | {r['back']} |")
    lines.append("")
    for i in range(0, len(rows), 2):
        ours, peer = rows[i][2], rows[i + 1][2]
        lines.append(f"- busy {rows[i][1]:.0f} µs: bytes / message publish (mean) "
                     f"x{ours['mean_us'] / peer['mean_us']:.2f}")
    text = "\n".join(lines)
    print(text)
    if args.doc:
        from perf_doc import write_section

        print(f"wrote {write_section('publish', 'One publish of the output (bench_publish.py)', text)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
