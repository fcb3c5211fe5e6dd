"""The Localizer's compiled fast paths change no result: one call per message
(core.message_step) and one per part (core.measurements.fuse_part).

The same drive, with lagged camera fixes (rewinds) and bad messages mixed in, through the
fast paths and with them disabled (every part then takes check_part / implausible): the
estimates are bitwise equal, and so are every counter and the NIS sums.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from helpers.localizer_scenario import Event, drive, ekf_config, run

import ekf_localization.core.localizer as localizer_module
from ekf_localization.models.registry import make_localizer


def _events(seed: int) -> list[Event]:
    rng = np.random.default_rng(seed)
    out = []
    for ev in drive(3.0, seed=seed):
        m = ev.measurement
        roll = rng.random()
        if ev.source == "pose0":
            ev = replace(ev, now_ns=ev.now_ns + 60_000_000)  # 60 ms late: inserted by a rewind
        elif ev.source == "odom0" and roll < 0.03:
            twist = m.twist.copy()
            twist[0] = np.nan if roll < 0.01 else (1e6 if roll < 0.02 else twist[0])
            cov = m.twist_covariance.copy()
            if roll >= 0.02:
                cov[0, 0] = 0.0  # a zero variance: floored
            ev = replace(ev, measurement=replace(m, twist=twist, twist_covariance=cov))
        elif ev.source == "imu0" and roll < 0.01:
            cov = m.angular_velocity_covariance.copy()
            cov[2, 2] = -1e-4  # not positive definite
            ev = replace(ev, measurement=replace(m, angular_velocity_covariance=cov))
        out.append(ev)
    return sorted(out, key=lambda e: e.now_ns)


def _run(events, steps: bool = True, **overrides):
    loc = make_localizer(ekf_config(**overrides))
    if not steps:
        loc._steps.clear()  # no one-call messages (core.message_step): lanes and the general path
    outputs: list = []
    run(loc, events, outputs)
    stats = {k: (s.applied, dict(s.rejected), s.zero_variances_floored, s.applied_as_current)
             for k, s in loc.stats.items()}
    return outputs, stats, loc.rewinds, loc.nis


def _assert_same(a_run, b_run) -> None:
    (a_out, a_stats, a_rewinds, a_nis), (b_out, b_stats, b_rewinds, b_nis) = a_run, b_run
    assert a_rewinds == b_rewinds
    assert a_stats == b_stats
    assert a_nis == b_nis  # the same squared distances, summed in the same order
    assert len(a_out) == len(b_out) > 100
    for a, b in zip(a_out, b_out, strict=True):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.state, b.state)
        np.testing.assert_array_equal(a.covariance, b.covariance)


@pytest.mark.parametrize("seed", [0, 1])
def test_fast_path_changes_nothing(seed, monkeypatch):
    events = _events(seed)
    fast = _run(events)
    lanes = _run(events, steps=False)
    monkeypatch.setattr(localizer_module, "fuse_part", lambda *args: 1)  # never a lane
    slow = _run(events, steps=False)
    assert fast[2] > 0  # rewinds replay one-call entries
    _assert_same(fast, slow)
    _assert_same(lanes, slow)
    rejected = fast[1]["odom0"][1]
    assert rejected.get("nonfinite", 0) > 0 and rejected.get("implausible_value", 0) > 0
    assert fast[1]["odom0"][2] > 0 and fast[1]["imu0"][1].get("bad_covariance", 0) > 0


@pytest.mark.parametrize("overrides", [{"smooth_lagged_data": False},
                                       {"model": "differential", "use_control": False},
                                       {"odom0_twist_rejection_threshold": 0.5}],
                         ids=["no-smoothing", "differential", "gated"])
def test_one_call_messages_change_nothing(overrides):
    """Without smoothing (lagged fixes fused as current), on the tank model, and with updates
    gated: the one-call messages give the state, counts and NIS of the separate calls."""
    events = _events(2)
    fast = _run(events, **overrides)
    _assert_same(fast, _run(events, steps=False, **overrides))
    if "odom0_twist_rejection_threshold" in overrides:
        assert fast[1]["odom0"][1].get("mahalanobis_gate", 0) > 10


def _calls_on_odometry_and_imu(monkeypatch, method: str):
    """(calls of Localizer.<method>, the Localizer, its bad messages) on _events(0)'s odometry and IMU."""
    events = [e for e in _events(0) if e.source in ("odom0", "imu0")]
    calls = {"n": 0}
    original = getattr(localizer_module.Localizer, method)

    def counting(self, *args):
        calls["n"] += 1
        return original(self, *args)

    monkeypatch.setattr(localizer_module.Localizer, method, counting)
    loc = make_localizer(ekf_config())
    run(loc, events, [])
    bad = sum(loc.stats[s].rejected_total + loc.stats[s].zero_variances_floored for s in ("odom0", "imu0"))
    return calls["n"], loc, bad


