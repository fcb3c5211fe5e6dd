"""ekf_node over real DDS: a publisher process feeds the scenario, the test checks the output.

Each test starts ekf_node (the console entry point) as a process, a feeder process
(helpers/ekf_node_feeder.py) publishing odometry, lagged camera poses, IMU, cmd_vel (and
/clock), and subscribes to odometry/filtered and /diagnostics itself.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from argparse import Namespace
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.ekf_node_feeder import scenario_for
from helpers.fusion_scenario import process_noise
from helpers.ros_helpers import (
    REPO,
    node_command,
    running_process,
    spin_until,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.angles import quaternion_to_yaw
from ekf_localization.core.linalg import is_positive_definite, is_symmetric
from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.ros.params_match import section_for

pytestmark = [pytest.mark.ros, pytest.mark.slow]
FEEDER = str(Path(__file__).resolve().parent / "helpers" / "ekf_node_feeder.py")


def params_file(tmp_path: Path, name: str, **overrides) -> Path:
    """config/ekf.yaml with the test scenario's process noise and ``overrides``, for any node name."""
    base = section_for(yaml.safe_load((REPO / "config" / "ekf.yaml").read_text()), "ekf_node")
    base["process_noise_covariance"] = process_noise()
    base["use_control"] = True  # the scenario exercises cmd_vel as the process input (seed 000)
    # its truth follows the command at once (no wheel limits): seed 000's model, not the drive's
    base["wheel_acceleration_limit"] = base["wheel_speed_limit"] = 0.0
    base["control_latency"] = 0.0  # and at its stamp
    base["control_velocity_variance"] = [2.9032e-4, 2.9032e-4, 0.0, 0.0, 0.0, 0.45]
    base["control_guard"] = False  # the feeder's dead wheels are biased by design (fusion_scenario.config)
    base.update(overrides)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": base}}))
    return path


def ekf_command(params: Path, name: str) -> list[str]:
    return node_command("ekf_node") + ["--ros-args", "--params-file", str(params), "-r", f"__node:={name}",
                                       "-r", f"odometry/filtered:={name}/odometry/filtered"]


def feeder_command(*args: str) -> list[str]:
    return [sys.executable, FEEDER, *args]


class Listener:
    """Collects a node's outputs and the diagnostics, in the test process."""

    def __init__(self, ros_context, names: list[str]) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.node = Node("ekf_test_listener", context=ros_context)
        self.executor = SingleThreadedExecutor(context=ros_context)
        self.executor.add_node(self.node)
        self.outputs: dict[str, list[tuple]] = {n: [] for n in names}
        self.diag: dict[str, dict[str, str]] = {}  # the latest status of each name
        self.diag_history: list[dict[str, dict[str, str]]] = []
        self.subs = {n: self.node.create_subscription(Odometry, f"{n}/odometry/filtered",
                                                      self._collector(n), 1000) for n in names}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)

    def _collector(self, name: str):
        def collect(msg) -> None:
            p = msg.pose.pose
            q = p.orientation
            yaw = quaternion_to_yaw(q.x, q.y, q.z, q.w)
            pc = np.asarray(msg.pose.covariance).reshape(6, 6)
            tc = np.asarray(msg.twist.covariance).reshape(6, 6)
            vals = [p.position.x, p.position.y, yaw, msg.twist.twist.linear.x, msg.twist.twist.linear.y,
                    msg.twist.twist.angular.z]
            finite = bool(np.all(np.isfinite(vals)) and np.all(np.isfinite(pc)) and np.all(np.isfinite(tc)))
            spd = finite and _is_spd(pc) and _is_spd(tc)
            stamp = msg.header.stamp.sec * SEC + msg.header.stamp.nanosec
            self.outputs[name].append((stamp, vals, finite, spd, msg.header.frame_id, msg.child_frame_id))
        return collect

    def _on_diag(self, msg) -> None:
        arr = {st.name: {kv.key: kv.value for kv in st.values} | {"_level": st.level, "_message": st.message}
               for st in msg.status}
        self.diag.update(arr)
        self.diag_history.append(arr)

    def fresh_diagnostics(self, timeout: float = 3.0) -> bool:
        """Wait for the next /diagnostics message (published once a second)."""
        n = len(self.diag_history)
        return self.spin_until(lambda: len(self.diag_history) > n, timeout)

    def settled_diagnostics(self, names: list[str], timeout: float = 10.0) -> bool:
        """Wait for two new successive /diagnostics messages that give the same ``received``
        count for each of ``names``: nothing more is arriving."""
        n0 = len(self.diag_history)

        def counts(arr: dict) -> list:
            return [arr.get(n, {}).get("received") for n in names]

        def settled() -> bool:
            h = self.diag_history[n0:]
            return len(h) >= 2 and None not in counts(h[-1]) and counts(h[-1]) == counts(h[-2])

        return self.spin_until(settled, timeout)

    def spin_until(self, predicate, timeout: float) -> bool:
        return spin_until(self.executor, predicate, timeout)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def _is_spd(C: np.ndarray) -> bool:
    return is_symmetric(C) and is_positive_definite(C)


