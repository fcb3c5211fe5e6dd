"""ekf_node over real DDS with a jointN input (sensor_msgs/JointState dead-wheel encoders).

The test process publishes the encoders of a robot driving a constant body twist, like
ros2_control's joint_state_broadcaster (positions in rad, names in any order, an extra joint),
interleaved with one bad message of each kind and an encoder reset; it checks the estimate
and the per-reason counters on /diagnostics.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.ros_helpers import (
    node_command,
    running_process,
    spin_until,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry

pytestmark = [pytest.mark.ros, pytest.mark.slow]
NAMES = ["left_pod", "right_pod", "lateral_pod"]
R_WHEEL, W, D = 0.024, 0.17, 0.1
TWIST = np.array([0.5, -0.2, 0.6])  # body [vx vy wz]
PERIOD_NS = 10_000_000


def _params(tmp_path: Path) -> Path:
    p = {"model": "mecanum", "frequency": 50.0, "world_frame": "odom", "publish_tf": False,
         "joint0": "joint_states", "joint0_names": NAMES, "joint0_queue_size": 200,
         "joint0_wheel_radius": R_WHEEL,
         "joint0_half_spacing": W, "joint0_lateral_offset": D, "joint0_speed_variance_coeff": 0.002,
         "joint0_speed_variance_floor": 6.4516e-07, "joint0_max_speed": 3.0,
         "process_noise_covariance": list(map(float, (np.eye(15) * 0.5).ravel()))}
    path = tmp_path / "ekf_joints.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": p}}))
    return path


def test_joint_states_fused_and_bad_messages_counted(ros_context, tmp_path: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import JointState

    node = Node("joint_feeder", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    pub = node.create_publisher(JointState, "joint_states", qos_profile_sensor_data)
    outputs: list[tuple[int, np.ndarray, np.ndarray]] = []
    diag: dict[str, dict[str, str]] = {}

    def on_odom(m) -> None:
        t = m.twist.twist
        outputs.append((m.header.stamp.sec * SEC + m.header.stamp.nanosec,
                        np.array([t.linear.x, t.linear.y, t.angular.z]),
                        np.asarray(m.twist.covariance).reshape(6, 6)))

    def on_diag(m) -> None:
        for st in m.status:
            diag[st.name] = {kv.key: kv.value for kv in st.values}

    sub = node.create_subscription(Odometry, "odometry/filtered", on_odom, 100)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    E_rate = DeadWheelGeometry(W, D).encoders_from_twist @ TWIST / R_WHEEL  # rad/s per wheel

    def message(t_ns: int, q: np.ndarray, names=None, velocity=()) -> JointState:
        m = JointState()
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(t_ns, SEC)
        # the broadcaster's order is not ours; an unrelated joint is in the message too
        order = names or ["arm", NAMES[2], NAMES[0], NAMES[1]]
        by_name = {"arm": 1.0, NAMES[0]: q[0], NAMES[1]: q[1], NAMES[2]: q[2]}
        m.name = list(order)
        m.position = [float(by_name.get(n, 0.0)) for n in order]
        m.velocity = list(velocity)
        return m

    bad = {  # reason -> a builder of the bad message at (stamp, positions, last good stamp)
        "unequal_array_lengths": lambda t, q, last: message(t, q, velocity=[1.0]),
        "duplicate_joint_names": lambda t, q, last: message(t, q, names=[NAMES[0], *NAMES]),
        "joint_missing": lambda t, q, last: message(t, q, names=["arm", NAMES[0], NAMES[1]]),
        "nonfinite": lambda t, q, last: message(t, np.array([q[0], math.nan, q[2]])),
        "stamp_not_increasing": lambda t, q, last: message(last - PERIOD_NS, q),
    }
    sent_bad = dict.fromkeys(bad, 0)
    try:
        cmd = node_command("ekf_node") + ["--ros-args", "--params-file", str(_params(tmp_path))]
        with running_process(cmd, tmp_path / "ekf.log") as ekf:
            assert wait_for_publishers(ex, sub, timeout=20.0), "ekf_node never came up"
            assert wait_for_subscribers(ex, pub, timeout=10.0)
            t0 = node.get_clock().now().nanoseconds
            reset_offset = 0.0
            last = None
            n_good = 250
            for k in range(n_good):
                t = t0 + k * PERIOD_NS
                if k == 150:
                    reset_offset = -500.0  # the left encoder is reset (a 12 m jump)
                q = E_rate * (k * PERIOD_NS / SEC) + np.array([reset_offset, 0.0, 0.0])
                if k % 20 == 10:
                    reason = list(bad)[(k // 20) % len(bad)]
                    pub.publish(bad[reason](t, q, last))
                    sent_bad[reason] += 1
                pub.publish(message(t, q))
                last = t
                ex.spin_once(timeout_sec=0.0)
                time.sleep(max(0.0, (t + PERIOD_NS - node.get_clock().now().nanoseconds) / SEC))
            total = n_good + sum(sent_bad.values())
            assert spin_until(ex, lambda: outputs and outputs[-1][0] >= last, 5.0)
            # diagnostics once a second: wait until they show everything that arrived
            done = lambda: int(diag.get("ekf_node: joint0", {}).get("received", -1)) >= total  # noqa: E731
            spin_until(ex, done, 5.0)
            assert "ekf_node: joint0" in diag, diag.keys()
            assert ekf.poll() is None, "ekf_node died"
        d = diag["ekf_node: joint0"]
        received = int(d["received"])
        lost = total - received
        assert 0 <= lost <= 0.1 * total, (lost, d)  # best effort: a lagging node drops some
        for reason, n in sent_bad.items():
            assert n - lost <= int(d[f"rejected_{reason}"]) <= n, (reason, d)
        assert 1 - lost <= int(d["rejected_encoder_jump"]) <= 1, d
        assert int(d["applied"]) >= n_good - 3 - lost
        # the estimate: the body twist, no spike at the encoder reset, covariance from the encoders
        late = [(t, v, C) for t, v, C in outputs if t0 + SEC // 2 <= t <= last]
        assert len(late) > 50
        err = np.array([v - TWIST for _, v, _ in late])
        assert np.abs(err).max() < 0.02, np.abs(err).max(axis=0)
        # outputs are predicted to "now": a node lagging behind its input adds process noise,
        # so the smallest published variance is the one right after the encoder updates
        C = min((c for _, _, c in late), key=lambda c: c[0, 0])
        assert 0.0 < C[0, 0] < 0.01 and 0.0 < C[5, 5] < 0.05
    finally:
        ex.shutdown()
        node.destroy_node()
