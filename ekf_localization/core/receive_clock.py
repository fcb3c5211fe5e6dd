"""The receiver's clock as the Localizer sees it: the newest ``now``, its stamp checks.

``now_ns`` is ROS time at the receiver (or a bag's receive time). A stamp too old or too far
ahead of it is rejected (core.measurements.check_stamp); a stamp ahead within
``future_stamp_tolerance`` (clock skew) is taken as the clock's time, so the filter, and so
its output, is never stamped ahead of the clock. The clock going backwards (a bag loop, a
simulator restart) is reported so the filter can reset.
"""

from __future__ import annotations

from ekf_localization.core.measurements import check_stamp


class ReceiveClock:
    """The newest receive time seen (None before the first) and the stamp checks against it."""

    def __init__(self, max_age_ns: int | None, future_tolerance_ns: int) -> None:
        self.max_age_ns = max_age_ns
        self.future_tolerance_ns = future_tolerance_ns
        self.now_ns: int | None = None

    def observe(self, now_ns: int | None) -> int | None:
        """Take ``now_ns`` (None: no clock for this call); return how far it went back, if it did."""
        if now_ns is None:
            return None
        now_ns = int(now_ns)
        back = self.now_ns - now_ns if self.now_ns is not None and now_ns < self.now_ns else None
        self.now_ns = now_ns
        return back

    def stamp_problem(self, stamp_ns: int) -> str | None:
        """The rejection reason of ``stamp_ns`` against the clock (stale, future), or None."""
        return check_stamp(stamp_ns, self.now_ns, self.max_age_ns, self.future_tolerance_ns)

    def not_ahead(self, stamp_ns: int) -> int:
        """``stamp_ns``, or the clock's time when the stamp is ahead of it (within tolerance)."""
        return min(stamp_ns, self.now_ns) if self.now_ns is not None else stamp_ns
