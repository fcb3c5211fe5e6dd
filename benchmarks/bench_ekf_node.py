"""ekf_node as shipped, live over DDS: CPU, messages lost and latency, against an rclpy relay.

    python benchmarks/bench_ekf_node.py [--duration 60] [--odom-rate 100]
                                        [--trials relay,shipped,per_message] [--doc]

Three processes on this machine's DDS (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a private
ROS_DOMAIN_ID): a publisher, the node under test, and this script (the observer).

The stream: ``--duration`` s of the demo's simulated drive (``sim_robot.ros.sim_bag.
simulated_messages``, the world of config/sim.yaml): dead-wheel odometry at ``--odom-rate``
Hz (100, or 1000 for the 1 kHz mode), IMU at 100 Hz, camera landmark poses at 20 Hz stamped
at capture and published 50 ms later, TwistStamped cmd_vel at 50 Hz, and odom->base_link on
/tf at 100 Hz from the odometry's pose (as sim_node broadcasts it; ekf_node needs it to
publish map->odom). The camera's field of view is widened so that every capture sees an
image (the demo's 70 degrees see one in 1 capture of 8 on this drive): 20 Hz of fixes. The
publisher sends each message at its receive time in the drive, restamped to the wall clock
(the camera's 50 ms in the past), with sim_node's QoS (reliable, depth 50).

Trials (``--trials``), one after the other, each with a fresh node process:

* ``relay`` (the peer): a minimal rclpy node on ekf_node's executor
  (``ros.node_runner.make_executor``) that subscribes to the same topics with ekf_node's QoS
  and depths (config/ekf.yaml), listens to /tf, and republishes every input at once: what
  rclpy and DDS cost for this traffic before any filtering.
* ``shipped``: ``ekf_node --params-file config/ekf.yaml``, unchanged (50 Hz output,
  predict_to_current_time, publish_tf, diagnostics).
* ``per_message``: the same plus ``publish_on_measurement: true`` (each fused message is
  published from its own callback), for the per-message latency.
* ``filterpy`` (the floor): benchmarks/filterpy_node.py, a minimal EKF node on filterpy with
  the shipped process model that reads the fused fields, predicts and updates on each message
  and publishes the 50 Hz estimate, with none of ekf_node's checks, frames, lag handling or
  TF: what the filtering itself costs in a Python node.

Measured over the publishing window only (a priming handshake first proves that the node's
readers have matched, then the counters are read, then the stream starts):

* CPU % of one core: the node process's utime + stime (/proc/<pid>/stat) over the window.
* Lost: messages published minus messages the node received, per input. ekf_node's own
  counters (the ``received`` value of each input on /diagnostics) before and after; for the
  relay, its republished copies this script received (reliable, deep queue).
* Latency, "publish to the first output computed after it": from a message's publish (the
  publisher's wall clock just before ``publish``) to the DDS source timestamp of the first
  /odometry/filtered whose stamp (the node's clock when it computed that output:
  predict_to_current_time) is at or after that publish. With the shipped 50 Hz timer this
  includes the wait for the next tick (up to 20 ms, by design; the stream is on a 10 ms grid,
  so where in 0..20 ms its p50 lies depends on the timer's phase); ``per_message`` publishes from
  the message's own callback, so there it is the node's reaction time. (It counts an output
  computed while the message was still queued behind another as including it: it can
  understate by that backlog, which the loss and CPU figures would show.) For the relay: from
  publish to the source timestamp of the message's own republished copy.

Targets: shipped at 100 Hz odometry: CPU <= 10 % of one core, 0 lost; p99 latency < 5 ms
(per_message); at ``--odom-rate 1000``: 0 lost.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import pickle
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
# topic -> (ekf_node's input name, message type, ekf_node's QoS depth in config/ekf.yaml)
INPUTS = {"odometry/dead_wheels": ("odom0", "nav_msgs.msg.Odometry", 50),
          "imu/data": ("imu0", "sensor_msgs.msg.Imu", 50),
          "camera/pose": ("pose0", "geometry_msgs.msg.PoseWithCovarianceStamped", 10),
          "cmd_vel": ("cmd_vel", "geometry_msgs.msg.TwistStamped", 5)}  # qos_profile_sensor_data's depth
TOPICS = list(INPUTS)
TF_PERIOD_NS = 10_000_000  # odom->base_link at 100 Hz
TARGET_CPU, TARGET_P99_MS = 10.0, 5.0
TARGET_CPU_RATIO = 2.0  # ekf_node's CPU against the relay's

# The publisher. argv: stream pickle, output npz. Talks to this script by lines:
# -> {"matched"} | <- "stop" (after priming) -> {"primed"} | <- "go" -> {"start_ns"} ... {"sent"} | <- "exit"
PUBLISHER = r"""
import importlib, json, math, pickle, select, sys, time
import numpy as np, rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ekf_localization.ros.tf_io import TfBroadcaster

