"""A bump over real DDS: sim_node pushes the robot sideways while its driven wheels (or swerve
modules) keep their speeds; ekf_node (config/ekf_driven_wheels.yaml or config/ekf_swerve.yaml,
camera off) finds the slip from the IMU's
acceleration, counts it on /diagnostics, warns naming the input, refuses the wheel speeds and
widens the published pose covariance, and not before the push."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from helpers.ros_helpers import (
    REPO,
    node_command,
    running_process,
    spin_until,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.tools.demo_params import known_start, write_ekf_params

pytestmark = [pytest.mark.ros, pytest.mark.slow]
START = (-0.5, -0.5, 0.0)
DRIVE_S = 3.0
BUMP = (1.5, 0.0, 0.3)  # s of sim time, m, m
DRIVES = {"mecanum": ("ekf_driven_wheels.yaml", "sim.yaml"), "swerve": ("ekf_swerve.yaml", "sim_swerve.yaml")}


def _value(status, key: str) -> int:
    return next((int(kv.value) for kv in status.values if kv.key == key), -1)


@pytest.mark.parametrize("drive", sorted(DRIVES))
def test_a_bump_is_found_counted_and_widens_the_pose(ros_context, tmp_path: Path, drive: str) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Twist, Vector3
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import Empty

    node = Node("slip_probe", context=ros_context,
                parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    truth: list[Odometry] = []
    est: list[Odometry] = []
    diag: dict = {}

    def on_diag(m) -> None:
        for st in m.status:
            diag[st.name] = st

    node.create_subscription(Odometry, "ground_truth/odom", truth.append, 500)
    est_sub = node.create_subscription(Odometry, "odometry/filtered", est.append, 500)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    cmd_pub = node.create_publisher(Twist, "cmd_vel", 10)
    config, sim_yaml = (REPO / "config" / f for f in DRIVES[drive])
    params = write_ekf_params(config, tmp_path / "ekf.yaml",
                              {**known_start(config, *START), "use_control": False})
    sim = [*node_command("sim_node"), "--ros-args", "--params-file", str(sim_yaml),
           "-p", "publish_clock:=true", "-p", "stamped_cmd_vel:=false", "-p", "camera.enabled:=false",
           "-p", f"cmd_vel_timeout:={DRIVE_S!r}", "-p", "wheel_encoders.publish_joint_states:=true",
           "-p", f"bump:=[{BUMP[0]!r}, {BUMP[1]!r}, {BUMP[2]!r}]",
           "-p", f"initial_pose:=[{START[0]!r}, {START[1]!r}, {START[2]!r}]",
           "-p", "wait_for_topics:=[odometry/filtered, slip_probe_go]", "-p", "wait_timeout:=120.0"]
    ekf = [*node_command("ekf_node"), "--ros-args", "--params-file", str(params), "-p", "use_sim_time:=true"]
    try:
        with running_process(ekf, tmp_path / "ekf.log") as ekf_proc, \
                running_process(sim, tmp_path / "sim.log") as sim_proc:
            assert wait_for_publishers(ex, est_sub, timeout=90.0), (tmp_path / "ekf.log").read_text()[-2000:]
            assert wait_for_subscribers(ex, cmd_pub, timeout=10.0)
            cmd_pub.publish(Twist(linear=Vector3(x=0.4), angular=Vector3(z=0.3)))
            # simulated time starts only now (its wait_for_topics): the command acts from t = 0 whatever
            # the DDS matching above took, so the drive and the push meet as planned
            spin_until(ex, lambda: False, 0.2)
            go = node.create_publisher(Empty, "slip_probe_go", 1)  # noqa: F841 - its existence is the signal
            done = lambda: bool(truth) and stamp_to_ns(truth[-1].header.stamp) > (BUMP[0] + 1.0) * SEC  # noqa: E731
            assert spin_until(ex, done, 60.0), (tmp_path / "sim.log").read_text()[-2000:]
            def seen() -> bool:
                st = diag.get("ekf_node: joint0")
                return st is not None and _value(st, "slips") >= 1

            assert spin_until(ex, seen, 10.0), {k: v.message for k, v in diag.items()}
            assert ekf_proc.poll() is None and sim_proc.poll() is None
    finally:
        ex.shutdown()
        node.destroy_node()
    status = diag["ekf_node: joint0"]
    assert _value(status, "slips") == 1
    assert _value(status, "rejected_slip") > 0
    log = (tmp_path / "ekf.log").read_text()
    assert "joint0: wheel slip or collision" in log
    # widened at the push, not before: x variance from millimetres to about slip_pose_variance
    wide = [stamp_to_ns(m.header.stamp) for m in est if m.pose.covariance[0] > 0.1]
    assert wide, max(m.pose.covariance[0] for m in est)
    assert BUMP[0] * SEC <= wide[0] <= (BUMP[0] + 0.3) * SEC
    narrow = [m.pose.covariance[0] for m in est if stamp_to_ns(m.header.stamp) < BUMP[0] * SEC]
    assert narrow and max(narrow) < 0.01
    pushed = [m for m in truth if stamp_to_ns(m.header.stamp) >= (BUMP[0] + 0.3) * SEC][0]
    before = [m for m in truth if stamp_to_ns(m.header.stamp) <= BUMP[0] * SEC][-1]
    assert math.hypot(pushed.pose.pose.position.x - before.pose.pose.position.x,
                      pushed.pose.pose.position.y - before.pose.pose.position.y) > 0.3  # driven and pushed
