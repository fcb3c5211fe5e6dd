"""ekf_node's ``publish_on_measurement`` over real DDS, on both executors.

With the timer at 1 Hz and ``predict_to_current_time: false``, each fused odometry message is
published from its own callback, stamped with its own stamp; a rejected one is not. The
events executor runs through node_runner.spin_forever (rclpy's EventsExecutor.spin() delivers
only the first message from another process).
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml
from helpers.ros_helpers import (
    node_command,
    running_process,
    spin_until,
    twist_odometry,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.units import NS_PER_S as SEC

pytestmark = [pytest.mark.ros]
N = 40


def _params(tmp_path: Path, on_measurement: bool) -> Path:
    cfg = [False] * 15
    cfg[6] = cfg[7] = cfg[11] = True
    params = {"model": "mecanum", "frequency": 1.0, "world_frame": "odom", "publish_tf": False,
              "predict_to_current_time": False, "sensor_timeout": 10.0, "odom0": "odometry/dead_wheels",
              "odom0_config": cfg, "odom0_queue_size": 100, "publish_on_measurement": on_measurement}
    path = tmp_path / "ekf.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    return path


@pytest.mark.parametrize("executor,on_measurement", [("single", True), ("events", True), ("events", False)])
def test_each_fused_message_is_published_at_its_stamp(ros_context, tmp_path, executor, on_measurement):
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    node = Node("publish_test", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    out: list[int] = []
    def on_output(m) -> None:
        out.append(m.header.stamp.sec * SEC + m.header.stamp.nanosec)

    sub = node.create_subscription(Odometry, "odometry/filtered", on_output, 1000)
    pub = node.create_publisher(Odometry, "odometry/dead_wheels", 100)
    cmd = node_command("ekf_node") + ["--ros-args", "--params-file", str(_params(tmp_path, on_measurement))]
    try:
        with running_process(cmd, tmp_path / "ekf.log", env={"EKF_LOCALIZATION_EXECUTOR": executor}):
            assert wait_for_subscribers(ex, pub, 1, 30.0) and wait_for_publishers(ex, sub, 1, 30.0), \
                (tmp_path / "ekf.log").read_text()
            # one fused message answered first: both directions matched before the counted run
            primed = False
            for _ in range(300):
                pub.publish(twist_odometry(time.time_ns(), 0.0))
                if spin_until(ex, lambda: bool(out), 0.1):
                    primed = True
                    break
            assert primed or not on_measurement, (tmp_path / "ekf.log").read_text()
            spin_until(ex, lambda: False, 0.2)
            out.clear()
            sent, bad = [], []
            for k in range(N):
                now = time.time_ns()
                rejected = k % 10 == 5  # NaN: rejected, so it must not be published
                pub.publish(twist_odometry(now, float("nan") if rejected else 0.5))
                (bad if rejected else sent).append(now)
                spin_until(ex, lambda: False, 0.01)  # ~100 Hz, spinning meanwhile
            spin_until(ex, lambda: set(sent) <= set(out), 5.0)
    finally:
        ex.shutdown()
        node.destroy_node()
    got = set(out)
    if on_measurement:
        assert set(sent) <= got, f"{len(set(sent) - got)} of {len(sent)} fused messages not published"
        assert not got & set(bad)
    else:  # the 1 Hz timer alone: a handful of outputs, not one per message
        assert len(got & set(sent)) <= 3
