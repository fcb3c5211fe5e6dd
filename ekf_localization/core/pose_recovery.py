"""Kidnapped-robot recovery of every absolute pose input: a run of gated fixes that agree (core.recovery)
re-initialises the pose (no ROS imports)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.measurements import REJECT_GATED
from ekf_localization.core.outcomes import Estimate
from ekf_localization.core.part_plans import PartPlan
from ekf_localization.core.recovery import GatedFixes, RecoveryConfig
from ekf_localization.core.units import NS_PER_S


class PoseRecovery:
    """The runs of gated absolute pose fixes (x, y and/or yaw in the world) of every pose input."""

    def __init__(self, config: RecoveryConfig, plans: dict[str, tuple[PartPlan, ...]],
                 x_is_angle: np.ndarray) -> None:
        keep = 3 * config.min_duration_ns + NS_PER_S
        self._runs = {(name, plan.name): GatedFixes(config, x_is_angle[plan.rows], keep)
                      for name, input_plans in plans.items() for plan in input_plans
                      if plan.name == "pose" and plan.rows is not None and len(plan.rows)}
        self._x_is_angle = x_is_angle

    def note(self, source: str, plan: PartPlan, z: np.ndarray, stamp: int, outcome: str | None,
             estimate_at: Callable[[int], Estimate | None]) -> tuple[np.ndarray, str] | None:
        """A fix's outcome (None: applied). Once a run of gated fixes agrees: (the pose values of
        ``plan.rows`` to re-initialise with, what happened); else None. ``estimate_at(stamp)``
        gives the filter's estimate at a stamp."""
        run = self._runs.get((source, plan.name))
        if run is None or outcome != REJECT_GATED:
            if run is not None and outcome is None:
                run.clear()
            return None
        est = estimate_at(stamp)
        if est is None:
            return None
        h = plan.model.h(est.state[None])[0]
        innovation = z - h
        for i in plan.angle_local:
            innovation[i] = wrap_angle(innovation[i])
        correction = run.add(stamp, innovation)
        if correction is None:
            return None
        linear = [c for c, r in zip(correction, plan.rows, strict=True) if not self._x_is_angle[r]]
        what = (f"{source}: {len(run)} pose fixes in a row failed the gate but agreed: pose "
                f"re-initialised from them ({float(np.linalg.norm(linear)):.2f} m away)")
        run.clear()
        return h + correction, what
