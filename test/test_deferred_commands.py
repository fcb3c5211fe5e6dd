"""Commands wait on the timeline until the measurements before them have come (core/timeline.py,
step 2): sensors that arrive late, in their own order, behind fresh cmd_vel are not lagged
entries (no rewind), and the filter is the one that took everything in stamp order.

Before, each command moved the committed state to its stamp at once, so every odometry and IMU
message that came after a newer command rewound the commands: on a starved CPU (sensor queues
half a second behind, cmd_vel fresh) that was ~100 replayed entries per message, and the node
never caught up (issue 35, case 2).
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers.localizer_scenario import SEC, START, T0, camera, drive, ekf_config, odometry, truth_at

from ekf_localization.core.measurements import ControlCommand
from ekf_localization.models.registry import make_localizer

CMD_PERIOD = 20_000_000  # cmd_vel at 50 Hz
SENSOR_LAG = 300_000_000  # the sensors' queues 0.3 s behind the clock (history_length is 0.5 s)
SECONDS = 3.0


def _commands() -> list[tuple[int, ControlCommand]]:
    """(arrival, command) of the truth's body twist, arriving at its stamp. They start once the
    first sensor message has come in both runs (the filter starts at the same entry), and sit
    5 ms off the sensors' 10 ms grid: no command shares a stamp with a measurement, whose order
    would then be the arrival order, which differs between the runs."""
    out = []
    for t in range(T0 + SENSOR_LAG + 5_000_000, T0 + int(SECONDS * SEC), CMD_PERIOD):
        vx, vy, wz = truth_at(t)[3:]
        out.append((t, ControlCommand(t, np.array([vx, vy, 0.0, 0.0, 0.0, wz]))))
    return out


def _feed(lag_ns: int):
    """A Localizer fed the drive's sensor messages ``lag_ns`` after their stamps and the commands
    at theirs, in arrival order (a sensor before a command that arrives at the same time)."""
    loc = make_localizer(ekf_config())
    events = [(ev.now_ns + lag_ns, 0, k, ev) for k, ev in enumerate(drive(SECONDS))]
    events += [(now, 1, k, cmd) for k, (now, cmd) in enumerate(_commands())]
    for now, kind, _, item in sorted(events, key=lambda e: e[:3]):
        if kind == 1:
            assert loc.add_control(item, now) is None
        else:
            loc.add_measurement(item.source, item.measurement, now)
    return loc


def test_sensors_behind_fresh_commands_do_not_rewind_and_match_stamp_order() -> None:
    in_order, late = _feed(0), _feed(SENSOR_LAG)
    assert in_order.rewinds == 0
    assert late.rewinds == 0, late.rewinds  # before: one per sensor message after a newer command
    for name, st in late.stats.items():  # every message fused, as in stamp order
        assert st.applied == in_order.stats[name].applied and not sum(st.rejected.values()), name
    # the same entries applied in the same order: the same filter, to rounding
    t_end = T0 + int(SECONDS * SEC)
    for t in (late.committed().stamp_ns, t_end):  # the newest measurement, then through commands
        a, b = in_order.estimate_at(t), late.estimate_at(t)
        np.testing.assert_allclose(b.state, a.state, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-12, atol=1e-15)


def test_a_set_pose_keeps_the_commands_that_waited_before_it() -> None:
    config = ekf_config()
    loc = make_localizer(config)
    ms, t = 1_000_000, T0
    for k in range(50):  # 0.5 s standing still, measured and commanded
        loc.add_measurement("odom0", odometry(t, 0.0, 0.0, 0.0), t)
        if k % 2 == 0:
            assert loc.add_control(ControlCommand(t + 5 * ms, np.zeros(6)), t + 5 * ms) is None
        t += 10 * ms
    c = t
    for _ in range(10):  # then 0.5 m/s commanded, with no measurement after: the commands wait
        assert loc.add_control(ControlCommand(c, np.array([0.5, 0, 0, 0, 0, 0])), c) is None
        c += CMD_PERIOD
    assert len(loc.history) - loc.history_size == 10  # deferred: in the history, not yet applied
    reset_at, after = c, 100 * ms
    assert loc.set_pose(camera(reset_at, *START), reset_at) is None
    vx = loc.estimate_at(reset_at + after).state[3]
    # Before the reset no measurement confirmed the commands (core/command_guard: the model
    # predicts without them, vx stays 0). The reset starts the guard again, and the newest command
    # acts from it: straight ahead, every wheel at the acceleration limit, vx = a r t. (Dropping
    # the waiting commands at the reset left the standing one in effect, timed out: vx 0.)
    assert vx == pytest.approx(config.wheel_acceleration_limit * config.wheel_radius * after / SEC, rel=1e-9)


@pytest.mark.parametrize("skew_ms", [5, 10, 22])
def test_a_command_ahead_of_this_clock_acts_at_its_own_stamp(skew_ms) -> None:
    """Each node has its own /clock, and pure_pursuit_node's can lead ekf_node's: in the demo
    commands arrived 10-22 ms ahead of ekf_node's clock (seeds 15 and 26, 170-196 of 460). A
    command within future_stamp_tolerance keeps its stamp: the filter equals the one that got
    every command at its stamp. (Moving the stamp to the clock made the drive model act early by
    the skew: a velocity 25 mm/s ahead of the truth at σ 1 mm/s, twist NEES 16-17.)"""
    skew = skew_ms * 1_000_000
    on_time = _feed(0)
    loc = make_localizer(ekf_config())
    events = [(ev.now_ns, 0, k, ev) for k, ev in enumerate(drive(SECONDS))]
    events += [(now - skew, 1, k, cmd) for k, (now, cmd) in enumerate(_commands())]
    for now, kind, _, item in sorted(events, key=lambda e: e[:3]):
        if kind == 1:
            assert loc.add_control(item, now) is None  # within the 0.1 s tolerance: taken
        else:
            loc.add_measurement(item.source, item.measurement, now)
    t_end = T0 + int(SECONDS * SEC)
    for t in (loc.committed().stamp_ns, t_end):
        a, b = on_time.estimate_at(t), loc.estimate_at(t)
        np.testing.assert_allclose(b.state, a.state, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-12, atol=1e-15)



def _at_rest_then_commanded(stamp_ns: int, receipt_ns: int):
    """At rest, measured at 100 Hz until ``receipt_ns``; 0.5 m/s commanded with ``stamp_ns``,
    received at ``receipt_ns`` (after the odometry of that time)."""
    loc = make_localizer(ekf_config())
    t = T0
    while t <= receipt_ns:
        loc.add_measurement("odom0", odometry(t, 0.0, 0.0, 0.0), t)
        t += 10_000_000
    assert loc.add_control(ControlCommand(stamp_ns, np.array([0.5, 0, 0, 0, 0, 0])), receipt_ns) is None
    return loc


def test_a_command_received_after_its_latency_acts_from_its_receipt() -> None:
    """A command that arrives after stamp + control_latency (a starved publisher) reached the drive
    late too, and a drive acts on a command when it gets it: the filter is the one that got the
    command on time, stamped its receipt - latency. Acting from stamp + latency instead would put
    40 ms of the drive's ramp (0.11 m/s) in the past, which the robot never drove."""
    ms, latency = 1_000_000, ekf_config().control_latency_ns
    receipt = T0 + 500 * ms
    late = _at_rest_then_commanded(receipt - latency - 40 * ms, receipt)
    on_time = _at_rest_then_commanded(receipt - latency, receipt)
    for t in (receipt, receipt + 10 * ms, receipt + 20 * ms):
        a, b = on_time.estimate_at(t), late.estimate_at(t)
        np.testing.assert_allclose(b.state, a.state, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-12, atol=1e-15)
    assert on_time.estimate_at(receipt).state[3] == pytest.approx(0.0, abs=1e-3)
    assert on_time.estimate_at(receipt + 20 * ms).state[3] > 0.05  # the drive's ramp, from the receipt
