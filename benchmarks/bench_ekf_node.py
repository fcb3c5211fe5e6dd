"""ekf_node under 1 kHz odometry from another process: loss, output rate, latency, CPU.

    python benchmarks/bench_ekf_node.py [--duration 10] [--rate 1000] [--frequency 1000]
                                        [--executors single,events] [--publish callback,timer]
                                        [--queue 100] [--doc]

Three processes on this machine's DDS (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a private
ROS_DOMAIN_ID): a publisher sends nav_msgs/Odometry at ``--rate`` Hz stamped with the wall
clock at publish time; the node under test; and this script, which subscribes to its
output. Each executor of ``--executors`` (ekf_localization.ros.node_runner: "single" =
SingleThreadedExecutor, "events" = rclpy.experimental.EventsExecutor, chosen with
$EKF_LOCALIZATION_EXECUTOR) runs both the relay and ekf_node. ekf_node runs with
``predict_to_current_time: false``, so each output is stamped with the newest odometry it has
fused: the latency of an input is the publish time (the DDS source timestamp) of the first
output stamped at or after it, minus its stamp; "arrival" takes the time DDS received that
output in this process instead (rmw's received timestamp, before this script's own executor,
whose queueing is not the node's). The peer is a minimal rclpy relay (subscribe, republish
at once) in the same setting, with the node's queue depth (``--queue``): it takes and
publishes messages as ekf_node does, the floor that rclpy and DDS set. ``--publish``:
"timer" publishes on ekf_node's timer at ``--frequency``; "callback" sets
``publish_on_measurement: true`` (each fused message is published from its own callback; the
timer runs at 50 Hz and has nothing new to add);
"rejected" is "callback" with every twist in a frame the node does not know, so each is
rejected, counted and warned about (throttled): what a misconfigured input costs; "tf" is
"callback" with ``publish_tf: true`` and a /tf listener in this script, so every output is
also broadcast as odom->base_link (as on a robot, where someone listens to /tf).

Reported: messages lost (sent − received by the node, from its /diagnostics), output rate,
input→publish latency p50/p99/max and input→arrival p99, CPU % of the node process (from
/proc), and ekf/relay ratios.
Target: 0 lost, p99 < 2 ms, CPU <= 25 % of one core.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import select
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
CLK_TCK = os.sysconf("SC_CLK_TCK")

PUBLISHER = r"""
import json, sys, time, numpy as np, rclpy
from rclpy.node import Node
from nav_msgs.msg import Odometry
rate, duration, n_sub, child = float(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), sys.argv[5]
rclpy.init()
node = Node("bench_odometry_publisher")
pub = node.create_publisher(Odometry, "odometry/dead_wheels", 100)
deadline = time.monotonic() + 60.0
while pub.get_subscription_count() < n_sub and time.monotonic() < deadline:
    time.sleep(0.01)
time.sleep(0.5)
msg = Odometry()
msg.header.frame_id, msg.child_frame_id = "odom", child
msg.pose.pose.orientation.w = 1.0
cov = [0.0] * 36
for i in range(6):
    cov[7 * i] = 1e-4
msg.pose.covariance = cov
msg.twist.covariance = cov
n = int(rate * duration)
period = 1.0 / rate
stamps = np.zeros(n, dtype=np.int64)
print(json.dumps({"start_ns": time.time_ns()}), flush=True)
t0 = time.perf_counter()
for k in range(n):
    target = t0 + k * period
    while True:
        d = target - time.perf_counter()
        if d <= 0:
            break
        if d > 2e-4:
            time.sleep(d - 1.5e-4)
    msg.twist.twist.linear.x = 0.5
    msg.twist.twist.angular.z = 0.1
    now = time.time_ns()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 1_000_000_000)
    pub.publish(msg)
    stamps[k] = now
np.save(sys.argv[4], stamps)
print(json.dumps({"sent": n, "end_ns": time.time_ns(), "wall_s": time.perf_counter() - t0}), flush=True)
time.sleep(1.0)
"""

RELAY = r"""
import copy, sys
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from nav_msgs.msg import Odometry
from ekf_localization.ros.node_runner import make_executor, spin_forever
rclpy.init()
node = Node("bench_relay")
pub = node.create_publisher(Odometry, "relay/odometry/filtered", 100)
qos = copy.copy(qos_profile_sensor_data)
qos.depth = int(sys.argv[1])  # the node's odom0_queue_size: the same queue as ekf_node's input
node.create_subscription(Odometry, "odometry/dead_wheels", pub.publish, qos)
ex = make_executor()
ex.add_node(node)
try:
    spin_forever(ex)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime + stime