def errors(outputs: list[tuple], scn, t_from: int, t_to: int) -> np.ndarray:
    """Position errors of the outputs stamped in [t_from, t_to) against the truth."""
    return np.array([math.hypot(v[0] - scn.truth_at(t)[0], v[1] - scn.truth_at(t)[1])
                     for t, v, *_ in outputs if t_from <= t < t_to])


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2)))


def test_tracks_truth_set_pose_reset_and_bag_loop(ros_context, tmp_path: Path) -> None:
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from std_srvs.srv import Empty

    args = Namespace(duration=4.0, seed=3, latency_ms=80, robot_speed=1.0)
    scn = scenario_for(args)
    t0 = int(scn.t_ns[0])
    params = params_file(tmp_path, "ekf", use_sim_time=True)
    lis = Listener(ros_context, ["ekf"])
    set_pose = lis.node.create_publisher(PoseWithCovarianceStamped, "set_pose", 10)
    reset = lis.node.create_client(Empty, "ekf/reset")  # the node ekf's ~/reset
    out = lis.outputs["ekf"]
    try:
        with running_process(ekf_command(params, "ekf"), tmp_path / "ekf.log") as ekf:
            assert wait_for_publishers(lis.executor, lis.subs["ekf"], timeout=20.0), "ekf_node never came up"
            assert wait_for_subscribers(lis.executor, set_pose, timeout=10.0)
            assert reset.wait_for_service(timeout_sec=10.0)
            with running_process(feeder_command("--mode", "track", "--duration", "4.0", "--loop-s", "1.0"),
                                 tmp_path / "feeder.log") as feeder:
                # 1. tracking
                assert lis.spin_until(lambda: out and out[-1][0] >= t0 + int(2.5 * SEC), 20.0), \
                    (tmp_path / "ekf.log").read_text()[-2000:]
                e = errors(out, scn, t0 + SEC, t0 + int(2.5 * SEC))
                assert len(e) > 50  # 50 Hz on simulated time
                assert rms(e) < 0.05, rms(e)
                assert out[-1][4:] == ("map", "base_link")
                # 2. set_pose moves the estimate (the camera's poses then fail the 5-sigma gate)
                truth = scn.truth_at(out[-1][0])
                target = (truth[0] + 2.0, truth[1] - 1.5, truth[2] + 1.0)
                msg = PoseWithCovarianceStamped()
                msg.header.frame_id = "map"  # zero stamp: now
                msg.pose.pose.position.x, msg.pose.pose.position.y = target[0], target[1]
                msg.pose.pose.orientation.z = math.sin(target[2] / 2)
                msg.pose.pose.orientation.w = math.cos(target[2] / 2)
                msg.pose.covariance = (np.eye(6) * 1e-4).ravel().tolist()
                n = len(out)
                set_pose.publish(msg)
                moved = lambda: any(math.hypot(v[0] - target[0], v[1] - target[1]) < 0.3  # noqa: E731
                                    for _, v, *_ in out[n:])
                assert lis.spin_until(moved, 5.0), "set_pose did not move the estimate"
                # the camera's next poses (2.5 m away, 5-sigma gate) are rejected, not fused
                t_moved = out[-1][0]
                assert lis.spin_until(lambda: out[-1][0] >= t_moved + int(0.3 * SEC), 5.0)
                assert math.hypot(out[-1][1][0] - target[0], out[-1][1][1] - target[1]) < 0.5
                # 3. reset: the filter starts again from initial_state and the camera pulls it back
                fut = reset.call_async(Empty.Request())
                assert lis.spin_until(fut.done, 5.0)
                reset_at = out[-1][0]
                assert lis.spin_until(lambda: out[-1][0] >= t0 + int(3.9 * SEC), 10.0)
                e_after = errors(out, scn, reset_at + int(0.6 * SEC), t0 + 4 * SEC)
                assert len(e_after) > 5 and e_after.max() < 0.15, e_after
                # 4. a bag loop: the clock jumps back 4 s, the node resets and tracks again
                looped = lambda: any(t < t0 + SEC for t, *_ in out[-20:])  # noqa: E731
                assert lis.spin_until(looped, 15.0)
                i_loop = next(i for i in range(1, len(out)) if out[i][0] < out[i - 1][0])
                # progress, not wall time: the node may lag on a loaded machine
                caught_up = lambda: out[-1][0] >= t0 + int(0.98 * SEC) and len(out) > i_loop + 5  # noqa: E731
                assert lis.spin_until(caught_up, 15.0)
                feeder.wait(timeout=20.0)
                assert feeder.returncode == 0, (tmp_path / "feeder.log").read_text()
                assert lis.fresh_diagnostics()
            assert ekf.poll() is None, "ekf_node died"
        loop_out = out[i_loop:]
        e_loop = errors(loop_out, scn, t0 + int(0.7 * SEC), t0 + SEC)
        assert len(e_loop) > 5 and e_loop.max() < 0.15, e_loop
        assert all(o[2] and o[3] for o in out), "non-finite or non-SPD output"
        filt = lis.diag["ekf: filter"]
        assert int(filt["resets"]) == 2, filt  # the reset service and the clock going backwards
        assert "backwards" in filt["last_reset_reason"]
        assert "time went backwards" in (tmp_path / "ekf.log").read_text()
        cam = lis.diag["ekf: pose0"]
        assert int(cam["applied"]) > 30 and int(cam["rejected_mahalanobis_gate"]) > 0  # gated after set_pose
        rates = [float(d["ekf: odom0"]["rate_hz"]) for d in lis.diag_history if "ekf: odom0" in d]
        # odometry at 200 Hz (simulated = wall time here): the rate the node took messages at, per
        # second; a node that lagged takes its backlog faster in the next second, so the median
        # of the seconds it was fed
        fed = [r for r in rates if r > 0.0]
        assert len(fed) >= 3 and 150.0 < float(np.median(fed)) < 250.0, rates
    finally:
        lis.close()


