"""sim_node in its own process, received over real DDS: types, frames, rates, sim time."""

from __future__ import annotations

import math
import subprocess
import time
from bisect import bisect_right

import pytest
from helpers.ros_helpers import (
    REPO,
    node_command,
    running_process,
    spin_until,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.angles import quaternion_to_yaw
from ekf_localization.core.units import stamp_to_ns

pytestmark = pytest.mark.ros

MS = 1_000_000
LATENCY_NS = 200 * MS
HALF_PI = 1.5707963267948966


def yaw_of(q) -> float:
    return quaternion_to_yaw(q.x, q.y, q.z, q.w)


def sim_command(*overrides: str, params_file: str = "sim.yaml") -> list[str]:
    cmd = [*node_command("sim_node"), "--ros-args", "--params-file", str(REPO / "config" / params_file)]
    for o in overrides:
        cmd += ["-p", o]
    return cmd


def test_sim_node_publishes_every_topic_on_sim_time(ros_context, tmp_path):
    from geometry_msgs.msg import PoseWithCovarianceStamped, Twist, TwistStamped, Vector3
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu

    probe = Node("sim_probe", context=ros_context)
    follower = Node("sim_time_follower", context=ros_context,
                    parameter_overrides=[Parameter("use_sim_time", value=True)])
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(probe)
    ex.add_node(follower)
    got: dict[str, list] = {k: [] for k in ("odom", "camera", "imu", "truth", "clock")}
    latest_clock = [0]

    clock_sent: list[tuple[int, int]] = []  # (DDS source timestamp, /clock value) ns

    def on_clock(m, info):
        latest_clock[0] = stamp_to_ns(m.clock)
        got["clock"].append((stamp_to_ns(m.clock), time.monotonic()))
        clock_sent.append((info["source_timestamp"], latest_clock[0]))

    def on_camera(m, info):  # (message, clock seen here, DDS source timestamp)
        got["camera"].append((m, latest_clock[0], info["source_timestamp"]))

    def keep(key):
        return lambda m: got[key].append((m, latest_clock[0], time.monotonic()))

    subs = [
        probe.create_subscription(Odometry, "odometry/dead_wheels", keep("odom"), qos_profile_sensor_data),
        probe.create_subscription(PoseWithCovarianceStamped, "camera/pose", on_camera,
                                  qos_profile_sensor_data),
        probe.create_subscription(Imu, "imu/data", keep("imu"), qos_profile_sensor_data),
        probe.create_subscription(Odometry, "ground_truth/odom", keep("truth"), qos_profile_sensor_data),
        probe.create_subscription(Clock, "/clock", on_clock, 1000),
    ]
    cmd_pub = probe.create_publisher(TwistStamped, "cmd_vel", 10)  # config/sim.yaml: stamped_cmd_vel
    cmd = sim_command("publish_clock:=true", f"initial_pose:=[0.0, 0.0, {HALF_PI}]",
                      f"camera.latency:={LATENCY_NS / 1e9}")
    with running_process(cmd, tmp_path / "sim.log") as proc:
        for s in subs:
            assert wait_for_publishers(ex, s, timeout=20.0), f"no publisher on {s.topic_name}"
        assert wait_for_subscribers(ex, cmd_pub, timeout=20.0)
        # a reader can see the writer before the writer sees the reader: readings may arrive
        # before the first /clock does, so the window starts once /clock is flowing
        assert spin_until(ex, lambda: latest_clock[0] > 0, timeout=20.0), "no /clock received"
        for k in got:
            got[k].clear()
        t0 = time.monotonic()
        assert spin_until(ex, lambda: time.monotonic() - t0 > 2.0 and len(got["camera"]) >= 10,
                          timeout=20.0)
        wall = time.monotonic() - t0
        stationary = {k: list(v) for k, v in got.items()}
        # drive forward (cmd_vel_timeout is 0.5 s: keep publishing)
        t1 = time.monotonic()
        while time.monotonic() - t1 < 1.0:
            cmd_pub.publish(TwistStamped(twist=Twist(linear=Vector3(x=0.3))))
            spin_until(ex, lambda: False, timeout=0.05)
        moving_truth = [m for m, _, _ in got["truth"][-20:]]
        moving_odom = [m for m, _, _ in got["odom"][-20:]]
        follower_now = follower.get_clock().now().nanoseconds
        assert proc.poll() is None, (tmp_path / "sim.log").read_text()

    log = (tmp_path / "sim.log").read_text()
    odom = [m for m, _, _ in stationary["odom"]]
    cams = stationary["camera"]
    imus = [m for m, _, _ in stationary["imu"]]
    truths = [m for m, _, _ in stationary["truth"]]
    clocks = [c for c, _ in stationary["clock"]]

    # types and frames (REP-105)
    assert all(type(m) is Odometry and m.header.frame_id == "odom" and m.child_frame_id == "base_link"
               for m in odom)
    assert all(type(m) is PoseWithCovarianceStamped and m.header.frame_id == "map" for m, _, _ in cams)
    assert all(type(m) is Imu and m.header.frame_id == "base_link" for m in imus)
    assert all(m.header.frame_id == "map" and m.child_frame_id == "base_link" for m in truths)

    # sim time: /clock increases; every stamp is on the sim clock's integer-ns grid
    assert len(clocks) > 20 and all(b > a for a, b in zip(clocks, clocks[1:], strict=False))
    assert clocks[0] < 60_000_000_000  # sim time started at 0, not at the wall-clock epoch
    assert follower_now >= clocks[-1] > 0  # a use_sim_time node follows /clock
    for msgs, period in ((odom, 10 * MS), (imus, 10 * MS), (truths, 10 * MS)):
        stamps = [stamp_to_ns(m.header.stamp) for m in msgs]
        assert all(s % period == 0 for s in stamps)
        steps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
        assert all(d % period == 0 and d > 0 for d in steps)
        assert sum(d == period for d in steps) >= 0.9 * len(steps)  # few or no lost messages
        # rate in wall time, real_time_factor 1.0: 100 Hz within a loose tolerance (shared CPU)
        assert 50.0 <= len(msgs) / wall <= 150.0, f"{len(msgs) / wall:.1f} Hz"
    cam_stamps = [stamp_to_ns(m.header.stamp) for m, _, _ in cams]
    assert all(s % (50 * MS) == 0 for s in cam_stamps)  # 20 Hz captures
    assert 10.0 <= len(cams) / wall <= 30.0
    # latency: a capture is published once the sim clock has passed its stamp by the latency (the
    # /clock published before it, by DDS source time: this process may take them late under load)
    clock_sent.sort()
    sent_at = [ts for ts, _ in clock_sent]
    for m, _, cam_sent in cams:
        k = bisect_right(sent_at, cam_sent)
        assert k > 0
        sim_clock = max(c for _, c in clock_sent[:k])
        assert sim_clock >= stamp_to_ns(m.header.stamp) + LATENCY_NS - 20 * MS

    # contents: robot at rest at the initial pose, facing the top wall images
    t = truths[-1]
    assert abs(t.pose.pose.position.x) < 0.05 and abs(t.pose.pose.position.y) < 0.05
    assert abs(yaw_of(t.pose.pose.orientation) - HALF_PI) < 0.2
    c = cams[-1][0]
    d = math.hypot(0.9144, 1.8288)  # to an image at (±36 in, 72 in)
    assert c.pose.covariance[0] == pytest.approx(0.001 * d * d + 6.4516e-7, rel=0.1)
    assert c.pose.covariance[14] == 1e6  # z unmeasured
    assert abs(c.pose.pose.position.y - t.pose.pose.position.y) < 0.5
    i = imus[-1]
    assert i.orientation_covariance[8] == pytest.approx(7.6154e-05)
    assert i.linear_acceleration.z == pytest.approx(9.80665)
    o = odom[-1]
    assert o.twist.covariance[0] > 0.0 and o.twist.covariance[14] == 1e6
    assert o.pose.covariance[0] > 0.0  # integrated pose published with a growing covariance

    # cmd_vel reached the robot: ~0.3 m/s forward (truth has eq. 26's white velocity noise)
    vx_truth = sorted(m.twist.twist.linear.x for m in moving_truth)[len(moving_truth) // 2]
    vx_odom = sorted(m.twist.twist.linear.x for m in moving_odom)[len(moving_odom) // 2]
    assert abs(vx_truth - 0.3) < 0.05 and abs(vx_odom - 0.3) < 0.05, (vx_truth, vx_odom)
    assert "Traceback" not in log
    ex.shutdown()
    probe.destroy_node()
    follower.destroy_node()


def test_tank_sim_node_as_fast_as_possible_runs_ahead_of_the_wall_clock(ros_context, tmp_path):
    from geometry_msgs.msg import Twist, Vector3
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock

    node = Node("afap_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    clocks: list[int] = []
    truths: list[Odometry] = []
    sub = node.create_subscription(Clock, "/clock", lambda m: clocks.append(stamp_to_ns(m.clock)), 100)
    truth_sub = node.create_subscription(Odometry, "ground_truth/odom", truths.append, 100)
    cmd_pub = node.create_publisher(Twist, "cmd_vel", 10)
    cmd = sim_command("publish_clock:=true", "real_time_factor:=0.0", "cmd_vel_timeout:=0.0",
                      "stamped_cmd_vel:=false",
                      params_file="sim_tank.yaml")
    with running_process(cmd, tmp_path / "afap.log"):
        assert wait_for_publishers(ex, sub, timeout=20.0) and wait_for_publishers(ex, truth_sub, timeout=20.0)
        assert wait_for_subscribers(ex, cmd_pub, timeout=20.0)
        cmd_pub.publish(Twist(linear=Vector3(x=0.2, y=0.5)))  # a tank ignores vy
        spin_until(ex, lambda: bool(clocks), timeout=10.0)
        c0, t0 = clocks[-1], time.monotonic()
        spin_until(ex, lambda: time.monotonic() - t0 > 1.0, timeout=5.0)
        sim_elapsed = (clocks[-1] - c0) * 1e-9
        wall = time.monotonic() - t0
    assert sim_elapsed > 2.0 * wall, f"{sim_elapsed:.2f} s of sim time in {wall:.2f} s"
    assert truths and all(m.twist.twist.linear.y == 0.0 for m in truths)
    assert max(m.twist.twist.linear.x for m in truths) > 0.1  # the command arrived
    ex.shutdown()
    node.destroy_node()


def test_bad_parameter_stops_sim_node_and_names_it(ros_domain, tmp_path):
    cmd = sim_command("camera.frequency:=30", "imu.yaw_variance:=-1.0")
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=str(REPO))
    assert result.returncode == 2
    err = result.stderr + result.stdout
    assert "'camera.frequency'" in err and "decimal point" in err
    assert "'imu.yaw_variance'" in err
