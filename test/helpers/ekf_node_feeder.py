"""Publisher process for the ekf_node integration tests (run as a script).

    python test/helpers/ekf_node_feeder.py --mode track|lagged|poison [options]

It replays the scenario of helpers/fusion_scenario.py over real DDS: dead-wheel odometry,
camera poses delivered ``--latency-ms`` after their capture stamp, IMU yaw rate and cmd_vel.
``track`` and ``lagged`` run on simulated time (it publishes /clock every millisecond, paced
at ``--speed`` times real time); ``track`` then jumps the clock back to the start (a bag
loop) and plays ``--loop-s`` more seconds. ``poison`` stamps with the wall clock and
corrupts a known share of the messages; it prints what it sent as one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # test/, when run as a script

from ekf_localization.core.units import NS_PER_S as SEC  # noqa: E402
from helpers.fusion_scenario import MS, Scenario, make_scenario  # noqa: E402


def scenario_for(args: argparse.Namespace) -> Scenario:
    return make_scenario(duration_s=args.duration, seed=args.seed, camera_latency_ns=args.latency_ms * MS,
                         odom_bias=(0.04, -0.03, 0.03), speed=args.robot_speed)


def build_message(scn: Scenario, source: str, j: int, stamp_ns: int | None = None):
    """The ROS message of scenario event (source, j), optionally re-stamped."""
    item = scn.item(source, j)
    return measurement_message(source, item, item.stamp_ns if stamp_ns is None else stamp_ns)


def measurement_message(source: str, item, stamp_ns: int, imu_orientation: bool = False):
    """The ROS message of measurement ``item`` of input ``source`` (cmd_vel, odom0, pose0, else an
    IMU), stamped ``stamp_ns``; the IMU's yaw only with ``imu_orientation`` (else its
    orientation covariance says "none", -1)."""
    from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu

    from ekf_localization.core.angles import yaw_to_quaternion
    from ekf_localization.core.units import ns_to_sec_nanosec

    if source == "cmd_vel":  # config/ekf.yaml: stamped_cmd_vel (TwistStamped, applied at its stamp)
        msg = TwistStamped()
        msg.header.frame_id = "base_link"
        tw = msg.twist
        tw.linear.x, tw.linear.y, tw.angular.z = (float(item.twist[0]), float(item.twist[1]),
                                                  float(item.twist[5]))
    elif source == "odom0":
        msg = Odometry()
        msg.header.frame_id, msg.child_frame_id = item.frame_id, item.child_frame_id
        msg.pose.pose.orientation.w = 1.0
        msg.pose.covariance = [float(c) for c in item.pose_covariance.ravel()]
        tw = msg.twist.twist
        tw.linear.x, tw.linear.y, tw.angular.z = (float(item.twist[0]), float(item.twist[1]),
                                                  float(item.twist[5]))
        msg.twist.covariance = [float(c) for c in item.twist_covariance.ravel()]
    elif source == "pose0":
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = item.frame_id
        p = msg.pose.pose
        p.position.x, p.position.y = float(item.pose[0]), float(item.pose[1])
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = yaw_to_quaternion(
            float(item.pose[5]))
        msg.pose.covariance = [float(c) for c in item.covariance.ravel()]
    else:
        msg = Imu()
        msg.header.frame_id = item.frame_id
        if imu_orientation:
            msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = \
                yaw_to_quaternion(float(item.orientation[2]))
            msg.orientation_covariance = [float(c) for c in item.orientation_covariance.ravel()]
        else:
            msg.orientation.w = 1.0
            msg.orientation_covariance = [-1.0] + [0.0] * 8
        msg.angular_velocity.z = float(item.angular_velocity[2])
        msg.angular_velocity_covariance = [float(c) for c in item.angular_velocity_covariance.ravel()]
        msg.linear_acceleration_covariance = [-1.0] + [0.0] * 8
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    return msg


# Poisoned messages (mode "poison"): index rule -> (what is done, the reason ekf_node should count).
def poison(source: str, j: int, msg, now_ns: int) -> str | None:
    """Corrupt ``msg`` in place when the rule for (source, j) says so; returns the expected reason."""
    from ekf_localization.core.units import ns_to_sec_nanosec

    if source == "odom0":
        cov = list(msg.twist.covariance)
        if j % 10 == 3:
            msg.twist.twist.linear.x = math.nan
            return "nonfinite"
        if j % 10 == 5:
            cov[0] = -cov[0]
            msg.twist.covariance = cov
            return "bad_covariance"
        if j % 10 == 7:
            cov[1] = 1e-5  # (0, 1) without (1, 0): not symmetric
            msg.twist.covariance = cov
            return "bad_covariance"
        if j % 10 == 9:
            msg.twist.twist.angular.z = math.inf
            return "nonfinite"
    elif source == "pose0":
        if j % 4 == 1:
            msg.header.frame_id = "odom"  # world_frame is map and no odom->map transform is known
            return "no_transform"
        if j % 4 == 2:
            cov = list(msg.pose.covariance)
            cov[35] = math.nan
            msg.pose.covariance = cov
            return "nonfinite"
    elif source == "imu0":
        if j % 5 == 2:
            msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(now_ns + 5 * SEC)
            return "future_stamp"
        if j % 5 == 4:
            msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(now_ns - 10 * SEC)
            return "stale_stamp"
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--mode", choices=("track", "lagged", "poison"), required=True)
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--latency-ms", type=int, default=80)
    ap.add_argument("--robot-speed", type=float, default=1.0)
    ap.add_argument("--speed", type=float, default=1.0, help="sim seconds per wall second")
    ap.add_argument("--loop-s", type=float, default=1.0)
    ap.add_argument("--subscribers", type=int, default=1, help="ekf_node processes to wait for")
    args = ap.parse_args(argv)

    import rclpy
    from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.duration import Duration
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu

    from ekf_localization.core.units import ns_to_sec_nanosec

    rclpy.init()
    node = Node("ekf_test_feeder")
    pubs = {"odom0": node.create_publisher(Odometry, "odometry/dead_wheels", 100),
            "pose0": node.create_publisher(PoseWithCovarianceStamped, "camera/pose", 10),
            "imu0": node.create_publisher(Imu, "imu/data", 100),
            "cmd_vel": node.create_publisher(TwistStamped, "cmd_vel", 10)}
    sim = args.mode != "poison"
    clock_pub = node.create_publisher(Clock, "/clock", 10) if sim else None
    waited = list(pubs.values()) + ([clock_pub] if sim else [])
    deadline = time.monotonic() + 30.0
    while any(p.get_subscription_count() < args.subscribers for p in waited):
        if time.monotonic() > deadline:
            print("feeder: subscribers never matched", file=sys.stderr)
            return 1
        time.sleep(0.01)
    scn = scenario_for(args)
    events = scn.events()
    sent: dict[str, int] = {}
    expected: dict[str, dict[str, int]] = {s: {} for s in pubs}

    def play(events, shift_ns: int = 0) -> None:
        t0 = int(scn.t_ns[0])
        wall0 = time.perf_counter()
        i = 0
        last = events[-1][0]
        for k in range(0, (last - t0) // MS + 1):
            t = t0 + k * MS
            target = wall0 + k * 1e-3 / args.speed
            delay = target - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            if sim:
                c = Clock()
                c.clock.sec, c.clock.nanosec = ns_to_sec_nanosec(t + shift_ns)
                clock_pub.publish(c)
            while i < len(events) and events[i][0] <= t:
                _, source, j = events[i]
                i += 1
                if sim:
                    stamp = scn.item(source, j).stamp_ns + shift_ns
                    msg = build_message(scn, source, j, stamp)
                else:  # wall-clock stamps: the camera's capture stamp is latency ago
                    now = time.time_ns()
                    lag = args.latency_ms * MS if source == "pose0" else 0
                    msg = build_message(scn, source, j, now - lag)
                    reason = poison(source, j, msg, now)
                    if reason is not None:
                        expected[source][reason] = expected[source].get(reason, 0) + 1
                pubs[source].publish(msg)
                sent[source] = sent.get(source, 0) + 1

    play(events)
    if args.mode == "track" and args.loop_s > 0:  # a bag loop: the clock jumps back
        loop_end = int(scn.t_ns[0]) + int(args.loop_s * SEC)
        play([e for e in events if e[0] <= loop_end])
    print(json.dumps({"sent": sent, "expected_rejections": expected}), flush=True)
    for p in waited:  # every message delivered (reliable QoS: acknowledged by the subscribers)
        if not p.wait_for_all_acked(Duration(seconds=5.0)):
            print("feeder: messages not acknowledged", file=sys.stderr)
            return 1
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
