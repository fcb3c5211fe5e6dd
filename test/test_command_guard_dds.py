"""The blocked and the frozen robot (issue 34) over real DDS with a real ekf_node on config/ekf.yaml.

This test process plays helpers/guard_scenario.py on simulated time (/clock every 10 ms, paced
at half real time): dead wheels, IMU, camera and cmd_vel, and it records /odometry/filtered and
/diagnostics. Bounds are the issue's: blocked, the estimate moves < 3 cm, 3σ covers the truth
and the cmd_vel status says "cmd_vel: not followed" (WARN) within 0.5 s; frozen, 3σ covers the
truth throughout and the error is < 10 cm 2 s after the sensors return.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.ekf_node_feeder import measurement_message
from helpers.guard_scenario import EVENT_S, RECOVER_S, SEC, T0, events, truth_at, truths
from helpers.localizer_scenario import START
from helpers.ros_helpers import REPO, node_command, running_process, spin_until, wait_for_subscribers

from ekf_localization.core.units import ns_to_sec_nanosec, stamp_to_ns
from ekf_localization.ros.params_match import section_for

pytestmark = [pytest.mark.ros, pytest.mark.slow]
PACE = 0.5  # simulated seconds per wall second: room for ekf_node on a loaded 2-core machine


def _params(tmp_path: Path) -> Path:
    base = dict(section_for(yaml.safe_load((REPO / "config" / "ekf.yaml").read_text()), "ekf_node"))
    base["use_sim_time"] = True
    base["initial_state"] = [START[0], START[1], 0.0, 0.0, 0.0, START[2]] + [0.0] * 9
    path = tmp_path / "ekf.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": base}}))
    return path


def play(name: str, ros_context, tmp_path: Path):
    """Run the scenario against ekf_node: (rows [t s, error, largest position std, x],
    cmd_vel statuses [(sim t s, level, message)])."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu

    node = Node("guard_test", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    pubs = {"odom0": node.create_publisher(Odometry, "odometry/dead_wheels", 100),
            "pose0": node.create_publisher(PoseWithCovarianceStamped, "camera/pose", 100),
            "imu0": node.create_publisher(Imu, "imu/data", 100),
            "cmd_vel": node.create_publisher(TwistStamped, "cmd_vel", 100)}
    clock = node.create_publisher(Clock, "/clock", 100)
    truth = truths(name)
    rows: list[tuple[float, float, float, float]] = []
    statuses: list[tuple[float, int, str]] = []
    sim_now = [0]

    def on_odom(msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        tr = truth_at(truth, t)
        p = msg.pose.pose.position
        cov = np.asarray(msg.pose.covariance).reshape(6, 6)[:2, :2]
        rows.append(((t - T0) / SEC, math.hypot(p.x - tr[0], p.y - tr[1]),
                     math.sqrt(max(np.linalg.eigvalsh(cov))), p.x))

    def on_diag(msg) -> None:
        for st in msg.status:
            if st.name.endswith(": cmd_vel"):
                statuses.append(((sim_now[0] - T0) / SEC, int.from_bytes(st.level, "little")
                                 if isinstance(st.level, bytes) else int(st.level), st.message))

    node.create_subscription(Odometry, "odometry/filtered", on_odom, 100)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)
    try:
        cmd = node_command("ekf_node") + ["--ros-args", "--params-file", str(_params(tmp_path))]
        with running_process(cmd, tmp_path / "ekf.log"):
            assert all(wait_for_subscribers(ex, p, timeout=30.0) for p in [clock, *pubs.values()]), \
                (tmp_path / "ekf.log").read_text()[-2000:]
            c = Clock()
            c.clock.sec, c.clock.nanosec = ns_to_sec_nanosec(T0 - 10_000_000)
            clock.publish(c)
            spin_until(ex, lambda: False, 0.5)  # the node has its clock
            start = time.monotonic()
            last = None
            for ev in events(name):
                if ev.now_ns != last:
                    last = ev.now_ns
                    sim_now[0] = last
                    c.clock.sec, c.clock.nanosec = ns_to_sec_nanosec(last)
                    clock.publish(c)
                    due = start + (last - T0) / SEC / PACE
                    while time.monotonic() < due:
                        ex.spin_once(timeout_sec=0.0005)
                m = ev.measurement
                pubs[ev.source].publish(measurement_message(ev.source, m, m.stamp_ns, imu_orientation=True))
            spin_until(ex, lambda: False, 0.3)
    finally:
        ex.shutdown()
        node.destroy_node()
    return np.array(rows), statuses


def between(rows: np.ndarray, a: float, b: float) -> np.ndarray:
    return rows[(rows[:, 0] >= a) & (rows[:, 0] < b)]


def test_blocked_robot_over_dds(ros_context, tmp_path: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus

    rows, statuses = play("blocked", ros_context, tmp_path)
    t0, t1 = EVENT_S["blocked"], RECOVER_S["blocked"]
    blocked = between(rows, t0, t1)
    assert len(blocked) > 20, len(blocked)  # 50 Hz, fewer on a loaded machine
    moved = abs(blocked[-1, 3] - blocked[0, 3])
    assert moved < 0.03, moved
    assert np.all(blocked[:, 1] <= 3 * blocked[:, 2]), blocked[blocked[:, 1] > 3 * blocked[:, 2]][:5]
    warn = [t for t, level, msg in statuses if level == DiagnosticStatus.WARN[0]
            and msg.startswith("cmd_vel: not followed")]
    assert warn and t0 <= warn[0] <= t0 + 0.5, statuses[:20]
    print(f"blocked: moved {moved * 100:.2f} cm, not followed at +{warn[0] - t0:.2f} s")


def test_frozen_robot_over_dds(ros_context, tmp_path: Path) -> None:
    rows, _ = play("frozen", ros_context, tmp_path)
    after_fix = rows[rows[:, 0] >= 1.0]
    assert len(between(rows, EVENT_S["frozen"], RECOVER_S["frozen"])) > 20
    worst = after_fix[np.argmax(after_fix[:, 1] - 3 * after_fix[:, 2])]
    assert np.all(after_fix[:, 1] <= 3 * after_fix[:, 2]), worst
    end = between(rows, RECOVER_S["frozen"] + 1.9, RECOVER_S["frozen"] + 2.0)
    assert len(end) and end[:, 1].max() < 0.10, end
    print(f"frozen: worst error - 3 sigma {worst[1] - 3 * worst[2]:.4f} m at {worst[0]:.2f} s, "
          f"error 2 s after the sensors return {end[:, 1].max() * 100:.2f} cm")
