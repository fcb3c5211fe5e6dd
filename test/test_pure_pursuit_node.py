"""pure_pursuit_node as a process over real DDS: the test is the robot (odometry in, cmd_vel out)."""

from __future__ import annotations

import math
import subprocess
import sys
import time

import pytest
from helpers.ros_helpers import (
    node_command,
    running_process,
    spin_until,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.units import NS_PER_S, ns_to_sec_nanosec, stamp_to_ns

pytestmark = pytest.mark.ros

SHORT_PATH = "frame_id: map\nwaypoints:\n  - [0.0, 0.0]\n  - [0.6, 0.0]\n"


def _odometry(node, x: float, y: float, yaw: float, frame: str = "map", stamp_ns: int | None = None):
    from nav_msgs.msg import Odometry

    msg = Odometry()
    if stamp_ns is None:
        msg.header.stamp = node.get_clock().now().to_msg()
    else:
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    msg.header.frame_id = frame
    msg.child_frame_id = "base_link"
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    for i in (0, 7, 35):
        msg.pose.covariance[i] = 1e-4
    return msg


class FakeRobot:
    """A perfect holonomic robot in the test process: integrates the last cmd_vel, publishes odometry.

    With ``sim_time_ns`` it also owns the clock: every 20 ms of wall time it advances sim time
    by 20 ms, publishes /clock and stamps the odometry with it.
    """

    def __init__(self, node, odom_topic: str = "odometry/filtered", sim_time_ns: int | None = None) -> None:
        from geometry_msgs.msg import PointStamped, TwistStamped
        from nav_msgs.msg import Odometry
        from nav_msgs.msg import Path as PathMsg
        from rclpy.qos import DurabilityPolicy, QoSProfile
        from rosgraph_msgs.msg import Clock
        from std_msgs.msg import Bool, Float64

        self.node = node
        self.pose = [0.0, 0.0, 0.0]
        self.cmd = (0.0, 0.0, 0.0)
        self.cmds: list[tuple[float, float, float]] = []
        self.targets: list = []
        self.progress: list[float] = []
        self.cmd_stamps: list[int] = []
        self.done: list[bool] = []
        self.paths: list = []
        self.publishing = True
        self.fixed_stamp_ns: int | None = None  # stamp every odometry message with this (a stuck source)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub = node.create_publisher(Odometry, odom_topic, 10)
        self.sim_time_ns = sim_time_ns
        self.clock_pub = node.create_publisher(Clock, "/clock", 10) if sim_time_ns is not None else None
        self.subs = [
            node.create_subscription(TwistStamped, "cmd_vel", self._on_cmd, 50),
            node.create_subscription(PointStamped, "pure_pursuit/target", self.targets.append, 50),
            node.create_subscription(Float64, "pure_pursuit/progress",
                                     lambda m: self.progress.append(m.data), 50),
            node.create_subscription(Bool, "pure_pursuit/done", lambda m: self.done.append(m.data), latched),
            node.create_subscription(PathMsg, "pure_pursuit/path", self.paths.append, latched),
        ]
        self._last = time.monotonic()
        node.create_timer(0.02, self._tick)

    def _on_cmd(self, msg) -> None:
        assert msg.header.frame_id == "base_link"  # config/pure_pursuit.yaml: stamped_cmd_vel
        self.cmd_stamps.append(stamp_to_ns(msg.header.stamp))
        t = msg.twist
        self.cmd = (t.linear.x, t.linear.y, t.angular.z)
        self.cmds.append(self.cmd)

    def _tick(self) -> None:
        now = time.monotonic()
        dt, self._last = now - self._last, now
        stamp = None
        if self.sim_time_ns is not None:
            from rosgraph_msgs.msg import Clock

            dt = 0.02
            self.sim_time_ns += 20_000_000
            stamp = self.sim_time_ns
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = ns_to_sec_nanosec(stamp)
            self.clock_pub.publish(clock)
        vx, vy, wz = self.cmd
        c, s = math.cos(self.pose[2]), math.sin(self.pose[2])
        self.pose[0] += (vx * c - vy * s) * dt
        self.pose[1] += (vx * s + vy * c) * dt
        self.pose[2] += wz * dt
        if self.fixed_stamp_ns is not None:
            stamp = self.fixed_stamp_ns
        if self.publishing:
            self.pub.publish(_odometry(self.node, *self.pose, stamp_ns=stamp))


@pytest.fixture
def ros_node(ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    node = Node("pure_pursuit_test", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    yield node, ex
    ex.shutdown()
    node.destroy_node()


def _xy(path_msg) -> list[tuple[float, float]]:
    return [(p.pose.position.x, p.pose.position.y) for p in path_msg.poses]


def _start(tmp_path, extra: list[str]):
    path_file = tmp_path / "short.yaml"
    path_file.write_text(SHORT_PATH)
    cmd = [*node_command("pure_pursuit_node"), "--ros-args", "--params-file", "config/pure_pursuit.yaml",
           "-p", f"path_file:={path_file}", "-p", "odom_timeout:=0.5", *extra]
    return running_process(cmd, tmp_path / "pure_pursuit_node.log")


def _wait_connected(ex, robot: FakeRobot) -> None:
    assert wait_for_subscribers(ex, robot.pub, timeout=20.0), "node never subscribed to odometry"
    for sub in robot.subs:
        assert wait_for_publishers(ex, sub, timeout=20.0), f"no publisher on {sub.topic_name}"


def test_follows_a_short_path_and_reports_done(ros_node, tmp_path):

    node, ex = ros_node
    robot = FakeRobot(node)
    with _start(tmp_path, []) as proc:
        _wait_connected(ex, robot)
        # the latched topics: the path as loaded, not done
        assert spin_until(ex, lambda: robot.paths and robot.done, timeout=10.0)
        assert _xy(robot.paths[-1]) == [(0.0, 0.0), (0.6, 0.0)]
        assert robot.paths[-1].header.frame_id == "map" and robot.done[-1] is False
        assert spin_until(ex, lambda: robot.done[-1], timeout=20.0), (
            f"not done; pose {robot.pose}, log:\n{(tmp_path / 'pure_pursuit_node.log').read_text()}")
        # done: a zero twist, and it stays zero
        assert spin_until(ex, lambda: robot.cmd == (0.0, 0.0, 0.0), timeout=2.0)
        n = len(robot.cmds)
        assert spin_until(ex, lambda: len(robot.cmds) > n + 5, timeout=5.0)
        assert all(c == (0.0, 0.0, 0.0) for c in robot.cmds[n:])
        assert proc.poll() is None
    moving = [c for c in robot.cmds if abs(c[0]) > 1e-6]
    assert moving and all(c[0] > 0.0 for c in moving)  # towards the target, which is ahead (+x)
    assert max(c[0] for c in moving) <= 1.0 + 1e-9
    assert robot.targets and all(t.header.frame_id == "map" and 0.0 <= t.point.x <= 0.6 + 1e-9
                                 for t in robot.targets)
    assert robot.targets[0].point.x == pytest.approx(0.3, abs=0.02)  # lookahead 0.3 m ahead of the start
    assert len(robot.progress) > 1 and all(b >= a for a, b in zip(robot.progress, robot.progress[1:],
                                                                    strict=False))
    assert robot.progress[-1] == pytest.approx(0.6)
    assert math.hypot(robot.pose[0] - 0.6, robot.pose[1]) < 0.03


def test_runs_on_sim_time(ros_node, tmp_path):
    """use_sim_time: the control timer and the staleness check follow /clock (here 1000 s on)."""
    node, ex = ros_node
    robot = FakeRobot(node, sim_time_ns=1000 * NS_PER_S)
    with _start(tmp_path, ["-p", "use_sim_time:=true"]):
        _wait_connected(ex, robot)
        assert wait_for_subscribers(ex, robot.clock_pub, timeout=20.0)
        assert spin_until(ex, lambda: robot.done and robot.done[-1], timeout=20.0), robot.pose
    assert math.hypot(robot.pose[0] - 0.6, robot.pose[1]) < 0.03
    assert robot.targets[0].header.stamp.sec >= 1000  # stamped in sim time
    # cmd_vel (TwistStamped) carries the sim-time control instant, non-decreasing
    stamps = [t for t in robot.cmd_stamps if t > 0]
    assert stamps and stamps[0] >= 1000 * NS_PER_S and stamps == sorted(stamps)


def test_new_path_at_run_time(ros_node, tmp_path):
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path as PathMsg

    node, ex = ros_node
    robot = FakeRobot(node)
    pub_path = node.create_publisher(PathMsg, "pure_pursuit/path_in", 10)
    with _start(tmp_path, []):
        _wait_connected(ex, robot)
        assert wait_for_subscribers(ex, pub_path, timeout=20.0)
        assert spin_until(ex, lambda: robot.progress and robot.progress[-1] > 0.05, timeout=20.0)
        msg = PathMsg()
        msg.header.frame_id = "map"
        for x, y in ((0.0, 0.0), (0.0, 0.4)):  # identity orientations: tangent headings
            ps = PoseStamped()
            ps.pose.position.x, ps.pose.position.y = x, y
            ps.pose.orientation.w = 1.0
            msg.poses.append(ps)
        n_paths = len(robot.paths)
        pub_path.publish(msg)
        assert spin_until(ex, lambda: len(robot.paths) > n_paths, timeout=10.0)
        assert _xy(robot.paths[-1]) == [(0.0, 0.0), (0.0, 0.4)]
        assert spin_until(ex, lambda: robot.done[-1], timeout=20.0)
    assert math.hypot(robot.pose[0], robot.pose[1] - 0.4) < 0.03


def test_stale_and_bad_odometry_give_zero_commands_and_are_counted(ros_node, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray

    node, ex = ros_node
    robot = FakeRobot(node)
    diags: list = []
    diag_sub = node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    with _start(tmp_path, ["-p", "frequency:=50.0"]):
        _wait_connected(ex, robot)
        assert wait_for_publishers(ex, diag_sub, timeout=20.0)
        assert spin_until(ex, lambda: any(abs(c[0]) > 0.05 for c in robot.cmds), timeout=20.0)
        robot.publishing = False  # odometry stops: within odom_timeout (0.5 s) the command is zero
        t0 = time.monotonic()
        assert spin_until(ex, lambda: robot.cmd == (0.0, 0.0, 0.0), timeout=5.0)
        assert time.monotonic() - t0 < 2.0
        n = len(robot.cmds)
        assert spin_until(ex, lambda: len(robot.cmds) > n + 10, timeout=5.0)
        assert all(c == (0.0, 0.0, 0.0) for c in robot.cmds[n:])  # stays zero while stale
        # bad messages: rejected, counted, never turned into motion
        bad = [_odometry(node, math.nan, 0.0, 0.0), _odometry(node, 0.1, 0.0, 0.0, frame="odom")]
        zero_q = _odometry(node, 0.1, 0.0, 0.0)
        zero_q.pose.pose.orientation.w = 0.0
        asym = _odometry(node, 0.1, 0.0, 0.0)
        asym.pose.covariance[1] = 0.5
        bad += [zero_q, asym]
        for m in bad:
            robot.pub.publish(m)
        n = len(robot.cmds)
        assert spin_until(ex, lambda: len(robot.cmds) > n + 10, timeout=5.0)
        assert all(c == (0.0, 0.0, 0.0) for c in robot.cmds[n:])

        def counts():
            if not diags:
                return {}
            return {kv.key: kv.value for kv in diags[-1].status[0].values}

        keys = ("odometry_rejected_non_finite", "odometry_rejected_wrong_frame",
                "odometry_rejected_bad_quaternion", "odometry_rejected_bad_covariance")
        assert spin_until(ex, lambda: all(counts().get(k) == "1" for k in keys), timeout=5.0), counts()
        assert diags[-1].status[0].message.startswith("odometry stale: stopped")


def test_time_jump_resets_and_rejected_odometry_stops_the_robot(ros_node, tmp_path):
    """A simulator restart (sim time jumps back) resets the follower instead of blinding it; odometry
    that keeps arriving but is all rejected stops the robot within odom_timeout, with an ERROR."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    node, ex = ros_node
    robot = FakeRobot(node, sim_time_ns=20_000_000_000)
    diags: list = []
    diag_sub = node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def values():
        return {kv.key: kv.value for kv in diags[-1].status[0].values} if diags else {}

    with _start(tmp_path, ["-p", "use_sim_time:=true", "-p", "frequency:=50.0"]):
        _wait_connected(ex, robot)
        assert wait_for_publishers(ex, diag_sub, timeout=20.0)
        assert spin_until(ex, lambda: robot.progress and robot.progress[-1] > 0.15, timeout=20.0)
        robot.sim_time_ns = NS_PER_S  # the simulator restarts; its robot is back at the start
        robot.pose = [0.0, 0.0, 0.0]
        n_progress = len(robot.progress)
        # the follower starts the path again on the new clock's odometry: progress restarts and grows
        assert spin_until(ex, lambda: any(p < 0.1 for p in robot.progress[n_progress:]), timeout=5.0), \
            values()
        assert spin_until(ex, lambda: robot.progress[-1] > 0.15, timeout=10.0), robot.progress[-5:]
        assert spin_until(ex, lambda: values().get("time_jumps") == "1", timeout=5.0), values()
        assert int(values().get("odometry_rejected_repeated_stamp", "0")) < 5, values()
        assert not robot.done[-1]
        # a source stuck on one stamp: every message rejected, the command goes to zero and stays
        robot.fixed_stamp_ns = robot.sim_time_ns
        t0 = time.monotonic()
        assert spin_until(ex, lambda: robot.cmd == (0.0, 0.0, 0.0), timeout=5.0), robot.cmd
        assert time.monotonic() - t0 < 2.0  # odom_timeout 0.5 s of sim time
        n = len(robot.cmds)
        assert spin_until(ex, lambda: len(robot.cmds) > n + 20, timeout=5.0)
        assert all(c == (0.0, 0.0, 0.0) for c in robot.cmds[n:])
        assert spin_until(ex, lambda: diags[-1].status[0].level == DiagnosticStatus.ERROR, timeout=5.0)
        message = diags[-1].status[0].message
        # a stuck stamp is a repeated_stamp, and once older than odom_timeout a stale_stamp
        assert message.startswith("odometry stale: stopped"), message
        assert "messages of the last period rejected" in message, message
        assert "repeated_stamp" in message or "stale_stamp" in message, message


@pytest.mark.parametrize("arg, needle", [
    ("frequency:=50", "parameter 'frequency': expected a float from 0.001 to 10000 (Hz), written with a "
                      "decimal point"),
    ("frequency:=1.0e-12", "parameter 'frequency': expected a float from 0.001 to 10000 (Hz), got 1e-12"),
    ("lookahead_distance:=-0.3", "parameter 'lookahead_distance': must be a finite number > 0"),
    ("mode:=tank", "parameter 'mode': must be one of holonomic, differential"),
    ("path_file:=missing.yaml", "parameter 'path_file': missing.yaml not found"),
    ("lookahed_distance:=0.2", "unknown parameter(s) 'lookahed_distance'"),
])
def test_bad_parameters_stop_the_node_at_start_up(ros_domain, arg, needle):
    cmd = [*node_command("pure_pursuit_node"), "--ros-args", "--params-file", "config/pure_pursuit.yaml",
           "-p", arg]
    from helpers.ros_helpers import REPO

    res = subprocess.run(cmd, capture_output=True, text=True, timeout=30, cwd=str(REPO))
    assert res.returncode == 2, res.stdout + res.stderr
    assert needle in res.stderr


def test_bad_path_file_names_the_entry(ros_domain, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("waypoints:\n  - [0.0, 0.0]\n  - {x: 1.0}\n")
    res = subprocess.run([*node_command("pure_pursuit_node"), "--ros-args", "-p", f"path_file:={bad}"],
                         capture_output=True, text=True, timeout=30)
    assert res.returncode == 2
    assert "parameter 'path_file'" in res.stderr
    assert "waypoints[1]: expected a mapping with x and y" in res.stderr


def test_module_entry_point_is_importable():
    code = "import ekf_localization.nodes.pure_pursuit_node as m; print(m.NODE_NAME)"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert res.stdout.strip() == "pure_pursuit_node"
