"""How each part of an input's messages is fused: which fields, which state rows, which gate.

An input's ``_config`` (robot_localization's 15 booleans) selects fields of its message's parts
(pose, twist, orientation, angular velocity, linear acceleration). A :class:`PartPlan` says,
for one part, which of its fields are fused into which state rows (z = x[rows]: a linear
measurement), the frame they must be in and the Mahalanobis gate. No ROS imports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ekf_localization.core.linear import LinearMeasurement
from ekf_localization.core.measurements import MeasurementPart

# differential inputs (robot_localization's ``_differential``): the part a pose part becomes, and back
RATE_PARTS = {"pose": "pose_rate", "orientation": "orientation_rate"}
SOURCE_PART = {rate: part for part, rate in RATE_PARTS.items()}


@dataclass(frozen=True, eq=False)
class PartPlan:
    """How one part of one input's messages is fused."""

    name: str
    local: np.ndarray  # indices within the part to fuse
    block: tuple[np.ndarray, np.ndarray]  # np.ix_(local, local)
    model: LinearMeasurement
    gate: float
    expected_frame: str
    rows: np.ndarray | None = None  # state components the part observes when the model selects them
    angle_local: tuple[int, ...] = ()  # positions within the part whose residual is wrapped
    nis_key: str = ""  # "input/part": its key in Localizer.nis
    r_checked: bool = False  # its R passed measurements.check_part (finite, symmetric PD) before the update
    widen_above: float = math.inf  # the residual check's NIS bound (core.ekf update; inf: none)


def floor_zero_variances(part: MeasurementPart, fused: np.ndarray, floor: float) -> MeasurementPart:
    """``part`` with a zero variance on a fused field raised to ``floor`` (the same part when it has none)."""
    cov = np.asarray(part.covariance, dtype=float)
    if cov.ndim != 2 or not part.provided:
        return part
    zero = cov[fused, fused] == 0.0
    if not zero.any():
        return part
    cov = cov.copy()
    cov[fused[zero], fused[zero]] = floor
    return replace(part, covariance=cov)
