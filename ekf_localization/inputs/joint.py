"""``jointN``: sensor_msgs/JointState of the dead-wheel encoders (ros2_control's
joint_state_broadcaster), fused as their surface speeds (seed 000 eq. 29-33).

core.joint_states turns successive messages into speeds E (m/s) stamped at each interval's
middle; :class:`JointHandler` fuses them as z = E = H x (eq. 33: the model's dead-wheel rows)
with R = diag(a·E² + b) (eq. 32). With ``tilt_compensation`` on a ramp, H = M·P⁻¹ (the wheels
measure the velocity along the surface, the state is horizontal) and R gets the tilt's
uncertainty through J = ∂h/∂(roll, pitch) (core.tilt).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from ekf_localization.core.config import InputConfig
from ekf_localization.core.fusion_context import Fused, FusionContext
from ekf_localization.core.joint_states import (
    EncoderInputConfig,
    EncoderSample,
    EncoderSpeeds,
    validate_encoder_config,
)
from ekf_localization.core.linalg import symmetrise
from ekf_localization.core.linear import LinearMeasurement
from ekf_localization.core.measurements import JointStateMeasurement
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.part_plans import PartPlan
from ekf_localization.core.tilt import TiltSample, horizontal_projection, projection_tilt_jacobian
from ekf_localization.core.tilt_input import TWIST_FIELDS
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.inputs.kind import InputKind, ParameterSpec, Report

ENCODER_PART = "encoders"


def read(msg) -> JointStateMeasurement:
    """Positions rad, velocities rad/s; empty arrays when absent (copies: a bag's are read-only views)."""
    return JointStateMeasurement(
        stamp_ns=stamp_to_ns(msg.header.stamp), names=tuple(str(n) for n in msg.name),
        positions=np.array(msg.position, dtype=float), velocities=np.array(msg.velocity, dtype=float),
        efforts=np.array(msg.effort, dtype=float))


_E = EncoderInputConfig(names=("left", "right", "lateral"))
PARAMETERS = (
    ParameterSpec("names", "str_list", None, "",
                  "joint names [left, right, lateral] (mecanum) or [left, right] (differential; a third is "
                  "ignored with a warning)", required=True),
    ParameterSpec("wheel_radius", "float", _E.wheel_radius, "m",
                  "dead-wheel radius: joint position rad -> distance along the surface"),
    ParameterSpec("half_spacing", "float", _E.half_spacing, "m",
                  "W: the parallel wheels sit at ±W from the centre line (seed 000 eq. 29-30)"),
    ParameterSpec("lateral_offset", "float", _E.lateral_offset, "m",
                  "D: the lateral wheel sits this far behind the centre (negative: in front), "
                  "E_a = vy - D·vyaw (eq. 30)"),
    ParameterSpec("speed_variance_coeff", "float", _E.speed_variance_coeff, "",
                  "a of the per-wheel speed variance a·E² + b (eq. 32)"),
    ParameterSpec("speed_variance_floor", "float", _E.speed_variance_floor, "(m/s)²", "b of a·E² + b"),
    ParameterSpec("use_velocities", "bool", _E.use_velocities, "",
                  "use the message's velocity array (rad/s) when it has one; false: speeds from position "
                  "differences"),
    ParameterSpec("max_speed", "float", _E.max_speed, "m/s",
                  "a position step implying a faster wheel is an encoder reset or wrap: rejected "
                  "(encoder_jump)"),
    ParameterSpec("tilt_compensation", "bool", _E.tilt_compensation, "",
                  "fuse the speeds against the horizontal velocity with the IMU's roll and pitch"),
)


def configure(values: Mapping[str, Any], name: str, spec: MotionModelSpec,
              report: Report) -> EncoderInputConfig | None:
    """A jointN input's dead-wheel settings from its parsed ``values``."""
    key = name + "_names"
    want = spec.dead_wheel_count
    if want == 0:
        report.problem(name, f"no jointN input: model '{spec.name}' has no dead-wheel encoder measurement",
                       values["topic"])
        return None
    what = (f"a list of {want} joint names [left, right{', lateral' if want == 3 else ''}]"
            + (" (a lateral third name is ignored)" if want == 2 else ""))
    names = values["names"]
    if names is None:
        report.problem(key, what + " (required)")
        return None
    if len(names) not in (want, 3) or not all(names):
        report.problem(key, what, names)
        return None
    if len(names) > want:
        report.warn(f"{key}: model '{spec.name}' has no lateral velocity; '{names[2]}' is not used")
        names = names[:want]
    cfg = EncoderInputConfig(names=tuple(names), **{p.name: values[p.name] for p in PARAMETERS[1:]})
    problem = validate_encoder_config(cfg)
    if problem is not None:
        field_name, form = problem.split(": ", 1)
        report.problem(f"{name}_{field_name}", form, values.get(field_name, getattr(cfg, field_name)))
        return None
    return cfg


class JointHandler:
    """A jointN input: its speed tracker and the model's encoder rows H (``spec.dead_wheel_rows``)."""

    def __init__(self, inp: InputConfig, ctx: FusionContext) -> None:
        cfg: EncoderInputConfig = inp.settings
        spec = ctx.spec
        self.config = cfg
        self.speeds = EncoderSpeeds(cfg)
        if spec.dead_wheel_rows is None:
            raise ValueError(f"model '{spec.name}' has no dead-wheel encoder measurement ({inp.name})")
        H = spec.dead_wheel_rows(cfg.half_spacing, cfg.lateral_offset)  # eq. 33
        # the body-twist components [vx vy vyaw] the state has, as (index in the twist, state column)
        present = [j for j, f in enumerate(TWIST_FIELDS) if f in ctx.field_to_state]
        self.twist_idx = np.array(present, dtype=np.intp)
        self.cols = np.array([ctx.field_to_state[TWIST_FIELDS[j]] for j in present], dtype=np.intp)
        self.H = H
        self.M = H[:, self.cols]  # encoders <- body twist (square: 3x3 or 2x2)
        self.M_inv = np.linalg.inv(self.M)
        m = H.shape[0]
        self.plan = PartPlan(ENCODER_PART, np.arange(m, dtype=np.intp), np.ix_(np.arange(m), np.arange(m)),
                             LinearMeasurement(H), inp.threshold(ENCODER_PART), "",
                             nis_key=f"{inp.name}/{ENCODER_PART}")
        self.plans = (self.plan,)
        self._tilt = ctx.tilt if cfg.tilt_compensation else None

    def reset(self) -> None:
        self.speeds.reset()

    def fuse(self, js: JointStateMeasurement, stamp: int) -> Fused:
        """The speeds since the previous message, stamped at the interval's middle; the first
        message is a position baseline (nothing to fuse yet)."""
        sample, reason = self.speeds.update(js)
        if reason is not None:
            return Fused(stamp, (), rejected=((ENCODER_PART, reason),))
        if sample is None:
            return Fused(stamp, (), fresh=True)
        tilt = None if self._tilt is None else self._tilt.at(sample.stamp_ns)
        return Fused(sample.stamp_ns, (self.update(sample, tilt),))

    def update(self, sample: EncoderSample,
               tilt: TiltSample | None) -> tuple[PartPlan, np.ndarray, np.ndarray]:
        """(plan, z = E, R = diag(a·E² + b) (eq. 32)); with a tilt, H = M·P⁻¹ and R gets the tilt term."""
        E = np.asarray(sample.speeds, dtype=float)
        R = np.diag(self.config.variances(E))
        if tilt is None:
            return self.plan, E, R
        idx = self.twist_idx
        P_inv = np.linalg.inv(horizontal_projection(tilt.roll, tilt.pitch)[np.ix_(idx, idx)])
        H = self.H.copy()
        H[:, self.cols] = self.M @ P_inv  # E = M·v_body, v_body = P⁻¹·v_horizontal
        v = np.zeros(3)
        v[idx] = self.M_inv @ E  # body twist implied by the measured speeds
        J = -self.M @ P_inv @ projection_tilt_jacobian(v, tilt.roll, tilt.pitch)[idx]  # ∂h/∂(roll, pitch)
        return replace(self.plan, model=LinearMeasurement(H)), E, symmetrise(R + J @ tilt.covariance @ J.T)


KIND = InputKind("joint", "sensor_msgs/msg/JointState", read, configure, JointHandler,
                 thresholds={"_rejection_threshold": ENCODER_PART}, parameters=PARAMETERS)
