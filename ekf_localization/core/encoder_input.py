"""A jointN input: dead-wheel encoder speeds fused with the model's encoder rows (seed 000
eq. 29-33), optionally corrected for the tilt of a ramp (no ROS imports)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ekf_localization.core.config import InputConfig
from ekf_localization.core.joint_states import EncoderSample, EncoderSpeeds
from ekf_localization.core.linalg import symmetrise
from ekf_localization.core.linear import LinearMeasurement
from ekf_localization.core.measurements import JointStateMeasurement
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.part_plans import PartPlan
from ekf_localization.core.tilt import TiltSample, horizontal_projection, projection_tilt_jacobian

ENCODER_PART = "encoders"
TWIST_FIELDS = (6, 7, 11)  # vx vy vyaw: the planar body twist


class EncoderInput:
    """A jointN input: its speed tracker and the model's encoder rows H (``spec.dead_wheel_rows``)."""

    def __init__(self, inp: InputConfig, spec: MotionModelSpec, field_to_state: dict[int, int]) -> None:
        cfg = inp.encoders
        self.config = cfg
        self.speeds = EncoderSpeeds(cfg)
        if spec.dead_wheel_rows is None:
            raise ValueError(f"model '{spec.name}' has no dead-wheel encoder measurement ({inp.name})")
        H = spec.dead_wheel_rows(cfg.half_spacing, cfg.lateral_offset)  # eq. 33
        # the body-twist components [vx vy vyaw] the state has, as (index in the twist, state column)
        present = [j for j, f in enumerate(TWIST_FIELDS) if f in field_to_state]
        self.twist_idx = np.array(present, dtype=np.intp)
        self.cols = np.array([field_to_state[TWIST_FIELDS[j]] for j in present], dtype=np.intp)
        self.H = H
        self.M = H[:, self.cols]  # encoders <- body twist (square: 3x3 or 2x2)
        self.M_inv = np.linalg.inv(self.M)
        m = H.shape[0]
        self.plan = PartPlan(ENCODER_PART, np.arange(m, dtype=np.intp), np.ix_(np.arange(m), np.arange(m)),
                             LinearMeasurement(H), inp.threshold(ENCODER_PART), "",
                             nis_key=f"{inp.name}/{ENCODER_PART}")

    def fuse(self, js: JointStateMeasurement, tilt_at: Callable[[int], TiltSample | None] | None
             ) -> tuple[int, PartPlan, np.ndarray, np.ndarray] | str | None:
        """(stamp, plan, z, R) of a JointState's speeds; or the reason it is rejected; or None for the
        first message (a position baseline, no speed yet). ``tilt_at``: the tilt at a stamp, with
        tilt compensation."""
        sample, reason = self.speeds.update(js)
        if reason is not None or sample is None:
            return reason
        return (sample.stamp_ns, *self.update(sample, None if tilt_at is None else tilt_at(sample.stamp_ns)))

    def update(self, sample: EncoderSample,
               tilt: TiltSample | None) -> tuple[PartPlan, np.ndarray, np.ndarray]:
        """(plan, z = E, R = diag(a·E² + b) (eq. 32)); with a tilt, H = M·P⁻¹ and R gets the tilt term."""
        E = np.asarray(sample.speeds, dtype=float)
        R = np.diag(self.config.variances(E))
        if tilt is None:
            return self.plan, E, R
        idx = self.twist_idx
        P = horizontal_projection(tilt.roll, tilt.pitch)[np.ix_(idx, idx)]
        P_inv = np.linalg.inv(P)
        H = self.H.copy()
        H[:, self.cols] = self.M @ P_inv  # E = M·v_body, v_body = P⁻¹·v_horizontal
        v = np.zeros(3)
        v[idx] = self.M_inv @ E  # body twist implied by the measured speeds
        J = -self.M @ P_inv @ projection_tilt_jacobian(v, tilt.roll, tilt.pitch)[idx]  # ∂h/∂(r, p)
        R = R + J @ tilt.covariance @ J.T
        return replace(self.plan, model=LinearMeasurement(H)), E, symmetrise(R)
