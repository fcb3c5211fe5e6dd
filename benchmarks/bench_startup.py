"""sim_node + ekf_node from start to the first /odometry/filtered, with no cache of any kind.

    python benchmarks/bench_startup.py [--repeats 3] [--doc]

Each repeat starts ``sim_node --params-file config/sim.yaml`` and ``ekf_node --params-file
config/ekf.yaml`` as processes (``python -m``, as ``ros2 run`` does) and times, from just
before the first is started, until this script (the observer, up and subscribed before they
start) receives the first /odometry/filtered. No cache: ``PYTHONDONTWRITEBYTECODE=1`` and
``PYTHONPYCACHEPREFIX`` set to an empty directory, so every module, numpy's and rclpy's
included, is compiled from source at every start and nothing is written. Also printed: the
CPU seconds both processes had used by then (/proc), the figure a busy machine does not
stretch. The peer, started the same way in the same run: a bare rclpy node that publishes a
nav_msgs/Odometry every 20 ms, timed to its first message here (what any Python ROS node
pays: interpreter, rclpy, DDS discovery). Target: <= 3 s.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CLK_TCK = os.sysconf("SC_CLK_TCK")
TARGET_S = 3.0
PEER = r"""
import rclpy
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException
rclpy.init()
node = rclpy.create_node("bench_startup_peer")
pub = node.create_publisher(Odometry, "bench_startup/peer", 10)
node.create_timer(0.02, lambda: pub.publish(Odometry()))
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""


def cpu_seconds(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except FileNotFoundError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime + stime


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def time_to_first(observer, topic: str, cmds: list[list[str]], env: dict[str, str],
                  timeout: float = 60.0) -> tuple[float, float]:
    """(seconds from starting ``cmds`` to the first message on ``topic`` here, CPU seconds the
    processes had used by then); the processes are then stopped."""
    from nav_msgs.msg import Odometry

    node, ex = observer
    got: list[float] = []
    sub = node.create_subscription(Odometry, topic, lambda _msg: got or got.append(time.perf_counter()), 10)
    procs: list[subprocess.Popen] = []
    try:
        t0 = time.perf_counter()
        for cmd in cmds:
            procs.append(subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL, start_new_session=True))
        while not got:
            if time.perf_counter() - t0 > timeout or any(p.poll() is not None for p in procs):
                raise RuntimeError(f"no message on {topic} from {cmds}")
            ex.spin_once(timeout_sec=0.002)
        cpu = sum(cpu_seconds(p.pid) for p in procs)
        return got[0] - t0, cpu
    finally:
        stop(procs)
        node.destroy_subscription(sub)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--doc", action="store_true", help="write the figure into docs/performance.md")
    args = ap.parse_args(argv)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    if "ROS_DOMAIN_ID" not in os.environ:
        lo, hi = (int(v) for v in os.environ.get("EKF_TEST_DOMAINS", "11:25").split(":"))
        os.environ["ROS_DOMAIN_ID"] = str(random.Random().randint(lo, hi))
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    rclpy.init()
    node = rclpy.create_node("bench_startup_observer")
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    sim = [sys.executable, "-m", "sim_robot.ros.sim_node", "--ros-args",
           "--params-file", str(REPO / "config" / "sim.yaml")]
    ekf = [sys.executable, "-m", "ekf_localization.nodes.ekf_node", "--ros-args",
           "--params-file", str(REPO / "config" / "ekf.yaml")]
    peer = [sys.executable, "-c", PEER]
    ours: list[tuple[float, float]] = []
    floor: list[tuple[float, float]] = []
    try:
        for _ in range(args.repeats):
            for cmds, out, topic in (([peer], floor, "bench_startup/peer"),
                                     ([sim, ekf], ours, "odometry/filtered")):
                with tempfile.TemporaryDirectory() as empty:  # a fresh, empty bytecode cache each start
                    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", PYTHONPYCACHEPREFIX=empty)
                    out.append(time_to_first((node, ex), topic, cmds, env))
                    if any(Path(empty).iterdir()):
                        raise RuntimeError("something wrote a bytecode cache")
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown()
    load = " ".join(f"{v:.1f}" for v in os.getloadavg())
    numba = "importable" if importlib.util.find_spec("numba") else "not installed"
    print(f"{args.repeats} repeats, no bytecode cache; numba {numba}; {os.cpu_count()} CPUs, "
          f"load average {load}")
    print(f"{'case':<48}{'to first message, s':>22}{'CPU s by then':>16}")
    for name, rows in (("sim_node + ekf_node -> /odometry/filtered", ours),
                       ("peer: bare rclpy publisher -> its first message", floor)):
        for s, cpu in rows:
            print(f"{name:<48}{s:>22.2f}{cpu:>16.2f}")
    med = statistics.median(s for s, _ in ours)
    med_cpu = statistics.median(c for _, c in ours)
    peer_med = statistics.median(s for s, _ in floor)
    peer_cpu = statistics.median(c for _, c in floor)
    print(f"median: sim + ekf {med:.2f} s ({med_cpu:.2f} CPU s), "
          f"peer {peer_med:.2f} s ({peer_cpu:.2f} CPU s); "
          f"target <= {TARGET_S:g} s: {'met' if med <= TARGET_S else 'NOT met'}")
    if args.doc:
        sys.path.insert(0, str(REPO / "benchmarks"))
        from perf_doc import write_row

        write_row("sim_node + ekf_node start to first /odometry/filtered, no cache",
                  f"median {med:.2f} s of {args.repeats} ({med_cpu:.2f} CPU s); numba {numba}",
                  f"bare rclpy publisher to its first message: {peer_med:.2f} s ({peer_cpu:.2f} CPU s)")
        print(f"wrote {REPO / 'docs' / 'performance.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
