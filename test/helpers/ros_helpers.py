"""Helpers for integration tests over real DDS: wait on matches, run nodes as processes."""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

# Unique per run (seeded from the OS), then one new domain per test that asks for one.
# Domain ids 1..100 keep Fast DDS's ports inside the valid range on Linux.
# EKF_TEST_DOMAINS=LO:HI (inclusive) confines a run to its own ids, so that parallel runs on
# one machine never share a domain. Under pytest-xdist each worker takes its own slice of that
# range (worker_domains), so two workers of one run never share a domain either.


def worker_domains(lo: int, hi: int, worker: str | None, count: str | None) -> tuple[int, int]:
    """The inclusive slice of ``lo..hi`` that xdist worker ``worker`` ("gwN") of ``count`` uses."""
    if not worker or not count:
        return lo, hi
    i, n = int(worker.removeprefix("gw")), int(count)
    size = (hi - lo + 1) // n
    if size < 1:
        raise ValueError(f"EKF_TEST_DOMAINS={lo}:{hi} has fewer ids than the {n} xdist workers")
    return lo + i * size, lo + (i + 1) * size - 1


_lo, _hi = worker_domains(*(int(v) for v in os.environ.get("EKF_TEST_DOMAINS", "1:100").split(":")),
                          os.environ.get("PYTEST_XDIST_WORKER"), os.environ.get("PYTEST_XDIST_WORKER_COUNT"))
_next_domain = [random.Random(os.getpid() ^ int.from_bytes(os.urandom(4), "little")).randrange(_lo, _hi + 1)]


def allocate_domain() -> int:
    """A ROS_DOMAIN_ID no other test of this run has used (until the range is used up)."""
    d = _next_domain[0]
    _next_domain[0] = _lo + (d - _lo + 1) % (_hi - _lo + 1)
    return d


def spin_until(executor, predicate: Callable[[], bool], timeout: float = 10.0,
               step: float = 0.02) -> bool:
    """Spin ``executor`` until ``predicate()`` is true or ``timeout`` seconds pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        executor.spin_once(timeout_sec=step)
    return predicate()


def wait_for_subscribers(executor, publisher, count: int = 1, timeout: float = 10.0) -> bool:
    """Wait until ``publisher`` has matched ``count`` subscriptions (DDS discovery)."""
    return spin_until(executor, lambda: publisher.get_subscription_count() >= count, timeout)


def wait_for_publishers(executor, subscription, count: int = 1, timeout: float = 10.0) -> bool:
    """Wait until ``subscription`` has matched ``count`` publishers (DDS discovery)."""
    return spin_until(executor, lambda: subscription.get_publisher_count() >= count, timeout)


def node_command(executable: str) -> list[str]:
    """The console entry point from the venv, or the module as a fallback."""
    exe = shutil.which(executable)
    if exe:
        return [exe]
    modules = {
        "ekf_node": "ekf_localization.nodes.ekf_node",
        "sim_node": "sim_robot.ros.sim_node",
        "pure_pursuit_node": "ekf_localization.nodes.pure_pursuit_node",
        "tag_localizer": "ekf_localization.nodes.tag_localizer_node",
        "nt_bridge": "ekf_localization.nodes.nt_bridge_node",
    }
    return [sys.executable, "-m", modules[executable]]


@contextmanager
def running_process(cmd: list[str], log_path: Path,
                    env: dict[str, str] | None = None) -> Iterator[subprocess.Popen]:
    """Run ``cmd`` with this test's environment; stop it (SIGINT, then SIGKILL) afterwards."""
    full_env = dict(os.environ)
    if env:
        full_env.update(env)
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=full_env,
                                cwd=str(REPO), start_new_session=True)
        try:
            yield proc
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait(timeout=5)


def twist_odometry(stamp_ns: int, vx: float):
    """nav_msgs/Odometry of base_link in odom at ``stamp_ns``: forward speed ``vx`` m/s with a
    1e-4 diagonal twist covariance, the pose at the origin."""
    from nav_msgs.msg import Odometry

    from ekf_localization.core.units import ns_to_sec_nanosec

    msg = Odometry()
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    msg.pose.pose.orientation.w = 1.0
    msg.twist.twist.linear.x = vx
    msg.twist.covariance = [1e-4 if i % 7 == 0 else 0.0 for i in range(36)]
    return msg



def fifo_allowed(priority: int) -> bool:
    """Whether a process of this user may run under SCHED_FIFO at ``priority`` (tried in a child)."""
    probe = f"import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({priority}))"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True).returncode == 0

class Diagnostics:
    """The latest /diagnostics status per name, and every one received, in the test process."""

    def __init__(self, ros_context) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.node = Node("diagnostics_listener", context=ros_context)
        self.executor = SingleThreadedExecutor(context=ros_context)
        self.executor.add_node(self.node)
        self.latest: dict[str, dict[str, str]] = {}
        self.history: list[tuple[float, str, dict[str, str]]] = []
        self.sub = self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on, 100)

    def _on(self, msg) -> None:
        for st in msg.status:
            d = {kv.key: kv.value for kv in st.values} | {"_level": st.level, "_message": st.message}
            self.latest[st.name] = d
            self.history.append((time.monotonic(), st.name, d))

    def get(self, name: str, key: str, default: str = "") -> str:
        return self.latest.get(name, {}).get(key, default)

    def spin_until(self, predicate, timeout: float) -> bool:
        return spin_until(self.executor, predicate, timeout)

    def spin_for(self, seconds: float) -> None:
        spin_until(self.executor, lambda: False, seconds)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
