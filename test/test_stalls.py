"""Stalls over real DDS: a stopped simulator catches up with wall time, the EKF never stays blind.

sim_node runs at real time (stamps = wall time, no /clock) with ekf_node, both from the
shipped config. SIGSTOP freezes the simulator for 2 s; after SIGCONT its stamps must be the
wall time again (ticks dropped, reported), so the EKF fuses its odometry again at once. An
input whose messages are all rejected for longer than sensor_timeout is an ERROR naming the
measured lag.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest
from helpers.ros_helpers import REPO, Diagnostics, node_command, running_process, wait_for_publishers

from ekf_localization.core.units import NS_PER_S as SEC

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def _node(executable: str, config: str) -> list[str]:
    return [*node_command(executable), "--ros-args", "--params-file", str(REPO / "config" / config)]


def test_stopped_simulator_catches_up_and_the_ekf_keeps_fusing(ros_context, tmp_path: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus

    diag = Diagnostics(ros_context)
    odom0, sim = "ekf_node: odom0", "sim_node: simulator"
    applied = lambda: int(diag.get(odom0, "applied", "0"))  # noqa: E731
    stale = lambda: int(diag.get(odom0, "rejected_stale_stamp", "0"))  # noqa: E731
    try:
        with running_process(_node("ekf_node", "ekf.yaml"), tmp_path / "ekf.log"), \
                running_process(_node("sim_node", "sim.yaml"), tmp_path / "sim.log") as sim_proc:
            assert wait_for_publishers(diag.executor, diag.sub, count=2, timeout=30.0)
            assert diag.spin_until(lambda: applied() > 200, 30.0), (tmp_path / "ekf.log").read_text()[-2000:]
            # no start-up lag: odom0 is fresh (not a sensor_timeout WARN) once running
            t_ok = time.monotonic()
            diag.spin_for(2.5)
            levels = [d["_level"] for t, n, d in diag.history if n == odom0 and t > t_ok]
            assert levels and all(lv == DiagnosticStatus.OK for lv in levels), \
                [d["_message"] for t, n, d in diag.history if n == odom0 and t > t_ok]
            os.kill(sim_proc.pid, signal.SIGSTOP)
            try:
                time.sleep(2.0)  # the simulator is frozen: nothing to spin for
            finally:
                os.kill(sim_proc.pid, signal.SIGCONT)
            t_resume = time.monotonic()
            assert diag.spin_until(lambda: "dropped" in diag.get(sim, "_message"), 5.0), diag.latest.get(sim)
            assert float(diag.get(sim, "dropped_s", "0")) >= 1.5
            assert abs(float(diag.get(sim, "stamp_lag_s", "9"))) < 0.2, diag.latest.get(sim)
            # the EKF fuses the simulator's odometry again, not 2 s stale stamps forever
            diag.spin_until(lambda: time.monotonic() - t_resume > 1.5, 3.0)
            applied_1, stale_1 = applied(), stale()
            diag.spin_for(2.5)
            assert applied() - applied_1 > 100, (applied_1, applied(), diag.latest.get(odom0))
            assert stale() - stale_1 < 10, (stale_1, stale())
            assert diag.latest[odom0]["_level"] != DiagnosticStatus.ERROR, diag.latest[odom0]
    finally:
        diag.close()


def test_input_with_every_message_rejected_is_an_error_naming_the_lag(ros_context, tmp_path: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data

    diag = Diagnostics(ros_context)
    pub = diag.node.create_publisher(Odometry, "odometry/dead_wheels", qos_profile_sensor_data)

    def send() -> None:  # dead-wheel odometry stamped 1.5 s in the past (max_measurement_age 1.0 s)
        msg = Odometry()
        t = diag.node.get_clock().now().nanoseconds - int(1.5 * SEC)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, SEC)
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        for i in (0, 7, 14, 21, 28, 35):
            msg.pose.covariance[i] = msg.twist.covariance[i] = 1e-4
        pub.publish(msg)

    timer = diag.node.create_timer(0.02, send)
    odom0 = "ekf_node: odom0"
    try:
        with running_process(_node("ekf_node", "ekf.yaml"), tmp_path / "ekf.log"):
            assert wait_for_publishers(diag.executor, diag.sub, timeout=30.0)
            assert diag.spin_until(lambda: diag.latest.get(odom0, {}).get("_level") == DiagnosticStatus.ERROR,
                                   10.0), diag.latest.get(odom0)
            message = diag.latest[odom0]["_message"]
            assert "every message rejected" in message and "stale_stamp" in message, message
            assert "lag the clock by 1.5" in message, message
            assert diag.latest[odom0]["last_stamp_lag_s"].startswith("1.5")
            assert diag.latest["ekf_node: filter"]["_level"] == DiagnosticStatus.ERROR
            assert diag.latest["ekf_node: imu0"]["last_stamp_age_s"] == "never"
    finally:
        timer.cancel()
        diag.close()
