"""node_runner.run_node: a stop is a clean exit, a real fault is not hidden."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.ros

# A node whose timer callback publishes after the context is shut down: the same state as a
# Ctrl-C that lands while a callback is publishing (rcl: "publisher's context is invalid").
_SCRIPT = """
import sys
import rclpy
from rclpy.node import Node
from std_msgs.msg import Bool
from ekf_localization.ros.node_runner import run_node

class Racing(Node):
    def __init__(self):
        super().__init__("racing_shutdown")
        self.pub = self.create_publisher(Bool, "racing", 10)
        self.create_timer(0.01, self.tick)

    def tick(self):
        if sys.argv[1] == "shutdown":
            rclpy.shutdown()  # the context goes away ...
        self.pub.publish(Bool(data=True))  # ... under this publish
        if sys.argv[1] == "fault":
            raise RuntimeError("a real fault")

sys.exit(run_node("racing_shutdown", Racing, args=[sys.argv[0]]))
"""


@pytest.mark.parametrize("executor", ["single", "events"])
def test_a_publish_racing_the_shutdown_is_a_clean_exit(ros_domain: int, executor: str) -> None:
    res = subprocess.run([sys.executable, "-c", _SCRIPT, "shutdown"], capture_output=True, text=True,
                         timeout=60, env=dict(os.environ, EKF_LOCALIZATION_EXECUTOR=executor))
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr + res.stdout


def test_a_callback_fault_while_running_still_raises(ros_domain: int) -> None:
    res = subprocess.run([sys.executable, "-c", _SCRIPT, "fault"], capture_output=True, text=True,
                         timeout=60, env=dict(os.environ, EKF_LOCALIZATION_EXECUTOR="single"))
    assert res.returncode != 0
    assert "RuntimeError: a real fault" in res.stderr