def test_one_call_messages_are_taken(monkeypatch):
    """Clean odometry and IMU messages take one compiled call each (Localizer._step): no lane."""
    calls, loc, bad = _calls_on_odometry_and_imu(monkeypatch, "_lane_updates")
    assert 0 < calls <= bad + 2  # the first message (it initialises the filter), and the bad ones
    assert loc.stats["odom0"].applied > 200


def test_arrays_the_kernel_is_not_typed_for_take_the_general_path():
    """float32 arrays in a record: not typed for the one-call kernel, so that input's messages
    take the separate calls from then on, with the same result as a Localizer that never tried."""
    events = [e for e in _events(3) if e.source in ("odom0", "imu0")]
    events = [replace(e, measurement=replace(e.measurement, twist=e.measurement.twist.astype(np.float32)))
              if e.source == "odom0" and i > 50 else e for i, e in enumerate(events)]
    tried = _run(events)
    assert tried[1]["odom0"][0] > 200
    _assert_same(tried, _run(events, steps=False))


def test_clean_messages_take_the_lane(monkeypatch):
    """A clean message in the filter's frames builds no parts and takes no general path: the
    lane (Localizer._lane_updates) is what the test above compares against the general path."""
    calls, loc, bad = _calls_on_odometry_and_imu(monkeypatch, "_in_filter_frames")
    assert 0 < calls <= bad + 2  # the first message of each input, and the bad ones
    assert loc.stats["odom0"].applied > 200


def test_batched_history_deletes_change_nothing(monkeypatch):
    """Entries older than history_length are deleted from the history's list in batches
    (_PRUNE_BATCH): camera fixes lagged around history_length are applied or rejected as when
    they are deleted one stamp at a time, with the same states, and history_size,
    earliest_insertable_ns and the estimates from the oldest entry agree after every message."""
    lags_ms = [0, 300, 480, 490, 495, 499, 500, 501, 505, 510, 520, 550]  # history_length: 0.5 s
    events = []
    for ev in drive(3.0, seed=4):
        if ev.source == "pose0":
            lag = lags_ms[sum(e.source == "pose0" for e in events) % len(lags_ms)]
            ev = replace(ev, now_ns=ev.now_ns + lag * 1_000_000)
        events.append(ev)
    events.sort(key=lambda e: e.now_ns)

    def trace():
        loc = make_localizer(ekf_config())
        seen = []
        for ev in events:
            result = loc.add_measurement(ev.source, ev.measurement, ev.now_ns)
            c = loc.committed()
            earliest = loc.earliest_insertable_ns
            oldest = loc.estimate_at(earliest)
            seen.append((result, loc.history_size, earliest, c.state.tobytes(), c.covariance.tobytes(),
                         oldest.state.tobytes(), oldest.covariance.tobytes()))
        return seen, loc.rewinds, dict(loc.stats["pose0"].rejected), loc.nis

    batched = trace()
    monkeypatch.setattr(localizer_module, "_PRUNE_BATCH", 0)  # every entry deleted as it leaves
    single = trace()
    assert batched[1] > 50 and batched[2].get("older_than_history", 0) > 3  # both sides of the edge
    assert batched == single
