"""ROS stamps <-> integer nanoseconds (never through float seconds).

Duck-typed on ``.sec`` / ``.nanosec``, so rclpy and rosbags messages both work.
"""

from __future__ import annotations

from ekf_localization.core.units import NS_PER_S


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def ns_to_sec_nanosec(t_ns: int) -> tuple[int, int]:
    """Integer nanoseconds -> (sec, nanosec) with 0 <= nanosec < 1e9."""
    sec, nanosec = divmod(int(t_ns), NS_PER_S)
    return sec, nanosec
