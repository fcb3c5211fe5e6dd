"""Time and length units: the one place that converts between integer nanoseconds, seconds and
ROS stamps (and inches to metres).

Time is integer nanoseconds everywhere (stamps, periods, timeouts); ``t_ns / NS_PER_S``
(:func:`ns_to_seconds`) is the one conversion to float seconds, done where a rate or a
duration in seconds is needed, and :func:`seconds_to_ns` the one way back (a parameter, a
duration). ROS stamps go to and from nanoseconds directly (:func:`stamp_to_ns`,
:func:`ns_to_sec_nanosec`), never through float seconds; they are duck-typed on ``.sec`` /
``.nanosec``, so rclpy and rosbags messages both work.
"""

from __future__ import annotations

NS_PER_S = 1_000_000_000
METRES_PER_INCH = 0.0254  # exact (international inch)


def seconds_to_ns(seconds: float) -> int:
    """Seconds (a parameter, a duration) -> integer nanoseconds, rounded to the nearest."""
    return int(round(seconds * NS_PER_S))


def ns_to_seconds(t_ns):
    """Integer nanoseconds (an int or an integer array) -> float seconds.

    int / int is correctly rounded, so a large stamp difference keeps its nanoseconds.
    """
    return t_ns / NS_PER_S


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time (or Duration) -> integer nanoseconds."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def ns_to_sec_nanosec(t_ns: int) -> tuple[int, int]:
    """Integer nanoseconds -> (sec, nanosec) with 0 <= nanosec < NS_PER_S."""
    sec, nanosec = divmod(int(t_ns), NS_PER_S)
    return sec, nanosec
