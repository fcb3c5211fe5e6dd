"""ros/due_timer.py over real DDS: a timer on simulated time, on a busy node, on both executors.

The test publishes /clock every simulated millisecond and a message on the ticker's ``load``
topic with each (helpers/sim_time_ticker.py busy-waits 0.25 ms on each), at real-time pace, in
0.2 s segments with the clock stopping after each: a warm-up until the first tick comes back,
then 2 s, then the clock jumps back 2 s (a bag loop) and plays 1 s more. rclpy 7.1's
EventsExecutor calls a plain timer again before it is due on a busy node (the ``plain`` control,
loaded more, checks that it still does), and each such call pushes the timer a period later:
ticks go missing and, when the clock stops, the one due by its last value may never come
(ekf_node's bag-loop test stalled so). The due timer ticks once per period.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest
from helpers.ros_helpers import running_process, spin_until, wait_for_publishers, wait_for_subscribers

from ekf_localization.core.units import NS_PER_S as SEC

pytestmark = [pytest.mark.ros]
TICKER = str(Path(__file__).resolve().parent / "helpers" / "sim_time_ticker.py")
T0 = 100 * SEC  # simulated start
MS = SEC // 1000
PERIOD = 20 * MS  # the ticker's 50 Hz
SEGMENT = 200 * MS  # the clock plays in segments and stops after each
SEGMENTS = 10  # 2 s, then 1 s again after the jump back
WARMUP_SEGMENTS = 10  # before T0, until the first tick has come back
BUSY_S = "0.00025"
CONTROL_BUSY_S = "0.002"  # the control's node cannot keep up with its 1 kHz load
CONTROL_RUNS = 2


def _run(ros_context, tmp_path: Path, executor: str, timer: str,
         busy_s: str = BUSY_S) -> list[tuple[int, list[int]]]:
    """(end, the ticks (ROS times) in it) of each segment."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Int64

    node = Node("due_timer_test", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ticks: list[int] = []
    sub = node.create_subscription(Int64, "ticks", lambda m: ticks.append(m.data), 1000)
    load = node.create_publisher(Int64, "load", qos_profile_sensor_data)
    clock = node.create_publisher(Clock, "/clock", 10)

    def play(start: int) -> None:
        """/clock and a load message every simulated ms of a segment, at real-time pace."""
        wall0 = time.monotonic()
        for k in range(1, SEGMENT // MS + 1):
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(start + k * MS, SEC)
            clock.publish(c)
            load.publish(Int64(data=k))
            while time.monotonic() < wall0 + k * 1e-3:  # spin_until's 20 ms step would make bursts
                ex.spin_once(timeout_sec=0.0005)

    starts = [T0 + i * SEGMENT for i in range(SEGMENTS)]
    starts += starts[:SEGMENTS // 2]  # the clock jumps back and plays on
    log = tmp_path / f"ticker_{executor}_{timer}.log"
    per_segment: list[tuple[int, list[int]]] = []
    try:
        with running_process([sys.executable, TICKER, timer, busy_s], log,
                             env={"EKF_LOCALIZATION_EXECUTOR": executor}) as ticker:
            assert wait_for_subscribers(ex, clock, 1, 30.0) and wait_for_subscribers(ex, load, 1, 30.0) \
                and wait_for_publishers(ex, sub, 1, 30.0), log.read_text()
            # Matched here is not matched there: the ticker may not see /clock yet, nor we its
            # ticks. Play the clock up to T0 until a tick comes back; then both paths work.
            for start in range(T0 - WARMUP_SEGMENTS * SEGMENT, T0, SEGMENT):
                play(start)
                if spin_until(ex, lambda: bool(ticks), 0.3):
                    break
            assert ticks, f"no tick in {WARMUP_SEGMENTS} warm-up segments: {log.read_text()}"
            for start in starts:
                n = len(ticks)
                play(start)
                end = start + SEGMENT
                # the clock has stopped: the tick due by its last value comes, or never (a
                # stuck timer never ticks again; 1 s leaves a loaded ticker time to come)
                spin_until(ex, lambda end=end, n=n: any(t > end - PERIOD for t in ticks[n:]), 1.0)
                per_segment.append((end, [t for t in ticks[n:] if start < t <= end]))
            assert ticker.poll() is None, log.read_text()
    finally:
        ex.shutdown()
        node.destroy_node()
    return per_segment


@pytest.mark.parametrize("executor", ["single", "events"])
def test_due_timer_ticks_once_a_period_and_its_last_due_tick_comes(ros_context, tmp_path, executor):
    segments = _run(ros_context, tmp_path, executor, "due")
    repeated = sum(len(s) - len(set(s)) for _, s in segments)
    assert repeated == 0, f"{repeated} ticks ran twice at one ROS time"
    late = [((end - T0) / SEC, [(t - end) // MS for t in s[-3:]]) for end, s in segments
            if max(s, default=0) <= end - PERIOD]
    assert not late, f"segments whose last due tick never came (end s, last ticks ms from it): {late}"
    ticks = sum(len(s) for _, s in segments)
    due = len(segments) * (SEGMENT // PERIOD)
    assert ticks >= 0.85 * due, f"{ticks} of {due} ticks"  # a node held up long misses some


@pytest.mark.slow
def test_plain_timer_on_events_still_runs_early(ros_context, tmp_path):
    """The control: rclpy's EventsExecutor still repeats a plain timer (else due_timer may go).
    A check of rclpy, not of this package, which keeps a core busy for seconds: a slow study.
    At the due test's 0.25 ms of load the repeats depend on the machine (runs without any: 6 of
    6 on one, 1 of 3 on another), so the control loads its node past what it can keep up with
    (2 ms per 1 kHz message): there 13 of 13 runs repeated 32-192 ticks, 5 of them with the
    other core busy."""
    repeated = 0
    for run in range(CONTROL_RUNS):
        (tmp_path / f"run{run}").mkdir()
        segments = _run(ros_context, tmp_path / f"run{run}", "events", "plain", CONTROL_BUSY_S)
        repeated += sum(len(s) - len(set(s)) for _, s in segments)
        if repeated:
            break
    assert repeated > 0, "no repeated ticks: rclpy's EventsExecutor may be fixed (see ros/due_timer.py)"
