"""A lagged measurement whose rewind would replay more than timeline.MAX_REPLAY_ENTRIES entries is
dropped and counted as ``overloaded`` (issue 35, case 2: under overload, rewinds of lagged camera
poses replaying the whole history each made the filter fall further behind; fusing such a pose
into the current state instead put an old position at the robot's present place)."""

from __future__ import annotations

from helpers.localizer_scenario import T0, camera, ekf_config, odometry, truth_at

from ekf_localization.core.measurements import REJECT_OVERLOADED
from ekf_localization.core.timeline import MAX_REPLAY_ENTRIES
from ekf_localization.models.registry import make_localizer

STEP = 10_000_000


def _localizer_with_history(entries: int):
    loc = make_localizer(ekf_config(history_length=4.0, max_measurement_age=4.0))  # 400 entries
    t = T0
    for _ in range(entries):
        loc.add_measurement("odom0", odometry(t, 0.4, 0.0, 0.3), t)
        t += STEP
    return loc, t - STEP


def test_a_lag_within_the_bound_rewinds() -> None:
    loc, now = _localizer_with_history(40)
    stamp = now - 20 * STEP
    x, y, yaw = truth_at(stamp)[:3]
    loc.add_measurement("pose0", camera(stamp, x, y, yaw), now)
    assert (loc.rewinds, loc.skipped_rewinds) == (1, 0)
    assert loc.stats["pose0"].applied_as_current == 0


def test_a_lag_beyond_the_bound_is_dropped_as_overloaded_and_counted() -> None:
    loc, now = _localizer_with_history(MAX_REPLAY_ENTRIES + 20)
    before = loc.committed()
    stamp = now - (MAX_REPLAY_ENTRIES + 5) * STEP
    x, y, yaw = truth_at(stamp)[:3]
    result = loc.add_measurement("pose0", camera(stamp, x, y, yaw), now)
    assert not result.applied and {r for _, r in result.rejected} == {REJECT_OVERLOADED}, result
    assert (loc.rewinds, loc.skipped_rewinds) == (0, 1)
    st = loc.stats["pose0"]
    assert st.received == 1 and st.rejected[REJECT_OVERLOADED] == len(result.rejected)
    assert st.applied == 0 and st.applied_as_current == 0
    after = loc.committed()  # the state is untouched: nothing stale was fused
    assert after.stamp_ns == before.stamp_ns
    assert (after.state == before.state).all() and (after.covariance == before.covariance).all()
