"""Unit constants and conversions: integer nanoseconds <-> seconds, inches -> metres."""

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
