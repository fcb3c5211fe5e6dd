"""How each part of an input's messages is fused: which fields, which state rows, which gate.

An input's ``_config`` (robot_localization's 15 booleans) selects fields of its message's parts
(pose, twist, orientation, angular velocity, linear acceleration). A :class:`PartPlan` says,
for one part, which of its fields are fused into which state rows (z = x[rows]: a linear
measurement), the frame they must be in and the Mahalanobis gate. No ROS imports.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ekf_localization.core.config import InputConfig
from ekf_localization.core.linear import LinearMeasurement, select_rows
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


def make_plans(inp: InputConfig, field_to_state: dict[int, int], x_is_angle: np.ndarray,
               world_frame: str, base_frame: str) -> tuple[PartPlan, ...]:
    """The plans of every part ``inp`` fuses (a part whose fields the state has not is left out)."""
    plans = []
    n = len(x_is_angle)
    for name, first, length in inp.parts:
        target = first  # the fields a part measures: a differential pose measures their rates
        if inp.differential and name in RATE_PARTS:
            name, target = RATE_PARTS[name], first + 6
        local = [j for j in range(length) if inp.config[first + j] and (target + j) in field_to_state]
        if not local:
            continue
        rows = [field_to_state[target + j] for j in local]
        angle_rows = tuple(r for r in rows if x_is_angle[r])
        idx = np.array(local, dtype=np.intp)
        plans.append(PartPlan(name, idx, np.ix_(idx, idx), select_rows(n, rows, angle_rows),
                              inp.threshold(SOURCE_PART.get(name, name)),
                              world_frame if name == "pose" else base_frame,
                              np.array(rows, dtype=np.intp),
                              tuple(i for i, r in enumerate(rows) if r in angle_rows), f"{inp.name}/{name}",
                              r_checked=True))
    return tuple(plans)


def fusion_plan(inp: InputConfig, field_to_state: dict[int, int], n: int, base_frame: str) -> PartPlan:
    """The plan of an input kind with its own measurement model (``inp.fusion``, inputs.kind.Fusion:
    e.g. a landmark's range and bearing)."""
    model, angle_local = inp.fusion.measurement_model(field_to_state, n)
    local = np.arange(model.m, dtype=np.intp)
    part = inp.fusion.part
    return PartPlan(part, local, np.ix_(local, local), model, inp.threshold(part), base_frame,
                    angle_local=tuple(angle_local), nis_key=f"{inp.name}/{part}")


def process_input_plan(inp: InputConfig, input_fields: tuple[int, ...]) -> tuple[str, np.ndarray] | None:
    """(part name, indices within it) of the model's process-input fields (e.g. an IMU's ax,
    seed 001 eq. 2) when ``inp`` fuses any of them: it supplies the whole input vector."""
    if not any(inp.config[f] for f in input_fields):
        return None
    for name, first, length in inp.parts:
        if all(first <= f < first + length for f in input_fields):
            return name, np.array([f - first for f in input_fields], dtype=np.intp)
    return None


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
