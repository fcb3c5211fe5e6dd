"""A busy node with a 50 Hz timer on simulated time, for test_due_timer.py (run as a script).

    python test/helpers/sim_time_ticker.py due|plain BUSY_S

``due`` makes the timer with ekf_localization.ros.due_timer.create_due_timer, ``plain`` with
``Node.create_timer``. Each tick publishes the ROS time it ran at on ``ticks`` (Int64); each
message on ``load`` (sensor-data QoS) busy-waits BUSY_S seconds, so that at 1 kHz events queue
up behind one another. It spins on node_runner's executor ($EKF_LOCALIZATION_EXECUTOR).
"""

from __future__ import annotations

import sys
import time

from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Int64

from ekf_localization.ros.due_timer import create_due_timer
from ekf_localization.ros.node_runner import run_node

PERIOD_S = 0.02


class Ticker(Node):
    def __init__(self, due: bool, busy_s: float) -> None:
        super().__init__("sim_time_ticker", parameter_overrides=[Parameter("use_sim_time", value=True)])
        self._busy_s = busy_s
        self._pub = self.create_publisher(Int64, "ticks", 1000)
        if due:
            create_due_timer(self, PERIOD_S, self._on_timer)
        else:
            self.create_timer(PERIOD_S, self._on_timer)
        self.create_subscription(Int64, "load", self._on_load, qos_profile_sensor_data)

    def _on_load(self, _msg: Int64) -> None:
        until = time.perf_counter() + self._busy_s
        while time.perf_counter() < until:
            pass

    def _on_timer(self) -> None:
        self._pub.publish(Int64(data=self.get_clock().now().nanoseconds))


def main() -> int:
    kind, busy_s = sys.argv[1], float(sys.argv[2])
    return run_node("sim_time_ticker", lambda: Ticker(kind == "due", busy_s), args=sys.argv[:1])


if __name__ == "__main__":
    sys.exit(main())
