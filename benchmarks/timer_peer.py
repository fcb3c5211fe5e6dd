"""The peer of soak_dds.py's output gaps: a bare node that only publishes on a timer.

    python benchmarks/timer_peer.py   (soak_dds.py starts it)

A 50 Hz timer on simulated time (``ros/due_timer.py``, as ekf_node's), on node_runner's
executor (as ekf_node), publishing an empty nav_msgs/Odometry stamped with its clock on
``soak_peer/odometry``. It does no filtering, so the gaps it shows under the same simulator,
real-time factor and CPU hogs are what rclpy and the scheduler cost any Python node; ekf_node's
gaps beyond them are its own.
"""

from __future__ import annotations

import sys

from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.parameter import Parameter

from ekf_localization.ros.due_timer import create_due_timer
from ekf_localization.ros.node_runner import run_node

TOPIC = "soak_peer/odometry"
PERIOD_S = 0.02  # config/ekf.yaml's frequency, 50 Hz


class TimerPeer(Node):
    def __init__(self) -> None:
        super().__init__("soak_timer_peer", parameter_overrides=[Parameter("use_sim_time", value=True)])
        self._pub = self.create_publisher(Odometry, TOPIC, 10)  # the depth of ekf_node's output
        self._msg = Odometry()
        create_due_timer(self, PERIOD_S, self._on_timer)

    def _on_timer(self) -> None:
        self._msg.header.stamp = self.get_clock().now().to_msg()
        self._pub.publish(self._msg)


def main() -> int:
    return run_node("soak_timer_peer", TimerPeer, args=sys.argv[:1])


if __name__ == "__main__":
    sys.exit(main())