stream_path, out_path = sys.argv[1], sys.argv[2]
with open(stream_path, "rb") as f:
    # stream: [(topic index or -1 for /tf, offset ns, lag ns, message or (x, y, yaw))]
    topics, types, stream = pickle.load(f)
rclpy.init()
node = Node("bench_stream_publisher")
qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)  # sim_node's
pubs = []
for t, ty in zip(topics, types):
    mod, cls = ty.rsplit(".", 1)
    pubs.append(node.create_publisher(getattr(importlib.import_module(mod), cls), t, qos))
tf = TfBroadcaster(node)

def say(**kw):
    print(json.dumps(kw), flush=True)

def line_ready(timeout):
    return bool(select.select([sys.stdin], [], [], timeout)[0])

def restamp(msg, lag_ns):
    sec, nsec = divmod(time.time_ns() - lag_ns, 1_000_000_000)
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
    return sec * 1_000_000_000 + nsec

deadline = time.monotonic() + 60.0
while min(p.get_subscription_count() for p in pubs) < 1 and time.monotonic() < deadline:
    time.sleep(0.01)
say(matched=[p.get_subscription_count() for p in pubs])
first = {}
for k, lag, payload in ((k, lag, p) for k, _, lag, p in stream if k >= 0):
    first.setdefault(k, (lag, payload))
primed = [0] * len(pubs)
while not line_ready(0.1):  # prime: one message per topic every 100 ms until "stop"
    for k, (lag, msg) in first.items():
        restamp(msg, lag)
        pubs[k].publish(msg)
        primed[k] += 1
sys.stdin.readline()
say(primed=primed)
sys.stdin.readline()  # "go"
n = len(stream)
pub_ns = np.zeros(n, dtype=np.int64)
stamp_ns = np.zeros(n, dtype=np.int64)
start = time.time_ns()
say(start_ns=start)
t0 = time.perf_counter()
for i, (k, offset, lag, payload) in enumerate(stream):
    target = t0 + offset * 1e-9
    while True:
        d = target - time.perf_counter()
        if d <= 0:
            break
        if d > 2e-4:
            time.sleep(d - 1.5e-4)
    if k < 0:
        now = time.time_ns()
        tf.send_planar(now, "odom", "base_link", payload)
        pub_ns[i] = stamp_ns[i] = now
        continue
    stamp_ns[i] = restamp(payload, lag)
    pub_ns[i] = time.time_ns()
    pubs[k].publish(payload)
topic_ix = np.array([k for k, _, _, _ in stream], dtype=np.int64)
np.savez(out_path, pub_ns=pub_ns, stamp_ns=stamp_ns, topic=topic_ix)
sent = [int(np.sum(topic_ix == k)) for k in range(len(pubs))]
late_ms = (pub_ns - start - np.array([o for _, o, _, _ in stream])) / 1e6  # behind the schedule
say(sent=sent, late_ms_p99=float(np.percentile(late_ms, 99)), wall_s=time.perf_counter() - t0)
sys.stdin.readline()  # "exit"
"""

RELAY = r"""
import copy, importlib, json, sys
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from ekf_localization.ros.node_runner import make_executor, spin_forever
from ekf_localization.ros.tf_io import TF_QOS, TF_TOPIC, tf_message_class
inputs = json.loads(sys.argv[1])  # [[topic, type, depth]]
rclpy.init()
node = Node("bench_relay")
out_qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
for topic, ty, depth in inputs:
    mod, cls = ty.rsplit(".", 1)
    msg_type = getattr(importlib.import_module(mod), cls)
    pub = node.create_publisher(msg_type, "relay/" + topic, out_qos)
    qos = copy.copy(qos_profile_sensor_data)
    qos.depth = depth
    node.create_subscription(msg_type, topic, pub.publish, qos)