def test_delayed_landmark_with_history_beats_without(ros_context, tmp_path: Path, record_property) -> None:
    args = Namespace(duration=4.0, seed=5, latency_ms=150, robot_speed=1.5)
    scn = scenario_for(args)
    t0 = int(scn.t_ns[0])
    names = ["hist", "nohist"]
    files = {"hist": params_file(tmp_path, "hist", use_sim_time=True, smooth_lagged_data=True),
             "nohist": params_file(tmp_path, "nohist", use_sim_time=True, smooth_lagged_data=False)}
    lis = Listener(ros_context, names)
    try:
        with running_process(ekf_command(files["hist"], "hist"), tmp_path / "hist.log"), \
                running_process(ekf_command(files["nohist"], "nohist"), tmp_path / "nohist.log"):
            for n in names:
                assert wait_for_publishers(lis.executor, lis.subs[n], timeout=20.0), f"{n} never came up"
            with running_process(feeder_command("--mode", "lagged", "--duration", "4.0", "--seed", "5",
                                                "--latency-ms", "150", "--robot-speed", "1.5",
                                                "--subscribers", "2"), tmp_path / "feeder.log") as feeder:
                end = t0 + int(3.9 * SEC)
                assert lis.spin_until(lambda: all(lis.outputs[n] and lis.outputs[n][-1][0] >= end
                                                  for n in names), 25.0)
                feeder.wait(timeout=10.0)
                assert lis.fresh_diagnostics()
        r = {n: rms(errors(lis.outputs[n], scn, t0 + SEC, t0 + 4 * SEC)) for n in names}
        record_property("rms_with_history_m", float(r["hist"]))
        record_property("rms_without_history_m", float(r["nohist"]))
        print(f"\nlagged camera (150 ms): position RMS with history {r['hist']:.4f} m, "
              f"without {r['nohist']:.4f} m")
        # idle: 0.020-0.023 m with history against 0.173 m without (2026-12-06); a loaded CI run
        # reached 0.052 m with history. The claim is the ratio; the absolute bound is a sanity one
        counters = {k: lis.diag["hist: filter"].get(k) for k in ("rewinds", "dropped_overloaded")}
        assert r["hist"] < 0.5 * r["nohist"], (r, counters)
        assert r["hist"] < 0.08, (r, counters, lis.diag.get("hist: pose0"))
        assert int(lis.diag["hist: filter"]["rewinds"]) > 20
        assert int(lis.diag["nohist: pose0"]["applied_as_current"]) > 20
        for n in names:
            assert all(o[2] and o[3] for o in lis.outputs[n])
    finally:
        lis.close()


