"""sim_node -> joint_states -> ekf_node over real DDS, driving over the simulator's ramp.

sim_node publishes its dead wheels as sensor_msgs/JointState and the IMU's tilt; ekf_node
(config/ekf_joint_states.yaml with the IMU's roll/pitch and tilt compensation) fuses them.
Checked: the joint positions are rad of surface distance, the truth climbs the ramp, and
/odometry/filtered carries z and the pitch while the robot is on it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from helpers.ros_helpers import (
    REPO,
    node_command,
    running_process,
    spin_until,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.angles import quaternion_to_rpy
from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.tools.demo_analysis import tilt_overrides
from ekf_localization.tools.demo_params import known_start, write_ekf_params

pytestmark = [pytest.mark.ros, pytest.mark.slow]
START = (-0.2, -0.8, 0.0)  # heading east towards the ramp (config/sim.yaml: x 0.15 .. 0.85 m)
SPEED = 0.4
DRIVE_S = 2.3  # s at SPEED from x = -0.2 m: stops at about x = 0.72 m, on the down slope (0.6 .. 0.85 m)


def test_joint_states_from_the_sim_drive_the_ekf_over_the_ramp(ros_context, tmp_path: Path) -> None:
    from geometry_msgs.msg import Twist, Vector3
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    node = Node("ramp_probe", context=ros_context,
                parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    joints: list[JointState] = []
    truth: list[Odometry] = []
    est: list[Odometry] = []
    js_sub = node.create_subscription(JointState, "joint_states", joints.append, 500)
    node.create_subscription(Odometry, "ground_truth/odom", truth.append, 500)
    est_sub = node.create_subscription(Odometry, "odometry/filtered", est.append, 500)
    cmd_pub = node.create_publisher(Twist, "cmd_vel", 10)
    start = known_start(REPO / "config" / "ekf_joint_states.yaml", *START)
    start.update(tilt_overrides(joint_states=True))
    params = write_ekf_params(REPO / "config" / "ekf_joint_states.yaml", tmp_path / "ekf.yaml", start)
    sim = [*node_command("sim_node"), "--ros-args", "--params-file", str(REPO / "config" / "sim.yaml"),
           "-p", "publish_clock:=true", "-p", "stamped_cmd_vel:=false",
           "-p", f"cmd_vel_timeout:={DRIVE_S!r}",  # the sim stops itself: no race with this test's lag
           "-p", "dead_wheels.publish_joint_states:=true", "-p", "ramp.enabled:=true",
           "-p", f"initial_pose:=[{START[0]!r}, {START[1]!r}, {START[2]!r}]",
           "-p", "wait_for_topics:=[odometry/filtered, cmd_vel]", "-p", "wait_timeout:=120.0"]
    ekf = [*node_command("ekf_node"), "--ros-args", "--params-file", str(params), "-p", "use_sim_time:=true"]
    try:
        with running_process(ekf, tmp_path / "ekf.log") as ekf_proc, \
                running_process(sim, tmp_path / "sim.log") as sim_proc:
            assert wait_for_publishers(ex, js_sub, timeout=30.0), (tmp_path / "sim.log").read_text()[-2000:]
            # the EKF's start-up: generous for a loaded machine
            assert wait_for_publishers(ex, est_sub, timeout=90.0), (tmp_path / "ekf.log").read_text()[-2000:]
            assert wait_for_subscribers(ex, cmd_pub, timeout=10.0)
            cmd_pub.publish(Twist(linear=Vector3(x=SPEED)))  # one command: DRIVE_S of sim time, then stop

            def stopped_on_the_far_side() -> bool:
                if not truth or truth[-1].pose.pose.position.x < 0.6:
                    return False
                v = truth[-1].twist.twist.linear
                return math.hypot(v.x, v.y) < 1e-3

            assert spin_until(ex, stopped_on_the_far_side, 60.0), \
                truth[-1].pose.pose.position if truth else "no truth"
            # let a lagging node catch up with the stop
            t_stop = stamp_to_ns(truth[-1].header.stamp)
            caught_up = lambda: bool(est) and stamp_to_ns(est[-1].header.stamp) >= t_stop + SEC // 2  # noqa: E731
            assert spin_until(ex, caught_up, 30.0)
            assert ekf_proc.poll() is None and sim_proc.poll() is None
    finally:
        ex.shutdown()
        node.destroy_node()
    # joint_states: the three pods by name, positions in rad of distance along the surface
    assert list(joints[-1].name) == ["left_pod", "right_pod", "lateral_pod"]
    assert len(joints[-1].velocity) == 0
    stamps = np.array([stamp_to_ns(m.header.stamp) for m in joints])
    pos = np.array([list(m.position) for m in joints])
    level = [stamp_to_ns(m.header.stamp) for m in truth
             if -0.1 < m.pose.pose.position.x < 0.1]  # at speed on level ground
    moving = (stamps >= level[0]) & (stamps <= level[-1])
    speed = 0.024 * np.diff(pos[moving, :2], axis=0) / (np.diff(stamps[moving])[:, None] / SEC)
    assert np.median(speed) == pytest.approx(SPEED, rel=0.05)
    # truth climbs the 15° ramp: z and a nose-up pitch
    on_slope = [m for m in truth if 0.2 < m.pose.pose.position.x < 0.35]
    assert on_slope
    p = on_slope[-1].pose.pose
    assert p.position.z > 0.01
    assert quaternion_to_rpy(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)[1] == \
        pytest.approx(-math.radians(15.0), abs=1e-3)
    # the estimate publishes z and the IMU's pitch while on the slope (compared at equal stamps)
    # the estimate carries the IMU's pitch and the dead-reckoned z: while climbing (under load the
    # node may lag its inputs, so compare the climb's pitch, not its timing) and once stopped
    def pitch(pose) -> float:
        q = pose.orientation
        return quaternion_to_rpy(q.x, q.y, q.z, q.w)[1]

    climbing = [e for e in est if abs(pitch(e.pose.pose) + math.radians(15.0)) < math.radians(3.0)]
    assert climbing, [round(pitch(e.pose.pose), 3) for e in est]
    stopped, truth_stopped = est[-1].pose.pose, truth[-1].pose.pose
    assert truth_stopped.position.x < 0.85 and truth_stopped.position.z > 0.01  # on the down slope
    assert pitch(stopped) == pytest.approx(math.radians(15.0), abs=math.radians(3.0))  # nose down
    assert stopped.position.z == pytest.approx(truth_stopped.position.z, abs=0.03)
    assert est[-1].pose.covariance[14] > 1e-9  # z variance: dead-reckoned, not the planar placeholder
