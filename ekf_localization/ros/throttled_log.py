"""Warnings and errors on a message path, throttled per key before rclpy is called.

rclpy's ``throttle_duration_sec`` finds the caller's frame with ``inspect`` on every call,
also when it then drops the line, and throttles per line of code, so one input's warnings
could hide another's. :class:`ThrottledLog` keeps a steady-clock stamp per key (the input
and what went wrong), logs the first line of a key at once and then at most one a period,
saying how many like it it held back.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable

from ekf_localization.core.units import seconds_to_ns

_MAX_KEYS = 1024  # keys remembered; beyond that the oldest are forgotten (their next line logs)


class ThrottledLog:
    """``warning(key, text)`` / ``error(key, text)``: at most one line per key per ``period_s``."""

    def __init__(self, logger, period_s: float = 5.0,
                 clock_ns: Callable[[], int] = time.monotonic_ns) -> None:
        self._logger = logger
        self._period_ns = seconds_to_ns(period_s)
        self._clock_ns = clock_ns
        self._due: dict[Hashable, list[int]] = {}  # key -> [next time a line may go out, lines held back]

    def warning(self, key: Hashable, text: str | Callable[[], str]) -> bool:
        """Log ``text`` (or what it returns: built only when logged) as a warning, unless a line of
        ``key`` went out less than a period ago; True when it was logged."""
        return self._log(self._logger.warning, key, text)

    def error(self, key: Hashable, text: str | Callable[[], str]) -> bool:
        """As :meth:`warning`, at error severity."""
        return self._log(self._logger.error, key, text)

    def _log(self, emit: Callable[[str], object], key: Hashable, text: str | Callable[[], str]) -> bool:
        now = self._clock_ns()
        slot = self._due.get(key)
        if slot is not None and now < slot[0]:
            slot[1] += 1
            return False
        held = slot[1] if slot is not None else 0
        if slot is None:
            if len(self._due) >= _MAX_KEYS:
                del self._due[next(iter(self._due))]
            slot = self._due[key] = [0, 0]
        slot[0], slot[1] = now + self._period_ns, 0
        line = text() if callable(text) else text
        if held:
            line += f" (and {held} more since the last such line)"
        emit(line)
        return True