def test_poisoned_messages_are_rejected_counted_and_output_stays_finite(ros_context, tmp_path: Path) -> None:
    params = params_file(tmp_path, "ekf", use_sim_time=False)
    lis = Listener(ros_context, ["ekf"])
    out = lis.outputs["ekf"]
    try:
        with running_process(ekf_command(params, "ekf"), tmp_path / "ekf.log") as ekf:
            assert wait_for_publishers(lis.executor, lis.subs["ekf"], timeout=20.0)
            with running_process(feeder_command("--mode", "poison", "--duration", "2.0"),
                                 tmp_path / "feeder.log") as feeder:
                assert lis.spin_until(lambda: feeder.poll() is not None, 30.0)
            assert feeder.returncode == 0, (tmp_path / "feeder.log").read_text()
            report = json.loads((tmp_path / "feeder.log").read_text().strip().splitlines()[-1])
            sent, expected = report["sent"], report["expected_rejections"]
            # diagnostics published after everything arrived
            assert lis.settled_diagnostics([f"ekf: {s}" for s in ("odom0", "pose0", "imu0")])
            assert ekf.poll() is None, "ekf_node died"
        assert len(out) > 100 and all(o[2] and o[3] for o in out)
        for source in ("odom0", "pose0", "imu0"):
            d = lis.diag[f"ekf: {source}"]
            lost = sent[source] - int(d["received"])
            # best effort: a message published before the reader side matched can be lost
            assert 0 <= lost <= 0.1 * sent[source], (source, lost)
            for reason, n in expected[source].items():
                got = int(d[f"rejected_{reason}"])
                assert n - lost <= got <= n, (source, reason, got, n)
            assert int(d["applied"]) > 0
            assert d["_level"] == b"\x01"  # WARN: rejections in the last period
        assert sum(expected["odom0"].values()) > 50
        assert lis.diag["ekf: filter"]["predict_failures"] == "0"
    finally:
        lis.close()


def test_bad_parameter_file_exits_nonzero_naming_the_parameter(tmp_path: Path) -> None:
    bad = params_file(tmp_path, "bad", pose0_config=[True, True, False])
    res = subprocess.run(ekf_command(bad, "ekf"), capture_output=True, text=True, timeout=60, cwd=REPO)
    assert res.returncode == 2, res.stderr
    assert "parameter 'pose0_config': expected a list of 15 booleans" in res.stderr


def _start_at_origin(lis, pub, pose_pub, name: str) -> None:
    """Once ekf_node ``name`` listens to ``pub`` and ``pose_pub``: a set_pose at the origin, now,
    starts the filter; its first output arrives."""
    from geometry_msgs.msg import PoseWithCovarianceStamped

    assert wait_for_subscribers(lis.executor, pub, timeout=60.0)
    assert wait_for_subscribers(lis.executor, pose_pub, timeout=20.0)
    start = PoseWithCovarianceStamped()
    start.header.frame_id = "map"
    pose_pub.publish(start)
    assert lis.spin_until(lambda: len(lis.outputs[name]) > 0, 10.0)


def _three_wrong_wheel_counts_rejected(lis, pub, ekf, name: str) -> None:
    """Three wheel commands with 3 speeds: each rejected and counted; ekf_node keeps running, and
    the earlier (good) commands were applied."""
    from std_msgs.msg import Float64MultiArray

    bad = Float64MultiArray(data=[1.0, 2.0, 3.0])
    for _ in range(3):
        pub.publish(bad)
        lis.spin_until(lambda: False, 0.02)
    assert lis.spin_until(lambda: int(lis.diag.get(f"{name}: wheel_command", {}).get(
        "rejected_wrong_wheel_count", 0)) == 3, 5.0)
    assert ekf.poll() is None, "ekf_node died"
    d = lis.diag[f"{name}: wheel_command"]
    assert int(d["applied"]) >= 20 and int(d["rejected"]) == 3