node.create_subscription(tf_message_class(), TF_TOPIC, lambda msg: None, TF_QOS)  # ekf_node listens too
ex = make_executor()
ex.add_node(node)
try:
    spin_forever(ex)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""


def message_type(dotted: str):
    import importlib

    mod, cls = dotted.rsplit(".", 1)
    return getattr(importlib.import_module(mod), cls)


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime + stime


def make_stream(duration_s: float, odom_rate: float) -> list[tuple[int, int, int, object]]:
    """(topic index or -1 for /tf, offset ns from the first message, stamp lag ns, message or
    (x, y, yaw) for /tf) of the simulated demo drive, in receive order."""
    from sim_robot.ros.sim_bag import demo_world_config, simulated_messages

    world = demo_world_config()
    world = dataclasses.replace(
        world, camera=dataclasses.replace(world.camera, field_of_view=math.radians(179.0), max_range=20.0),
        dead_wheels=dataclasses.replace(world.dead_wheels, period_ns=round(1e9 / odom_rate)))
    out = []
    t_first = None
    next_tf = 0
    for topic, recv_ns, msg in simulated_messages(duration_s, seed=0, world_config=world):
        topic = topic.lstrip("/")
        if topic not in INPUTS:
            continue  # ground truth
        t_first = recv_ns if t_first is None else t_first
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        out.append((TOPICS.index(topic), recv_ns - t_first, recv_ns - stamp, msg))
        if topic == "odometry/dead_wheels" and recv_ns - t_first >= next_tf:
            next_tf += TF_PERIOD_NS
            q = msg.pose.pose.orientation
            yaw = 2.0 * math.atan2(q.z, q.w)
            out.append((-1, recv_ns - t_first, 0, (msg.pose.pose.position.x, msg.pose.pose.position.y, yaw)))
    return out


def node_command(trial: str, workdir: Path, profile: bool = False) -> tuple[list[str], str]:
    """The node process of ``trial`` (under cProfile with ``profile``) and its output topic."""
    if trial == "relay":
        spec = json.dumps([[t, ty, depth] for t, (_, ty, depth) in INPUTS.items()])
        return [sys.executable, "-c", RELAY, spec], ""
    if trial == "filterpy":
        return [sys.executable, str(REPO / "benchmarks" / "filterpy_node.py")], "odometry/filtered"
    prof = ["-m", "cProfile", "-o", str(workdir / f"{trial}.prof")] if profile else []
    cmd = [sys.executable, *prof, "-m", "ekf_localization.nodes.ekf_node", "--ros-args",
           "--params-file", str(REPO / "config" / "ekf.yaml")]
    if trial == "per_message":
        extra = workdir / "per_message.yaml"
        params = {"/**/ekf_node": {"ros__parameters": {"publish_on_measurement": True}}}
        extra.write_text(yaml.safe_dump(params))
        cmd += ["--params-file", str(extra)]
    return cmd, "odometry/filtered"


