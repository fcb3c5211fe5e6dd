"""NetworkTables 4 timestamps -> ROS time.

Every NT4 value carries the time it was published at, in the **server's** clock (the roboRIO's
FPGA time, µs). An NT4 client measures the offset between the server's clock and its own
(``NetworkTableInstance.getServerTimeOffset()``: server = local + offset, µs, updated by
periodic round trips). The local NT clock (``ntcore._now()``, µs) is not ROS time either, so the
bridge samples both clocks together on each poll (local, ROS, local: the ROS reading is paired
with the midpoint of the two local ones). A value's ROS stamp is then

    t_ros = (t_server − offset_server) · 1000 + (ROS − local)        [ns]

so a module state measured on the roboRIO 20 ms before it was sent is stamped 20 ms before the
ROS time of its sending, whatever the network's delay.
"""

from __future__ import annotations

from dataclasses import dataclass

NS_PER_US = 1000
US_PER_S = 1_000_000


@dataclass
class NtClock:
    """The two offsets of the module docstring; None until measured."""

    server_offset_us: int | None = None
    ros_minus_local_ns: int | None = None
    bracket_us: int | None = None  # width of the last local-clock bracket around the ROS reading

    def sample(self, local_before_us: int, ros_ns: int, local_after_us: int) -> None:
        """Pair a ROS clock reading with the local NT clock read just before and just after it."""
        self.bracket_us = int(local_after_us - local_before_us)
        self.ros_minus_local_ns = int(ros_ns) - (int(local_before_us) + int(local_after_us)) * NS_PER_US // 2

    def to_ros_ns(self, server_time_us: int) -> int | None:
        """ROS time (ns) of a server timestamp, or None before the client is synchronised."""
        if self.server_offset_us is None or self.ros_minus_local_ns is None:
            return None
        return (int(server_time_us) - int(self.server_offset_us)) * NS_PER_US + self.ros_minus_local_ns
