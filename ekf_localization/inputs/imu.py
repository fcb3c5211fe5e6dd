"""``imuN``: sensor_msgs/Imu, orientation as roll, pitch, yaw (RL's imuN; REP-145: a covariance
whose first entry is -1 means the message has no such data).

Besides its fused parts (inputs/py), an IMU may carry two things the model uses:

* the **tilt** of a ramp: an imuN fusing roll and pitch supplies them (core.tilt_input), and
  inputs with ``tilt_compensation`` project their velocities with it;
* the model's **process input**: a model whose ``input_fields`` a message carries (the
  differential model's forward acceleration, seed 001 eq. 2) takes it from this message, in
  effect from its stamp;
* the **slip check**'s references (inputs/slip.py): with a jointN input's ``slip_detection``,
  its gyro z and planar acceleration, fused or not.

A gyro's z axis is corrected before anything uses it: ``(measured - yaw_rate_bias) /
yaw_rate_scale``, its variance divided by ``yaw_rate_scale²`` (docs/models.md, "IMU yaw-rate
scale and bias"; ekf_calibrate fits both).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ekf_localization.core.angles import quaternion_to_rpy
from ekf_localization.core.config import InputConfig
from ekf_localization.core.fusion_context import Fused, FusionContext
from ekf_localization.core.measurements import ImuMeasurement, MeasurementPart, check_part, implausible
from ekf_localization.core.tilt_input import horizontal_velocity
from ekf_localization.inputs.kind import InputKind, ParameterSpec, covariance, header_of
from ekf_localization.inputs.parts import COMMON, PartsHandler, PartsSettings, configure_parts
from ekf_localization.inputs.slip import monitor, wanted

PARTS = (("orientation", 3, 3), ("angular_velocity", 9, 3), ("linear_acceleration", 12, 3))
TILT_FIELDS = (3, 4)  # roll and pitch: an imuN fusing both supplies the tilt (core.tilt)
TILT_PART = "tilt"
YAW_RATE = 2  # the gyro's z axis within angular_velocity

PARAMETERS = (
    ParameterSpec("yaw_rate_scale", "float", 1.0, "",
                  "the gyro's z-axis scale: the yaw rate used is (measured - yaw_rate_bias) / yaw_rate_scale "
                  "(ekf_calibrate fits it; not in RL)",
                  lambda v: math.isfinite(v) and v > 0.0, "a finite factor > 0"),
    ParameterSpec("yaw_rate_bias", "float", 0.0, "rad/s",
                  "the gyro's z-axis bias, subtracted before the scale (ekf_calibrate fits it; not in RL)",
                  math.isfinite, "a finite float"),
)


@dataclass(frozen=True)
class ImuSettings(PartsSettings):
    """An imuN input's settings: its parts' and its gyro z calibration."""

    yaw_rate_scale: float = 1.0
    yaw_rate_bias: float = 0.0  # rad/s


def read(msg) -> ImuMeasurement:
    stamp, frame = header_of(msg)
    q, a, acc = msg.orientation, msg.angular_velocity, msg.linear_acceleration
    return ImuMeasurement(
        stamp_ns=stamp, frame_id=frame, orientation=np.array(quaternion_to_rpy(q.x, q.y, q.z, q.w)),
        orientation_covariance=covariance(msg.orientation_covariance, 3),
        angular_velocity=np.array([a.x, a.y, a.z], dtype=float),
        angular_velocity_covariance=covariance(msg.angular_velocity_covariance, 3),
        linear_acceleration=np.array([acc.x, acc.y, acc.z], dtype=float),
        linear_acceleration_covariance=covariance(msg.linear_acceleration_covariance, 3))


def _tilt_source(config: tuple[bool, ...]) -> bool:
    return all(config[f] for f in TILT_FIELDS)


def configure(values, name, spec, report) -> ImuSettings:
    extra = frozenset(TILT_FIELDS) if _tilt_source(values["config"]) else frozenset()
    parts = configure_parts(values, name, spec, report, "imu", PARTS, extra_fields=extra)
    return ImuSettings(**vars(parts), yaw_rate_scale=values["yaw_rate_scale"],
                       yaw_rate_bias=values["yaw_rate_bias"])


def corrected_yaw_rate(m: ImuMeasurement, scale: float, bias: float) -> ImuMeasurement:
    """``m`` with its gyro z as ``(z - bias) / scale`` and that row and column of its covariance
    divided by ``scale`` (a variance by scale²)."""
    w = np.array(m.angular_velocity, dtype=float)
    w[YAW_RATE] = (w[YAW_RATE] - bias) / scale
    C = np.array(m.angular_velocity_covariance, dtype=float)
    if C[0, 0] != -1.0:  # REP-145's "not provided" flag stays as it is
        C[YAW_RATE, :] /= scale
        C[:, YAW_RATE] /= scale
    return replace(m, angular_velocity=w, angular_velocity_covariance=C)


def _process_input(settings: PartsSettings,
                   input_fields: tuple[int, ...]) -> tuple[str, np.ndarray] | None:
    """(part name, indices within it) of the model's process-input fields when the input fuses
    any of them: that part supplies the whole input vector."""
    if not any(settings.config[f] for f in input_fields):
        return None
    for name, first, length in settings.parts:
        if all(first <= f < first + length for f in input_fields):
            return name, np.array([f - first for f in input_fields], dtype=np.intp)
    return None


class ImuHandler(PartsHandler):
    """An imuN input: its parts, and its tilt and process input (module docstring)."""

    def __init__(self, inp: InputConfig, ctx: FusionContext) -> None:
        s: ImuSettings = inp.settings
        gyro = (s.yaw_rate_scale, s.yaw_rate_bias)
        self._gyro = gyro if gyro != (1.0, 0.0) else None  # None: the message as it is
        self._tilt_source = _tilt_source(inp.settings.config)
        self._input = _process_input(inp.settings, ctx.spec.input_fields)
        extra = {"orientation"} if self._tilt_source else set()
        if self._input is not None:
            extra.add(self._input[0])
        self._slip = monitor(ctx) if wanted(ctx) else None
        if self._slip is not None:
            extra |= {"angular_velocity", "linear_acceleration"}
        super().__init__(inp, ctx, extra)

    def fuse(self, record: Any, stamp: int) -> Fused:
        if self._gyro is not None:
            record = corrected_yaw_rate(record, *self._gyro)
        return super().fuse(record, stamp)

    def _velocity_at(self, t: int) -> tuple[float, float, np.ndarray] | None:
        return horizontal_velocity(self._ctx.estimate_at(t), self._ctx.field_to_state)

    def extras(self, parts_: dict[str, MeasurementPart], no_transform: dict[str, str],
               stamp: int) -> tuple[tuple[str, ...], list[tuple[str, str]]]:
        applied: tuple[str, ...] = ()
        rejected: list[tuple[str, str]] = []
        if self._tilt_source:
            reason = no_transform.get("orientation") \
                or self._ctx.tilt.add(parts_["orientation"], stamp, self._velocity_at)
            if reason is None:
                applied = (TILT_PART,)
            else:
                rejected.append((TILT_PART, reason))
        w, a = parts_.get("angular_velocity"), parts_.get("linear_acceleration")
        if self._slip is not None and w is not None and a is not None and w.provided and a.provided:
            self._slip.note_imu(stamp, w.values[2], w.covariance[2, 2], a.values[:2], a.covariance[:2, :2])
        if self._input is not None:
            name, local = self._input
            reason = no_transform.get(name) or self._add_process_input(parts_[name], local, stamp)
            if reason is None:
                applied += (name,)
            else:
                rejected.append((name, reason))
        return applied, rejected

    def _add_process_input(self, part: MeasurementPart, local: np.ndarray, stamp: int) -> str | None:
        """The model's process input (``spec.input_fields`` of ``part``) in effect from ``stamp`` on."""
        reason = check_part(part, local, self._ctx.config.base_link_frame) \
            or implausible(part.values, part.first_field, local, self._plausible)
        if reason is not None:
            return reason
        return self._ctx.add_process_input(self.name, np.asarray(part.values, dtype=float)[local], stamp)


def handler(inp: InputConfig, ctx: FusionContext) -> Any:
    return ImuHandler(inp, ctx)


KIND = InputKind("imu", "sensor_msgs/msg/Imu", read, configure, handler, parts=PARTS,
                 thresholds={"_pose_rejection_threshold": "orientation",
                             "_twist_rejection_threshold": "angular_velocity",
                             "_angular_velocity_rejection_threshold": "angular_velocity",
                             "_linear_acceleration_rejection_threshold": "linear_acceleration"},
                 common=COMMON, parameters=PARAMETERS)
