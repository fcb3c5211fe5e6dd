"""ekf_node's clock: the system clock read directly without simulated time, and ROS time (None
until a /clock message) from the moment ``use_sim_time`` is set at run time, and back.

The node runs in this process on config/ekf.yaml; no /clock is published.
"""

from __future__ import annotations

import time

import pytest
from helpers.ros_helpers import REPO

pytestmark = pytest.mark.ros


def test_clock_follows_use_sim_time_set_at_run_time(ros_context) -> None:
    from rclpy.parameter import Parameter

    from ekf_localization.nodes.ekf_node import EkfNode

    args = ["--ros-args", "--params-file", str(REPO / "config" / "ekf.yaml")]
    node = EkfNode(context=ros_context, cli_args=args)
    try:
        before = time.time_ns()
        now = node._now_ns()
        assert now is not None and before <= now <= time.time_ns()
        assert node.set_parameters([Parameter("use_sim_time", value=True)])[0].successful
        assert node.get_clock().ros_time_is_active
        assert node._now_ns() is None  # simulated time, and no /clock yet
        assert node.set_parameters([Parameter("use_sim_time", value=False)])[0].successful
        before = time.time_ns()
        now = node._now_ns()
        assert now is not None and before <= now <= time.time_ns()
    finally:
        node.destroy_node()
