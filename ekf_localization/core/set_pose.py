"""A ``set_pose`` request checked: where the filter restarts, and with what covariance (no ROS).

The request puts x, y and yaw (those the state has; velocities are kept) at its stamp. A zero
stamp means "now" on the receiver's clock. An all-zero, invalid or implausible covariance
(a standard deviation beyond the field, or beyond π for an angle) says nothing about the pose:
the initial covariance P0 is used instead.
"""

from __future__ import annotations

import math

import numpy as np

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.measurements import (
    REJECT_FRAME,
    REJECT_NONFINITE,
    REJECT_ZERO_STAMP,
    PoseMeasurement,
    covariance_problem,
    implausible,
)
from ekf_localization.core.receive_clock import ReceiveClock

_POSE_FIELDS = (0, 1, 5)  # x, y, yaw
_POSITION_FIELDS = np.array([0, 1], dtype=np.intp)


def checked_pose(pose: PoseMeasurement, config: EkfConfig, clock: ReceiveClock,
                 field_to_state: dict[int, int], x_is_angle: np.ndarray,
                 P0: np.ndarray) -> tuple[int, list[int], np.ndarray, np.ndarray] | str:
    """(stamp, state rows, their values, their covariance) of a set_pose request, or why it is refused."""
    fields = [f for f in _POSE_FIELDS if f in field_to_state]
    values = np.asarray(pose.pose, dtype=float)[fields]
    reason = None
    if not np.all(np.isfinite(values)):
        reason = REJECT_NONFINITE
    elif pose.frame_id.lstrip("/") != config.world_frame:
        reason = REJECT_FRAME
    elif pose.stamp_ns <= 0 and clock.now_ns is None:  # "now" without a clock: no time at all
        reason = REJECT_ZERO_STAMP
    reason = reason or implausible(pose.pose, 0, _POSITION_FIELDS, config.plausible_bounds)
    stamp = int(pose.stamp_ns) if pose.stamp_ns > 0 else (clock.now_ns or 0)
    reason = reason or (clock.stamp_problem(stamp) if pose.stamp_ns > 0 else None)
    if reason is not None:
        return reason
    rows = [field_to_state[f] for f in fields]
    C = np.asarray(pose.covariance, dtype=float)[np.ix_(fields, fields)]
    big = np.diag(C) > np.where(x_is_angle[rows], math.pi, config.max_plausible_position) ** 2
    if covariance_problem(C) is not None or big.any():  # beyond the field: no pose information
        C = P0[np.ix_(rows, rows)]
    return clock.not_ahead(stamp), rows, values, C
