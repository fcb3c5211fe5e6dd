"""A node timer whose callback runs only when it is due, on any executor.

rclpy 7.1's EventsExecutor can dispatch a timer a second time before its next period: its
timer manager queues one dispatch per re-check while the timer is ready, and with simulated
time every /clock message is a re-check, so a busy node gets repeats. Each repeat runs
``rcl_timer_call``, which moves the timer's next call a whole period on, so the timer falls
behind the clock (a 50 Hz timer ticked ~75 times in 2 s of simulated time) and, once /clock
stops, its last due ticks never come. A call made before the timer was due leaves more than
one period to its next call (a due call, even a late one, leaves at most one); such a call is
skipped and the next call put back where it was (a reset with the period shortened for it).
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.clock import Clock
from rclpy.node import Node
from rclpy.timer import Timer


class _WhenDue:
    """The timer callback: ``callback()`` when due, else the timer's next call put back."""

    def __init__(self, callback: Callable[[], None]) -> None:
        self.callback = callback
        self.timer: Timer | None = None
        self.skipped = 0  # calls made before the timer was due

    def __call__(self) -> None:
        timer = self.timer
        left = timer.time_until_next_call()
        period = timer.timer_period_ns
        if left is not None and left > period:  # rcl moved the next call from now + left - period
            self.skipped += 1
            timer.timer_period_ns = left - period  # rcl_timer_reset: next call = now + period
            timer.reset()
            timer.timer_period_ns = period  # changes the period, not the next call
            return
        self.callback()


def create_due_timer(node: Node, period_s: float, callback: Callable[[], None],
                     clock: Clock | None = None) -> Timer:
    """``node.create_timer(period_s, callback, clock=clock)``, with calls made before the
    timer was due skipped (its schedule kept); the count is ``timer.callback.skipped``."""
    when_due = _WhenDue(callback)
    when_due.timer = timer = node.create_timer(period_s, when_due, clock=clock)
    return timer
