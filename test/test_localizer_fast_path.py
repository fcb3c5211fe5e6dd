"""The Localizer's compiled fast path (core.measurements.fuse_part) changes no result.

The same drive, with lagged camera fixes (rewinds) and bad messages mixed in, through the
fast path and with it disabled (every part then takes check_part / implausible): the
estimates are bitwise equal and every counter is the same.
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


def _run(events):
    loc = make_localizer(ekf_config())
    outputs: list = []
    run(loc, events, outputs)
    stats = {k: (s.applied, dict(s.rejected), s.zero_variances_floored) for k, s in loc.stats.items()}
    return outputs, stats, loc.rewinds


@pytest.mark.parametrize("seed", [0, 1])
def test_fast_path_changes_nothing(seed, monkeypatch):
    events = _events(seed)
    fast_out, fast_stats, fast_rewinds = _run(events)
    monkeypatch.setattr(localizer_module, "fuse_part", lambda *args: 1)  # never the fast path
    slow_out, slow_stats, slow_rewinds = _run(events)
    assert fast_rewinds == slow_rewinds > 0
    assert fast_stats == slow_stats
    rejected = fast_stats["odom0"][1]
    assert rejected.get("nonfinite", 0) > 0 and rejected.get("implausible_value", 0) > 0
    assert fast_stats["odom0"][2] > 0 and fast_stats["imu0"][1].get("bad_covariance", 0) > 0
    assert len(fast_out) == len(slow_out) > 100
    for a, b in zip(fast_out, slow_out, strict=True):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.state, b.state)
        np.testing.assert_array_equal(a.covariance, b.covariance)


def test_clean_messages_take_the_lane(monkeypatch):
    """A clean message in the filter's frames builds no parts and takes no general path: the
    lane (Localizer._lane_updates) is what the test above compares against the general path."""
    events = [e for e in _events(0) if e.source in ("odom0", "imu0")]
    general = {"calls": 0}
    original = localizer_module.Localizer._in_filter_frames

    def counting(self, *args):
        general["calls"] += 1
        return original(self, *args)

    monkeypatch.setattr(localizer_module.Localizer, "_in_filter_frames", counting)
    loc = make_localizer(ekf_config())
    run(loc, events, [])
    bad = sum(loc.stats[s].rejected_total + loc.stats[s].zero_variances_floored for s in ("odom0", "imu0"))
    assert 0 < general["calls"] <= bad + 2  # the first message of each input, and the bad ones
    assert loc.stats["odom0"].applied > 200