def test_wheel_speed_commands_over_dds_drive_the_prediction_and_bad_ones_are_counted(
        ros_context, tmp_path: Path) -> None:
    """std_msgs/Float64MultiArray wheel speeds (wheel_order below) drive the velocity through
    the wheel-space drive response; a message without four speeds is rejected and counted."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from std_msgs.msg import Float64MultiArray

    params = params_file(tmp_path, "wheels", wheel_command_topic="wheel_commands",
                         wheel_order=["front_left", "front_right", "rear_left", "rear_right"],
                         control_timeout=1.0, wheel_acceleration_limit=60.0, wheel_speed_limit=32.67)
    lis = Listener(ros_context, ["wheels"])
    pub = lis.node.create_publisher(Float64MultiArray, "wheel_commands", 10)
    pose_pub = lis.node.create_publisher(PoseWithCovarianceStamped, "set_pose", 10)
    try:
        with running_process(ekf_command(params, "wheels"), tmp_path / "wheels.log") as ekf:
            _start_at_origin(lis, pub, pose_pub, "wheels")
            # strafe left (eq. 24: rear-left and front-right forward, the others back), 10 rad/s,
            # in this wheel_order [front_left, front_right, rear_left, rear_right]: vy = r·10
            strafe = Float64MultiArray(data=[-10.0, 10.0, 10.0, -10.0])
            for _ in range(25):  # 0.5 s at 50 Hz; the wheels reach 10 rad/s after 1/6 s (60 rad/s²)
                pub.publish(strafe)
                lis.spin_until(lambda: False, 0.02)
            n = len(lis.outputs["wheels"])
            assert lis.spin_until(lambda: len(lis.outputs["wheels"]) > n + 2, 2.0)
            last = lis.outputs["wheels"][-1][1]
            assert last[4] == pytest.approx(0.048 * 10.0, abs=1e-3) and abs(last[3]) < 1e-3, last
            _three_wrong_wheel_counts_rejected(lis, pub, ekf, "wheels")
    finally:
        lis.close()


def test_tank_wheel_speed_commands_over_dds_drive_the_tank_model(ros_context, tmp_path: Path) -> None:
    """model tank: two std_msgs/Float64MultiArray wheel speeds in wheel_order [right, left] drive
    v and ω through the tank's wheel-space drive response; three speeds are rejected and counted."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from std_msgs.msg import Float64MultiArray

    params = params_file(tmp_path, "tank", model="tank", wheel_command_topic="wheel_commands",
                         wheel_order=["right", "left"], half_track=0.2, control_timeout=1.0,
                         wheel_acceleration_limit=60.0, wheel_speed_limit=32.67)
    lis = Listener(ros_context, ["tank"])
    pub = lis.node.create_publisher(Float64MultiArray, "wheel_commands", 10)
    pose_pub = lis.node.create_publisher(PoseWithCovarianceStamped, "set_pose", 10)
    try:
        with running_process(ekf_command(params, "tank"), tmp_path / "tank.log") as ekf:
            _start_at_origin(lis, pub, pose_pub, "tank")
            turn = Float64MultiArray(data=[12.0, 4.0])  # right 12, left 4 rad/s: forward and CCW
            for _ in range(25):  # 0.5 s at 50 Hz; 12 rad/s is reached after 0.2 s (60 rad/s²)
                pub.publish(turn)
                lis.spin_until(lambda: False, 0.02)
            n = len(lis.outputs["tank"])
            assert lis.spin_until(lambda: len(lis.outputs["tank"]) > n + 2, 2.0)
            last = lis.outputs["tank"][-1][1]
            assert last[3] == pytest.approx(0.048 * (12.0 + 4.0) / 2, abs=1e-3), last
            assert last[5] == pytest.approx(0.048 * (12.0 - 4.0) / (2 * 0.2), abs=1e-3), last
            assert last[4] == 0.0  # a tank does not strafe
            _three_wrong_wheel_counts_rejected(lis, pub, ekf, "tank")
    finally:
        lis.close()
