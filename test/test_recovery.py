"""Kidnapped-robot recovery (issue 15, defect 3): a wrong start recovers from agreeing camera fixes.

ROS-free, config/ekf.yaml and the drive of localizer_scenario.py. A ``set_pose`` 1.5 m from
the truth with a small covariance stands for a restarted ekf_node at the path start while the
robot is elsewhere: every camera fix then fails the 5-sigma gate.
"""

from __future__ import annotations

import numpy as np
from helpers.localizer_scenario import (
    SEC,
    T0,
    Event,
    camera,
    drive,
    ekf_config,
    position_error,
    run,
    truth_at,
)

from ekf_localization.core.measurements import REJECT_GATED, PoseMeasurement
from ekf_localization.core.recovery import GatedFixes, RecoveryConfig
from ekf_localization.models.registry import make_localizer


def kidnap(loc, t_ns: int) -> None:
    x, y, yaw, *_ = truth_at(t_ns)
    wrong = PoseMeasurement(t_ns, "map", np.array([x + 1.2, y - 0.9, 0.0, 0.0, 0.0, yaw + 0.4]),
                            np.eye(6) * 1e-4)
    assert loc.set_pose(wrong, t_ns) is None


def kidnapped_run(seconds_after: float, **overrides):
    loc = make_localizer(ekf_config(**overrides))
    run(loc, drive(1.0, seed=4))
    t = T0 + SEC
    kidnap(loc, t)
    gated_before = loc.stats["pose0"].rejected[REJECT_GATED]
    outputs: list = []
    run(loc, drive(seconds_after, seed=5, start_ns=t + 10_000_000), outputs)
    return loc, outputs, loc.stats["pose0"].rejected[REJECT_GATED] - gated_before


def test_wrong_start_recovers_from_agreeing_camera_fixes() -> None:
    loc, outputs, gated = kidnapped_run(3.0)
    assert gated >= 10
    assert loc.pose_recoveries == 1 and loc.stats["pose0"].recoveries == 1
    assert "re-initialised" in loc.last_recovery, loc.last_recovery
    assert 1.4 < float(loc.last_recovery.split("(")[1].split(" m")[0]) < 1.6  # the 1.5 m kidnap
    assert position_error(outputs[-1]) < 0.05
    recovered_at = next(e.stamp_ns for e in outputs if e.stamp_ns > T0 + SEC and position_error(e) < 0.1)
    assert recovered_at - (T0 + SEC) < 2 * SEC  # min_duration 1 s of agreeing fixes, then at once


def test_without_recovery_the_wrong_start_stays_wrong() -> None:
    loc, outputs, gated = kidnapped_run(3.0, pose_recovery=False)
    assert loc.pose_recoveries == 0 and gated > 50
    assert position_error(outputs[-1]) > 1.0


def test_outliers_never_trigger_a_recovery() -> None:
    """Gated outliers scattered over the field while tracking, and after a kidnap: no re-initialisation."""
    rng = np.random.default_rng(7)

    def with_outliers(events, every: int):
        for k, ev in enumerate(events):
            yield ev
            if ev.source == "pose0" and k % every == 0:
                x, y = rng.uniform(-1.8, 1.8, size=2)
                yield Event("pose0", camera(ev.now_ns, x, y, rng.uniform(-3, 3)), ev.now_ns)

    loc = make_localizer(ekf_config())
    run(loc, with_outliers(drive(4.0, seed=6), 2))
    assert loc.stats["pose0"].rejected[REJECT_GATED] > 20 and loc.pose_recoveries == 0
    kidnap(loc, T0 + 4 * SEC)
    only_outliers = (Event("pose0", camera(ev.now_ns, *rng.uniform(-1.8, 1.8, size=2), rng.uniform(-3, 3)),
                           ev.now_ns) if ev.source == "pose0" else ev
                     for ev in drive(3.0, seed=8, start_ns=T0 + 4 * SEC + 10_000_000))
    run(loc, only_outliers)
    assert loc.pose_recoveries == 0


def test_gated_fixes_need_count_duration_and_agreement() -> None:
    cfg = RecoveryConfig(min_fixes=5, min_duration_ns=SEC, agreement=0.2, angle_agreement=0.3)
    run_ = GatedFixes(cfg, np.array([False, False, True]), keep_ns=4 * SEC)
    correction = None
    for k in range(5):  # five agreeing fixes within 0.4 s: too short
        correction = run_.add(k * 100_000_000, np.array([1.0, -0.5, 3.1 if k % 2 else -3.1]))
    assert correction is None
    correction = run_.add(1_100_000_000, np.array([1.02, -0.49, 3.12]))
    assert correction is not None
    assert np.allclose(correction[:2], [1.0, -0.5], atol=0.03)
    assert abs(abs(correction[2]) - 3.12) < 0.03  # the circular median across ±pi, not ~0
    run_.clear()
    assert len(run_) == 0
