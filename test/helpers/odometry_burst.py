"""Publish a burst of odometry at a given rate, for test_ekf_node_faults.py (run as a script).

    python test/helpers/odometry_burst.py COUNT RATE_HZ

Waits until ekf_node's subscription has matched (DDS discovery), prints ``burst``, publishes
COUNT nav_msgs/Odometry on ``odometry/dead_wheels`` (sensor-data QoS) stamped with the clock,
RATE_HZ on average (in runs of 50 back to back), prints ``done SECONDS`` and exits. A
process of its own, so that the burst does not hold the GIL of the test that times the reset
service's answers.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import rclpy
from nav_msgs.msg import Odometry
from rclpy.qos import qos_profile_sensor_data

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers.ros_helpers import twist_odometry  # noqa: E402

RUN = 50  # messages published back to back between sleeps


def main() -> int:
    count, rate_hz = int(sys.argv[1]), float(sys.argv[2])
    rclpy.init()
    node = rclpy.create_node("burst_probe")
    pub = node.create_publisher(Odometry, "odometry/dead_wheels", qos_profile_sensor_data)
    deadline = time.monotonic() + 20.0
    while pub.get_subscription_count() < 1:
        if time.monotonic() > deadline:
            print("no subscriber", flush=True)
            return 1
        time.sleep(0.01)
    clock = node.get_clock()
    msg = twist_odometry(clock.now().nanoseconds, 0.2)
    print("burst", flush=True)
    t0 = time.monotonic()
    for i in range(count):
        msg.header.stamp = clock.now().to_msg()
        pub.publish(msg)
        if i % RUN == RUN - 1:
            time.sleep(max(0.0, t0 + (i + 1) / rate_hz - time.monotonic()))
    print(f"done {time.monotonic() - t0:.3f}", flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
