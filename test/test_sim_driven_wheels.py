"""sim_node -> joint_states (the drive's own wheels) -> ekf_node over real DDS.

sim_node publishes its four mecanum wheels as sensor_msgs/JointState (``wheel_encoders.*``:
positions in whole encoder counts, jittered intervals); ekf_node runs
config/ekf_driven_wheels.yaml (a jointN input of geometry mecanum) with the camera off, so
that the wheels and the IMU carry the estimate. Checked: the message (names, counts,
intervals), the input's /diagnostics (applied, no fault), and the estimate against the truth.
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

from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.ros.parameters import parameters_from_yaml
from ekf_localization.tools.demo_params import known_start, write_ekf_params

pytestmark = [pytest.mark.ros, pytest.mark.slow]
START = (-0.5, -0.5, 0.3)
DRIVE_S = 3.0
CONFIG = REPO / "config" / "ekf_driven_wheels.yaml"


def test_the_sims_driven_wheels_drive_the_ekf(ros_context, tmp_path: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from geometry_msgs.msg import Twist, Vector3
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Empty

    node = Node("driven_wheels_probe", context=ros_context,
                parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    joints: list[JointState] = []
    truth: list[Odometry] = []
    est: list[Odometry] = []
    diag: dict[str, DiagnosticStatus] = {}

    def on_diag(m) -> None:
        for st in m.status:
            diag[st.name] = st

    js_sub = node.create_subscription(JointState, "joint_states", joints.append, 500)
    node.create_subscription(Odometry, "ground_truth/odom", truth.append, 500)
    est_sub = node.create_subscription(Odometry, "odometry/filtered", est.append, 500)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    cmd_pub = node.create_publisher(Twist, "cmd_vel", 10)
    params = write_ekf_params(CONFIG, tmp_path / "ekf.yaml",
                              {**known_start(CONFIG, *START), "use_control": False})
    sim = [*node_command("sim_node"), "--ros-args", "--params-file", str(REPO / "config" / "sim.yaml"),
           "-p", "publish_clock:=true", "-p", "stamped_cmd_vel:=false", "-p", "camera.enabled:=false",
           "-p", f"cmd_vel_timeout:={DRIVE_S!r}",  # the sim stops itself: no race with this test's lag
           "-p", "wheel_encoders.publish_joint_states:=true",
           "-p", f"initial_pose:=[{START[0]!r}, {START[1]!r}, {START[2]!r}]",
           "-p", "wait_for_topics:=[odometry/filtered, driven_wheels_probe_go]", "-p", "wait_timeout:=120.0"]
    ekf = [*node_command("ekf_node"), "--ros-args", "--params-file", str(params), "-p", "use_sim_time:=true"]
    try:
        with running_process(ekf, tmp_path / "ekf.log") as ekf_proc, \
                running_process(sim, tmp_path / "sim.log") as sim_proc:
            assert wait_for_publishers(ex, js_sub, timeout=30.0), (tmp_path / "sim.log").read_text()[-2000:]
            assert wait_for_publishers(ex, est_sub, timeout=90.0), (tmp_path / "ekf.log").read_text()[-2000:]
            assert wait_for_subscribers(ex, cmd_pub, timeout=10.0)
            cmd_pub.publish(Twist(linear=Vector3(x=0.4, y=0.2), angular=Vector3(z=0.6)))
            # simulated time starts only now (its wait_for_topics): the command acts from t = 0 whatever
            # the DDS matching above took, so the drive and the push meet as planned
            spin_until(ex, lambda: False, 0.2)
            go = node.create_publisher(Empty, "driven_wheels_probe_go", 1)  # noqa: F841 - its existence is the signal

            def stopped() -> bool:
                if len(truth) < 100:
                    return False
                v = truth[-1].twist.twist
                return math.hypot(v.linear.x, v.linear.y) + abs(v.angular.z) < 1e-3

            assert spin_until(ex, stopped, 60.0), truth[-1].twist.twist if truth else "no truth"
            t_stop = stamp_to_ns(truth[-1].header.stamp)
            caught_up = lambda: bool(est) and stamp_to_ns(est[-1].header.stamp) >= t_stop + SEC // 2  # noqa: E731
            assert spin_until(ex, caught_up, 30.0)
            seen = lambda: "ekf_node: joint0" in diag and any(  # noqa: E731
                kv.key == "applied" and int(kv.value) > 50 for kv in diag["ekf_node: joint0"].values)
            assert spin_until(ex, seen, 10.0), {k: v.message for k, v in diag.items()}
            assert ekf_proc.poll() is None and sim_proc.poll() is None
    finally:
        ex.shutdown()
        node.destroy_node()
    names = parameters_from_yaml(CONFIG, "ekf_node")["joint0_names"]
    assert list(joints[-1].name) == names and len(joints[-1].velocity) == 4
    # positions in whole counts of the resolution; intervals jittered within 16-41 ms
    q = parameters_from_yaml(REPO / "config" / "sim.yaml", "sim_node")["wheel_encoders.resolution"]
    counts = np.array([list(m.position) for m in joints]) / q
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.abs(counts[-1]).max() > 50  # the wheels turned
    dt = np.diff([stamp_to_ns(m.header.stamp) for m in joints]) / 1e6
    assert dt.min() >= 16 - 1e-6 and dt.max() <= 41 + 1e-6 and np.std(dt) > 0.5, dt
    assert 18 < np.mean(dt) < 23
    status = diag["ekf_node: joint0"]
    assert status.level == DiagnosticStatus.OK, status.message
    # the estimate once stopped: the wheels and the gyro dead-reckoned the drive
    p, pt = est[-1].pose.pose.position, truth[-1].pose.pose.position
    travelled = math.hypot(pt.x - START[0], pt.y - START[1])
    assert travelled > 0.8
    assert math.hypot(p.x - pt.x, p.y - pt.y) < 0.05, (p, pt)
