"""Records what one host sees of the others, as JSON lines, for test_multi_host.py.

Run inside the observer's namespace (``ip netns exec ... python multi_host_observer.py OUT``).
One line per message, flushed at once, with ``t`` = CLOCK_MONOTONIC (shared by all
namespaces) at reception:

* ``{"k": "est", "t", "w", "s", "x", "y", "finite"}``  /odometry/filtered (``finite``: pose, twist
  and both covariances all finite)
* ``{"k": "truth", "w", "s", "x", "y"}``         /ground_truth/odom
* ``{"k": "cmd", "t", "v"}``                      /cmd_vel (TwistStamped): linear x, y, angular z
* ``{"k": "diag", "t", "name", "level", "msg", "values"}``  /diagnostics, one per status

``w`` (on est and truth) is the wall clock at reception, in ns, for the arrival lag.
"""

from __future__ import annotations

import json
import math
import sys
import time


def main(out_path: str) -> int:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data

    from ekf_localization.core.units import stamp_to_ns

    out = open(out_path, "w", buffering=1)  # noqa: SIM115 (closed after spinning)

    def write(record: dict) -> None:
        out.write(json.dumps(record) + "\n")

    def on_est(msg: Odometry) -> None:
        p, tw = msg.pose.pose, msg.twist.twist
        values = [p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z,
                  p.orientation.w, tw.linear.x, tw.linear.y, tw.angular.z, *msg.pose.covariance,
                  *msg.twist.covariance]
        write({"k": "est", "t": time.monotonic(), "w": time.time_ns(), "s": stamp_to_ns(msg.header.stamp),
               "x": p.position.x,
               "y": p.position.y, "finite": all(math.isfinite(v) for v in values)})

    def on_truth(msg: Odometry) -> None:
        p = msg.pose.pose.position
        write({"k": "truth", "w": time.time_ns(), "s": stamp_to_ns(msg.header.stamp), "x": p.x, "y": p.y})

    def on_cmd(msg: TwistStamped) -> None:
        t = msg.twist
        write({"k": "cmd", "t": time.monotonic(), "v": [t.linear.x, t.linear.y, t.angular.z]})

    def on_diag(msg: DiagnosticArray) -> None:
        for st in msg.status:
            level = int.from_bytes(st.level, "little") if isinstance(st.level, bytes) else int(st.level)
            write({"k": "diag", "t": time.monotonic(), "name": st.name, "level": level, "msg": st.message,
                   "values": {kv.key: kv.value for kv in st.values}})

    rclpy.init()
    node = Node("multi_host_observer")
    qos = qos_profile_sensor_data
    subs = [node.create_subscription(Odometry, "odometry/filtered", on_est, qos),
            node.create_subscription(Odometry, "ground_truth/odom", on_truth, qos),
            node.create_subscription(TwistStamped, "cmd_vel", on_cmd, qos),
            node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)]
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        del subs
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
        out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
