"""The ``joint`` kind's swerve geometry: module states fused as linear rows in the body twist.

Not a kind of its own: ``inputs/joint.py`` builds a :class:`SwerveHandler` for a jointN input
with ``geometry: swerve``. core.swerve_states turns successive messages into each module's speed
along its wheel and steer angle; the update is

    z = [s_i cos φ_i, s_i sin φ_i]_i  (2N),   H = A on the state's [vx vy vyaw],
    R = blockdiag(Rot(φ_i) diag(σ_s,i², ŝ_i² σ_φ² + b) Rot(φ_i)ᵀ)

with A the module rows of models.swerve (uᵢ = (vx − ω yᵢ, vy + ω xᵢ)), σ_s² = a·ŝ² + b +
(r·q/G)²/(6·Δt²) the speed noise along the wheel (as the driven wheels', docs/models.md) and ŝ the
module speed the filter predicts at the sample's stamp (the measured one before there is an
estimate, or with ``speed_variance_at: measured``). Fusing these 2N rows equals fusing the
weighted least-squares twist of the modules with its covariance (docs/models.md, "Swerve
modules"); the rows are fused as they are, so that a check across inputs sees the redundancy.
"""

from __future__ import annotations

import numpy as np

from ekf_localization.core.config import InputConfig
from ekf_localization.core.fusion_context import Fused, FusionContext
from ekf_localization.core.joint_states import EncoderInputConfig, UnitsGuard
from ekf_localization.core.linear import LinearMeasurement
from ekf_localization.core.measurements import JointStateMeasurement
from ekf_localization.core.part_plans import PartPlan
from ekf_localization.core.swerve_states import SwerveSample, SwerveSpeeds
from ekf_localization.core.tilt_input import TWIST_FIELDS
from ekf_localization.core.units import NS_PER_S
from ekf_localization.inputs.joint_sampling import JointSampling
from ekf_localization.inputs.slip import monitor
from ekf_localization.models.swerve import SwerveKinematics, module_covariance, module_vectors


class SwerveHandler(JointSampling):
    """A jointN input of geometry swerve: its module tracker, its units guard and the rows H."""

    def __init__(self, inp: InputConfig, ctx: FusionContext, part: str) -> None:
        cfg: EncoderInputConfig = inp.settings
        self.config = cfg
        self.kinematics = SwerveKinematics(cfg.module_positions)
        self.speeds = SwerveSpeeds(cfg)
        self.guard = UnitsGuard(cfg, inp.name)
        self._stats = ctx.stats[inp.name]
        self._estimate_at = ctx.estimate_at
        missing = [f for f in TWIST_FIELDS if f not in ctx.field_to_state]
        if missing:
            raise ValueError(f"model '{ctx.spec.name}' has no lateral velocity or yaw rate: no swerve "
                             f"modules ({inp.name})")
        self.cols = np.array([ctx.field_to_state[f] for f in TWIST_FIELDS], dtype=np.intp)
        self.A = self.kinematics.module_rows
        m = self.A.shape[0]
        H = np.zeros((m, len(ctx.x_is_angle)))
        H[:, self.cols] = self.A
        self.H = H
        self.part = part
        self.plan = PartPlan(part, np.arange(m, dtype=np.intp), np.ix_(np.arange(m), np.arange(m)),
                             LinearMeasurement(H), inp.threshold(part), "", nis_key=f"{inp.name}/{part}")
        self.plans = (self.plan,)
        self._joints = frozenset(cfg.names) | frozenset(cfg.steer_names)
        if cfg.slip is not None:  # the check across inputs (inputs/slip.py) refuses slipping modules
            monitor(ctx).watch(inp.name, cfg.slip)

    def fuse(self, js: JointStateMeasurement, stamp: int) -> Fused:
        """The modules' velocity vectors since the previous message (the message checks of
        inputs/joint_sampling.py first)."""
        sample, early = self.sample(js, stamp)
        if early is not None:
            return early
        return Fused(sample.stamp_ns, (self.update(sample, self.predicted_state(sample.stamp_ns)),))

    def update(self, sample: SwerveSample, state: np.ndarray | None = None,
               ) -> tuple[PartPlan, np.ndarray, np.ndarray]:
        """(plan, z, R) of the module docstring; ŝ from ``state`` (the measured speeds without)."""
        cfg = self.config
        z = module_vectors(sample.speeds, sample.angles)
        s_hat = np.abs(np.asarray(sample.speeds, dtype=float))
        if state is not None:
            u = (self.A @ np.asarray(state, dtype=float)[self.cols]).reshape(-1, 2)
            predicted = np.hypot(u[:, 0], u[:, 1])
            if np.all(np.isfinite(predicted)):
                s_hat = predicted
        along = cfg.speed_variance_coeff * s_hat * s_hat + cfg.speed_variance_floor
        if sample.interval_ns is not None and cfg.position_resolution > 0.0:
            dt = sample.interval_ns / NS_PER_S
            q_wheel = cfg.position_resolution / cfg.drive_gear_ratio  # one count in rad of the wheel
            along = along + (cfg.wheel_radius * q_wheel) ** 2 / (6.0 * dt * dt)
        across = s_hat * s_hat * cfg.steer_angle_variance + cfg.speed_variance_floor
        return self.plan, z, module_covariance(sample.angles, along, across)