def ekf_params(path: Path, frequency: float, on_measurement: bool, queue: int, tf: bool) -> None:
    f15 = [False] * 15
    cfg = f15.copy()
    cfg[6] = cfg[7] = cfg[11] = True
    params = {"model": "mecanum", "frequency": frequency, "sensor_timeout": 1.0, "world_frame": "odom",
              "publish_tf": tf, "predict_to_current_time": False, "smooth_lagged_data": True,
              "history_length": 0.5, "odom0": "odometry/dead_wheels", "odom0_config": cfg,
              "odom0_queue_size": queue, "publish_on_measurement": on_measurement}
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))


def run(kind: str, executor: str, args: argparse.Namespace, workdir: Path, publish: str = "") -> dict:
    """One trial: start the node under test on ``executor`` and the publisher; measure."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    env = dict(os.environ)
    env["EKF_LOCALIZATION_EXECUTOR"] = executor
    if kind == "ekf":
        params = workdir / "bench_ekf.yaml"
        on_measurement = publish in ("callback", "rejected", "tf")
        ekf_params(params, 50.0 if on_measurement else args.frequency, on_measurement, args.queue,
                   tf=publish == "tf")
        cmd = [sys.executable, "-m", "ekf_localization.nodes.ekf_node", "--ros-args",
               "--params-file", str(params),
               "-r", "__node:=bench_ekf", "-r", "odometry/filtered:=ekf/odometry/filtered"]
        topic = "ekf/odometry/filtered"
    else:
        cmd = [sys.executable, "-c", RELAY, str(args.queue)]
        topic = "relay/odometry/filtered"
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node("bench_listener", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    arrivals: list[tuple[int, int, int]] = []  # (output stamp, published, received by DDS here) ns

    def on_output(msg, info) -> None:
        arrivals.append((msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                         info["source_timestamp"], info["received_timestamp"]))

    diag: dict[str, str] = {}

    def on_diag(msg) -> None:
        for st in msg.status:
            if st.name.endswith(": odom0"):
                diag.update({kv.key: kv.value for kv in st.values})

    sub = node.create_subscription(Odometry, topic, on_output, 10000)
    tf_received = [0]
    if publish == "tf":  # a /tf listener, as on a robot: the node then broadcasts odom->base_link
        from ekf_localization.ros.tf_io import TF_QOS, TF_TOPIC, tf_message_class

        node.create_subscription(tf_message_class(), TF_TOPIC,
                                 lambda msg: tf_received.__setitem__(0, tf_received[0] + len(msg.transforms)),
                                 TF_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    proc = subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 60.0
        while sub.get_publisher_count() == 0 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        if sub.get_publisher_count() == 0:
            raise RuntimeError(f"{kind}: the node never came up")
        stamps_file = workdir / f"{kind}_stamps.npy"
        child = "no_such_frame" if publish == "rejected" else "base_link"  # unknown: every twist rejected
        pub = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(args.rate), str(args.duration), "1",
                                str(stamps_file), child],
                               env=env, stdout=subprocess.PIPE, text=True, start_new_session=True)
        pub.stdout.readline()  # publishing starts now
        cpu0, wall0 = cpu_seconds(proc.pid), time.monotonic()
        while not select.select([pub.stdout], [], [], 0)[0]:  # until it prints its summary
            ex.spin_once(timeout_sec=0.005)
        cpu1, wall1 = cpu_seconds(proc.pid), time.monotonic()
        end = json.loads(pub.stdout.readline())
        pub.wait(timeout=10)
        settle = time.monotonic() + 2.5  # late outputs and one more diagnostics message
        while time.monotonic() < settle:
            ex.spin_once(timeout_sec=0.01)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    sent = int(end["sent"])
    inputs = np.load(stamps_file)
    out = np.array(sorted(a for a in arrivals if inputs[0] <= a[0] <= inputs[-1]),
                   dtype=np.int64).reshape(-1, 3)
    # input i is out when the first output stamped at or after it is published (arrives)
    first = np.minimum.accumulate(out[::-1, 1:], axis=0)[::-1]
    j = np.searchsorted(out[:, 0], inputs, side="left")
    covered = j < len(out)
    lat, lat_arrival = ((first[j[covered], c] - inputs[covered]) / 1e6 for c in (0, 1))  # ms
    received = len(np.unique(out[:, 0])) if kind.startswith("relay") else int(diag.get("received", -1))
    if lat.size == 0:  # no output at all: say so rather than fail on empty percentiles
        lat = lat_arrival = np.array([math.nan])
    return {"kind": f"{kind}/{executor}" + (f"/{publish}" if publish else ""),
            "sent": sent, "received_by_node": received, "lost": sent - received,
            "outputs": len(out), "output_rate_hz": len(out) / args.duration,
            "latency_p50_ms": float(np.percentile(lat, 50)), "latency_p99_ms": float(np.percentile(lat, 99)),
            "latency_max_ms": float(np.max(lat)), "arrival_p99_ms": float(np.percentile(lat_arrival, 99)),
            "cpu_percent": 100.0 * (cpu1 - cpu0) / (wall1 - wall0), "tf_received": tf_received[0]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=10.0, help="seconds of publishing per trial")
    ap.add_argument("--rate", type=float, default=1000.0, help="odometry rate, Hz")
    ap.add_argument("--frequency", type=float, default=1000.0, help="ekf_node output frequency, Hz")
    ap.add_argument("--queue", type=int, default=100, help="ekf_node's odom0_queue_size (its QoS depth)")
    ap.add_argument("--executors", default="single,events", help="comma-separated: single, events")
    ap.add_argument("--publish", default="callback,timer",
                    help="comma-separated ekf_node publishing modes: callback, timer; rejected "
                         "(callback, with every twist in a frame the node does not know); tf "
                         "(callback, with publish_tf and a /tf listener)")
    ap.add_argument("--doc", action="store_true", help="write the result into docs/performance.md")
    args = ap.parse_args(argv)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random().randrange(101, 200)))
    executors = [e.strip() for e in args.executors.split(",") if e.strip()]
    modes = [m.strip() for m in args.publish.split(",") if m.strip()]
    results = []
    pairs = []
    with tempfile.TemporaryDirectory() as tmp:
        for executor in executors:
            relay = run("relay", executor, args, Path(tmp))
            results.append(relay)
            for mode in modes:
                results.append(run("ekf", executor, args, Path(tmp), mode))
                pairs.append((relay, results[-1]))
    load = " ".join(f"{v:.1f}" for v in os.getloadavg())
    lines = [f"odometry {args.rate:g} Hz for {args.duration:g} s from another process; "
             f"ekf_node timer {args.frequency:g} Hz (callback mode: 50 Hz), odom0_queue_size {args.queue}; "
             f"{os.cpu_count()} CPUs, "
             f"load average {load} at the end", ""]
    cols = ["sent", "received_by_node", "lost", "outputs", "output_rate_hz", "latency_p50_ms",
            "latency_p99_ms", "latency_max_ms", "arrival_p99_ms", "cpu_percent"]
    lines.append("| node/executor | " + " | ".join(cols) + " |")
    lines.append("|---" * (len(cols) + 1) + "|")
    for r in results:
        cells = [f"{r[c]:.3f}" if isinstance(r[c], float) else f"{r[c]:d}" for c in cols]
        lines.append(f"| {r['kind']} | " + " | ".join(cells) + " |")
    lines.append("")
    for relay, ekf in pairs:
        if ekf["kind"].endswith("/rejected"):  # nothing is published: loss and CPU only
            lines.append(f"- {ekf['kind']} / {relay['kind']}: "
                         f"CPU x{ekf['cpu_percent'] / max(relay['cpu_percent'], 1e-9):.2f}, "
                         f"{ekf['lost']} lost, {ekf['outputs']} published")
            continue
        ok = ekf["lost"] == 0 and ekf["latency_p99_ms"] < 2.0 and ekf["cpu_percent"] <= 25.0
        lines.append(f"- {ekf['kind']} / {relay['kind']}: "
                     f"latency p50 x{ekf['latency_p50_ms'] / relay['latency_p50_ms']:.2f}, "
                     f"p99 x{ekf['latency_p99_ms'] / relay['latency_p99_ms']:.2f}, "
                     f"CPU x{ekf['cpu_percent'] / max(relay['cpu_percent'], 1e-9):.2f}; "
                     f"target (0 lost, p99 < 2 ms, CPU <= 25 %): {'met' if ok else 'NOT met'}"
                     + (f"; {ekf['tf_received']} transforms on /tf" if ekf["kind"].endswith("/tf") else ""))
    text = "\n".join(lines)
    print(text)
    if args.doc:
        from perf_doc import write_section  # benchmarks/ is on sys.path when run as a script

        print(f"wrote {write_section('ekf_node', 'ekf_node at 1 kHz odometry (bench_ekf_node.py)', text)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
