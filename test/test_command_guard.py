"""core.command_guard through the Localizer (ROS-free): the blocked and the frozen robot of
issue 34 (helpers/guard_scenario.py) on config/ekf.yaml, and the guard's χ² test alone.

Bounds: the issue's (blocked: moves < 3 cm, 3σ covers the truth, says "not followed" within
0.5 s; frozen: 3σ covers the truth throughout, error < 10 cm within 2 s of the sensors' return).
test_command_guard_dds.py asserts the same of ekf_node over DDS.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.guard_scenario import EVENT_S, RECOVER_S, SEC, T0, events, truth_at, truths
from helpers.localizer_scenario import ekf_config
from scipy.stats import chi2

from ekf_localization.core.command_guard import CommandGuard
from ekf_localization.models.registry import make_localizer


def run(name: str, **overrides) -> tuple[np.ndarray, list[tuple[float, bool]]]:
    """Rows [t s, position error, largest position std, x] at 50 Hz, and (t s, followed) changes."""
    loc = make_localizer(ekf_config(**overrides))
    truth = truths(name)
    rows, changes, next_out, followed = [], [], None, True
    for ev in events(name):
        next_out = ev.now_ns if next_out is None else next_out
        while next_out <= ev.now_ns:
            est = loc.advance_to(next_out)
            if est is not None:
                err = est.state[:2] - truth_at(truth, next_out)[:2]
                sd = math.sqrt(max(np.linalg.eigvalsh(est.covariance[:2, :2])))
                rows.append(((next_out - T0) / SEC, math.hypot(*err), sd, est.state[0]))
            next_out += 20_000_000
        if ev.source == "cmd_vel":
            loc.add_control(ev.measurement, ev.now_ns)
        else:
            loc.add_measurement(ev.source, ev.measurement, ev.now_ns)
        g = loc.command_guard
        if g is not None and g.followed != followed:
            followed = g.followed
            changes.append(((ev.now_ns - T0) / SEC, followed))
    return np.array(rows), changes


def between(rows: np.ndarray, a: float, b: float) -> np.ndarray:
    return rows[(rows[:, 0] >= a) & (rows[:, 0] < b)]


def test_blocked_robot_is_not_followed_and_stays_put() -> None:
    rows, changes = run("blocked")
    t0, t1 = EVENT_S["blocked"], RECOVER_S["blocked"]
    blocked = between(rows, t0, t1)
    assert abs(blocked[-1, 3] - blocked[0, 3]) < 0.03
    assert np.all(blocked[:, 1] <= 3 * blocked[:, 2])
    assert changes[0][1] is False and t0 <= changes[0][0] <= t0 + 0.5, changes
    assert changes[-1][1] is True and t1 < changes[-1][0] < t1 + 1.0, changes  # follows again
    assert between(rows, t1 + 1.0, t1 + 2.0)[:, 1].max() < 0.03


def test_blocked_robot_runs_away_without_the_guard() -> None:
    """The peer: what the issue measured (the estimate moves with the command, 3σ misses)."""
    rows, _ = run("blocked", control_guard=False)
    blocked = between(rows, EVENT_S["blocked"], RECOVER_S["blocked"])
    assert blocked[-1, 1] > 0.1 and blocked[-1, 1] > 3 * blocked[-1, 2]


def test_frozen_robot_covariance_covers_the_truth() -> None:
    rows, changes = run("frozen")
    assert np.all(rows[rows[:, 0] >= 1.0, 1] <= 3 * rows[rows[:, 0] >= 1.0, 2])  # after the first fixes
    after = between(rows, RECOVER_S["frozen"] + 2.0 - 0.02, RECOVER_S["frozen"] + 2.0)
    assert after[:, 1].max() < 0.10
    assert not any(followed is False for _, followed in changes if _ < EVENT_S["frozen"]), changes


def test_frozen_robot_without_the_guard_is_overconfident() -> None:
    rows, _ = run("frozen", control_guard=False)
    frozen = between(rows, EVENT_S["frozen"], RECOVER_S["frozen"])
    assert frozen[-1, 1] > 0.5 and frozen[-1, 1] > 3 * frozen[-1, 2]


class _Ekf:  # the guard's view of a filter, for its test alone
    def __init__(self) -> None:
        self.x = np.zeros(6)


@pytest.mark.parametrize("scale, trips", [(1.0, False), (30.0, True)])
def test_window_chi2_trips_on_the_quantile(scale: float, trips: bool) -> None:
    """A window of NIS values at the χ²(3) mean does not trip at 1e-3; thirty times it does at
    the χ²(Σm) quantile."""
    g = CommandGuard(250_000_000, 1e-3, 30_000_000, (0, 1, 5, 6, 7, 11))
    S = np.eye(3)
    for k in range(25):
        g.observe(k * 10_000_000, [3, 4, 5], np.zeros(6), np.ones(3), S, 3.0 * scale, np.zeros(3), None, None)
        if not g.followed:
            break
    assert g.followed is (not trips)
    if trips:
        total, dof, bound = g.statistic
        assert bound == pytest.approx(chi2.ppf(1 - 1e-3, dof))
        assert total > bound and g.trips == 1