class Observer:
    """This script's side: the node's outputs with their DDS source timestamps, its diagnostics."""

    def __init__(self, trial: str) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = Node("bench_observer", context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.outputs: list[tuple[int, int, int]] = []  # (topic index or -1, stamp ns, source timestamp ns)
        self.copies = [0] * len(TOPICS)
        self.diag: dict[str, int] = {}
        self.diag_messages = 0
        self.subs = []
        deep = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
        if trial == "relay":
            for k, (topic, (_, ty, _)) in enumerate(INPUTS.items()):
                self.subs.append(self.node.create_subscription(
                    message_type(ty), "relay/" + topic,
                    lambda msg, info, k=k: self._on_output(k, msg, info), deep))
        else:
            self.subs.append(self.node.create_subscription(
                Odometry, "odometry/filtered", lambda msg, info: self._on_output(-1, msg, info), deep))
            self.subs.append(self.node.create_subscription(DiagnosticArray, "/diagnostics",
                                                           self._on_diag, 10))

    def _on_output(self, k: int, msg, info) -> None:
        if k >= 0:
            self.copies[k] += 1
        self.outputs.append((k, msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                             info["source_timestamp"]))

    def _on_diag(self, msg) -> None:
        names = {name: topic for topic, (name, _, _) in INPUTS.items()}
        for st in msg.status:
            source = st.name.rsplit(": ", 1)[-1]
            if source in names:
                values = {kv.key: kv.value for kv in st.values}
                self.diag[names[source]] = int(values["received"])
        self.diag_messages += 1

    def received(self, trial: str) -> list[int]:
        """What the node has received per topic so far."""
        if trial == "relay":
            return list(self.copies)
        return [self.diag.get(t, 0) for t in TOPICS]

    def spin_until(self, done, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not done():
            if time.monotonic() > deadline:
                raise RuntimeError(f"timed out waiting for {what}")
            self.ex.spin_once(timeout_sec=0.01)

    def settle(self, trial: str) -> None:
        """Until the node's counts are final: two more diagnostics (ekf_node publishes them once a
        second), or for the relay no new copy for 0.5 s."""
        if trial == "relay":
            last, quiet = -1, time.monotonic()
            while time.monotonic() - quiet < 0.5:
                if len(self.outputs) != last:
                    last, quiet = len(self.outputs), time.monotonic()
                self.ex.spin_once(timeout_sec=0.01)
        else:
            n = self.diag_messages
            self.spin_until(lambda: self.diag_messages >= n + 2, 10.0, "diagnostics")

    def close(self) -> None:
        import rclpy

        self.ex.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


def read_json(proc: subprocess.Popen, obs: Observer, key: str, timeout: float = 120.0) -> dict:
    """The publisher's next line (a JSON object with ``key``), spinning the observer meanwhile."""
    deadline = time.monotonic() + timeout
    while not select.select([proc.stdout], [], [], 0)[0]:
        if time.monotonic() > deadline or proc.poll() is not None:
            raise RuntimeError(f"the publisher did not say {key!r}")
        obs.ex.spin_once(timeout_sec=0.005)
    out = json.loads(proc.stdout.readline())
    if key not in out:
        raise RuntimeError(f"the publisher said {out}, expected {key!r}")
    return out


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def run(trial: str, stream_file: Path, workdir: Path, profile: bool = False) -> dict:
    """One trial: the node under test, the publisher, measured."""
    cmd, _ = node_command(trial, workdir, profile)
    obs = Observer(trial)
    logs = REPO / "output" / "bench_ekf_node"  # the node's log of the last run, kept
    logs.mkdir(parents=True, exist_ok=True)
    log = (logs / f"{trial}.log").open("w")
    node = subprocess.Popen(cmd, cwd=REPO, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    pub = None
    try:
        if trial == "relay":
            obs.spin_until(lambda: min(s.get_publisher_count() for s in obs.subs) > 0, 60.0, "the relay")
        else:
            obs.spin_until(lambda: all(s.get_publisher_count() > 0 for s in obs.subs), 60.0, "ekf_node")
        npz = workdir / f"{trial}.npz"
        pub = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(stream_file), str(npz)],
                               cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                               start_new_session=True)
        read_json(pub, obs, "matched")
        # prime until the node has received on every input: its readers have matched the publisher
        obs.spin_until(lambda: min(obs.received(trial)) > 0, 60.0, "the node to receive every input")
        pub.stdin.write("stop\n")
        pub.stdin.flush()
        read_json(pub, obs, "primed")
        obs.settle(trial)
        before = obs.received(trial)
        n_before = len(obs.outputs)
        pub.stdin.write("go\n")
        pub.stdin.flush()
        read_json(pub, obs, "start_ns")
        cpu0, wall0 = cpu_seconds(node.pid), time.monotonic()
        end = read_json(pub, obs, "sent", timeout=1e6)
        cpu1, wall1 = cpu_seconds(node.pid), time.monotonic()
        obs.settle(trial)
        after = obs.received(trial)
        pub.stdin.write("exit\n")
        pub.stdin.flush()
        pub.wait(timeout=10)
    finally:
        if pub is not None:
            stop(pub)
        stop(node)
        log.close()
        outputs = obs.outputs
        obs.close()
    data = np.load(npz)
    sent = end["sent"]
    received = [a - b for a, b in zip(after, before, strict=True)]
    out = np.array(outputs[n_before:], dtype=np.int64).reshape(-1, 3)  # from the window on
    is_input = data["topic"] >= 0
    pub_ns = data["pub_ns"][is_input]
    if trial == "relay":  # each message's own copy, by topic and stamp
        lat = []
        for k in range(len(TOPICS)):
            mine = data["topic"] == k
            copies = out[out[:, 0] == k]
            pos = {s: ts for _, s, ts in copies}
            lat += [pos[s] - p for s, p in zip(data["stamp_ns"][mine], data["pub_ns"][mine], strict=True)
                    if s in pos]
        lat = np.asarray(lat, dtype=np.int64)
    else:  # the first output computed (stamped) at or after the publish
        out = out[np.argsort(out[:, 1], kind="stable")]
        first_pub = np.minimum.accumulate(out[::-1, 2])[::-1]
        j = np.searchsorted(out[:, 1], pub_ns, side="left")
        lat = first_pub[j[j < len(out)]] - pub_ns[j < len(out)]
    lat_ms = lat / 1e6 if lat.size else np.array([math.nan])
    return {"trial": trial, "sent": sent, "received": received, "lost": sum(sent) - sum(received),
            "outputs": int(np.sum(out[:, 0] < 0)) if trial != "relay" else len(out),
            "p50_ms": float(np.percentile(lat_ms, 50)), "p99_ms": float(np.percentile(lat_ms, 99)),
            "max_ms": float(np.max(lat_ms)), "cpu_percent": 100.0 * (cpu1 - cpu0) / (wall1 - wall0),
            "window_s": wall1 - wall0, "publisher_late_p99_ms": end["late_ms_p99"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of publishing per trial")
    ap.add_argument("--odom-rate", type=float, default=100.0, help="odometry rate, Hz (100 or 1000)")
    ap.add_argument("--trials", default="relay,shipped,per_message",
                    help="comma-separated: relay (the peer), shipped, per_message, filterpy (the floor)")
    ap.add_argument("--profile", action="store_true",
                    help="run ekf_node under cProfile and print it (then its CPU is not the shipped figure)")
    ap.add_argument("--doc", action="store_true", help="write the figures into docs/performance.md")
    args = ap.parse_args(argv)
    if args.profile and args.doc:
        ap.error("--profile slows the node: no --doc with it")
    trials = [t.strip() for t in args.trials.split(",") if t.strip()]
    if not set(trials) <= {"relay", "shipped", "per_message", "filterpy"}:
        ap.error("--trials: relay, shipped, per_message, filterpy")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    if "ROS_DOMAIN_ID" not in os.environ:
        lo, hi = (int(v) for v in os.environ.get("EKF_TEST_DOMAINS", "11:25").split(":"))
        os.environ["ROS_DOMAIN_ID"] = str(random.Random().randint(lo, hi))
    t0 = time.perf_counter()
    stream = make_stream(args.duration, args.odom_rate)
    print(f"stream: {args.duration:g} s, " + ", ".join(
        f"{sum(1 for k, *_ in stream if k == i)} {t}" for i, t in enumerate(TOPICS))
        + f", {sum(1 for k, *_ in stream if k < 0)} /tf (simulated in {time.perf_counter() - t0:.0f} s); "
        f"ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}", flush=True)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        stream_file = Path(tmp) / "stream.pkl"
        with stream_file.open("wb") as f:
            pickle.dump((TOPICS, [ty for _, ty, _ in INPUTS.values()], stream), f)
        for trial in trials:
            results[trial] = r = run(trial, stream_file, Path(tmp), args.profile)
            print(f"{trial}: {json.dumps(r)}", flush=True)
            if args.profile and trial != "relay":
                import pstats

                stats = pstats.Stats(str(Path(tmp) / f"{trial}.prof"))
                stats.sort_stats("tottime").print_stats(30)
                stats.sort_stats("cumulative").print_stats(60)
    load = " ".join(f"{v:.1f}" for v in os.getloadavg())
    rate = f"{args.odom_rate:g} Hz odometry"
    print(f"\n{rate}, IMU 100 Hz, camera 20 Hz (50 ms late), cmd_vel 50 Hz, /tf 100 Hz; "
          f"{args.duration:g} s per trial; {os.cpu_count()} CPUs, load average {load}")
    print(f"{'trial':<13}{'sent':>8}{'lost':>6}{'outputs':>9}{'CPU %':>8}{'p50 ms':>9}{'p99 ms':>9}"
          f"{'max ms':>9}{'pub late p99':>14}")
    for r in results.values():
        print(f"{r['trial']:<13}{sum(r['sent']):>8}{r['lost']:>6}{r['outputs']:>9}{r['cpu_percent']:>8.1f}"
              f"{r['p50_ms']:>9.2f}{r['p99_ms']:>9.2f}{r['max_ms']:>9.2f}{r['publisher_late_p99_ms']:>14.2f}")
    relay, shipped, per, floor = (results.get(k) for k in ("relay", "shipped", "per_message", "filterpy"))
    verdicts = []

    def verdict(text: str, ok: bool) -> None:
        verdicts.append(ok)
        print(f"{text}: {'met' if ok else 'NOT met'}")

    if shipped is not None:
        if args.odom_rate <= 100:
            verdict(f"shipped CPU {shipped['cpu_percent']:.1f} % of one core <= {TARGET_CPU:g} %"
                    + (f" (relay {relay['cpu_percent']:.1f} %)" if relay else ""),
                    shipped["cpu_percent"] <= TARGET_CPU)
        verdict(f"shipped lost {shipped['lost']} of {sum(shipped['sent'])} = 0"
                + (f" (relay {relay['lost']})" if relay else ""), shipped["lost"] == 0)
        if relay is not None:
            ratio = shipped["cpu_percent"] / relay["cpu_percent"]
            verdict(f"shipped CPU {ratio:.2f}x the relay's <= {TARGET_CPU_RATIO:g}x",
                    ratio <= TARGET_CPU_RATIO)
    if floor is not None and relay is not None:
        print(f"filterpy floor: CPU {floor['cpu_percent']:.1f} % = "
              f"{floor['cpu_percent'] / relay['cpu_percent']:.2f}x the relay's, lost {floor['lost']}"
              + (f"; shipped = {shipped['cpu_percent'] / floor['cpu_percent']:.2f}x the floor"
                 if shipped else ""))
    if per is not None and args.odom_rate <= 100:
        verdict(f"per_message latency p99 {per['p99_ms']:.2f} ms < {TARGET_P99_MS:g} ms"
                + (f" (relay {relay['p99_ms']:.2f} ms)" if relay else ""), per["p99_ms"] < TARGET_P99_MS)
    if args.doc:
        from perf_doc import write_row  # benchmarks/ is on sys.path when run as a script

        short = "" if args.duration >= 60 else f" ({args.duration:g} s run)"
        mode = f"ekf_node live, {'1 kHz' if args.odom_rate >= 1000 else '100 Hz'} odometry"
        peer = "rclpy relay of the same topics: " if relay else "no relay trial"
        if shipped is not None:
            if relay:
                peer_cpu = f"{peer}{relay['cpu_percent']:.1f} %"
                peer_lost = f"{peer}{relay['lost']} of {sum(relay['sent'])} lost"
            else:
                peer_cpu = peer_lost = peer
            write_row(f"{mode}: CPU % of one core (shipped config)",
                      f"{shipped['cpu_percent']:.1f} %{short}", peer_cpu)
            write_row(f"{mode}: messages lost (shipped config)",
                      f"{shipped['lost']} of {sum(shipped['sent'])}{short}", peer_lost)
            write_row(f"{mode}: publish to next 50 Hz output (shipped config)",
                      f"p50 {shipped['p50_ms']:.1f} ms, p99 {shipped['p99_ms']:.1f} ms{short}",
                      f"{peer}p50 {relay['p50_ms']:.2f} ms, p99 {relay['p99_ms']:.2f} ms" if relay else peer)
        if floor is not None:
            write_row(f"{mode}: CPU % of one core, minimal filterpy node (the floor)",
                      f"{floor['cpu_percent']:.1f} %, {floor['lost']} lost{short}",
                      f"{peer}{relay['cpu_percent']:.1f} %" if relay else peer)
        if per is not None:
            write_row(f"{mode}: publish to output, publish_on_measurement",
                      f"p50 {per['p50_ms']:.2f} ms, p99 {per['p99_ms']:.2f} ms, "
                      f"CPU {per['cpu_percent']:.1f} %{short}",
                      f"{peer}p50 {relay['p50_ms']:.2f} ms, p99 {relay['p99_ms']:.2f} ms" if relay else peer)
        print(f"wrote {REPO / 'docs' / 'performance.md'}")
    return 0  # it measures: the verdicts are printed


if __name__ == "__main__":
    sys.exit(main())
