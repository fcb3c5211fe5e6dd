"""set_pose at a stamp in the history and older than it (issue 15, defect 5): the pose holds at
its stamp and is predicted to "now" once, with the velocities the filter had.

ROS-free, config/ekf.yaml (history_length 0.5 s, max_measurement_age 1.0 s): the robot drives
straight along +x at 1 m/s, dead-wheel twists only (exact, 100 Hz), then a set_pose puts it
at (3, 1, 0). Predicting the interval between the pose's stamp and now twice (the defect)
would put x at 3 + 2 * age instead of 3 + age (checked: a _put_pose that first carries the
pose to the start of the history fails the 0.8 s case with x = 4.11 for 3.82).
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers.localizer_scenario import SEC, ekf_config, odometry

from ekf_localization.core.measurements import PoseMeasurement
from ekf_localization.models.registry import make_localizer

STEP = 10_000_000
T_START, T_NOW = 5 * SEC, 7 * SEC
SPEED = 1.0


def _driving_localizer():
    loc = make_localizer(ekf_config(initial_state=[0.0] * 15))
    for t in range(T_START, T_NOW + 1, STEP):
        assert loc.add_measurement("odom0", odometry(t, SPEED, 0.0, 0.0), t).applied
        if (t - T_START) % (2 * STEP) == 0:
            loc.advance_to(t)  # ekf_node's 50 Hz output
    return loc


@pytest.mark.parametrize("age_s", [0.2, 0.8])  # inside the 0.5 s history, older than it
def test_set_pose_is_predicted_once_from_its_stamp(age_s: float) -> None:
    loc = _driving_localizer()
    stamp = T_NOW - int(age_s * SEC)
    assert (stamp >= loc.earliest_insertable_ns) == (age_s < 0.5)  # the case the parameter names
    before = loc.estimate_at(T_NOW)
    assert abs(before.state[3] - SPEED) < 1e-3  # tracking the speed before
    pose = PoseMeasurement(stamp, "map", np.array([3.0, 1.0, 0.0, 0.0, 0.0, 0.0]), np.eye(6) * 1e-6)
    assert loc.set_pose(pose, T_NOW) is None
    est = loc.estimate_at(T_NOW)
    assert est.stamp_ns == T_NOW
    out = loc.advance_to(T_NOW + 2 * STEP)  # the next output: from the pose on as well
    assert out is not None and abs(out.state[0] - (3.0 + SPEED * (age_s + 0.02))) < 0.01, out.state[:4]
    x, y, yaw, vx = est.state[0], est.state[1], est.state[2], est.state[3]
    assert abs(x - (3.0 + SPEED * age_s)) < 0.01, (x, 3.0 + SPEED * age_s)  # once, not twice
    assert abs(y - 1.0) < 1e-3 and abs(yaw) < 1e-3
    assert abs(vx - SPEED) < 0.02  # the velocities are kept
    P = est.covariance
    assert np.allclose(P, P.T) and np.linalg.eigvalsh(P).min() >= -1e-12
    assert P[0, 0] < before.covariance[0, 0]  # the pose's covariance replaced the unobserved x's

    # and tracking goes on from there: another second of driving moves x by 1 m
    for t in range(T_NOW + 3 * STEP, T_NOW + SEC + 1, STEP):
        assert loc.add_measurement("odom0", odometry(t, SPEED, 0.0, 0.0), t).applied
    later = loc.advance_to(T_NOW + SEC)
    assert loc.resets == 0
    assert abs(later.state[0] - (x + SPEED)) < 0.02, (later.state[0], x + SPEED)
