"""What every ``jointN`` handler does with a message before its geometry's rows: the one path
from a sensor_msgs/JointState to an interval's sample, shared by the wheel encoders
(inputs/joint.py) and the swerve modules (inputs/swerve.py).

A message with none of the input's joints (another part of the robot on the same topic) is
ignored; the first message is a baseline (nothing to fuse yet); a refused one is counted by the
units guard, which sets the input's fault. The handler sets the attributes named below.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ekf_localization.core.fusion_context import Fused
from ekf_localization.core.measurements import JointStateMeasurement


class JointSampling:
    """The shared part of a jointN handler: ``speeds`` (the tracker), ``guard`` (its units guard),
    ``part`` (the name its rejections carry), ``config``, ``_joints``, ``_stats`` and
    ``_estimate_at``, set by the handler's ``__init__``."""

    part: str
    speeds: Any
    guard: Any
    config: Any
    _joints: frozenset[str]
    _stats: Any
    _estimate_at: Any

    def reset(self) -> None:
        self.speeds.reset()
        self.guard.reset()
        self._stats.fault = None

    def sample(self, js: JointStateMeasurement, stamp: int) -> tuple[Any, Fused | None]:
        """(the interval's sample, None), or (None, the Fused to return without one)."""
        if self._joints.isdisjoint(js.names):
            return None, Fused(stamp, ())
        sample, reason = self.speeds.update(js)
        self._stats.fault = self.guard.note(stamp, reason, self.speeds.last_jump_rate)
        if reason is not None:
            return None, Fused(stamp, (), rejected=((self.part, reason),))
        if sample is None:
            return None, Fused(stamp, (), fresh=True)
        return sample, None

    def predicted_state(self, stamp_ns: int) -> np.ndarray | None:
        """The filter's state at ``stamp_ns`` for the noise's predicted speeds (None: use the
        measured ones, with ``speed_variance_at: measured`` or before the start)."""
        if self.config.speed_variance_at != "predicted":
            return None
        est = self._estimate_at(stamp_ns)
        return None if est is None else est.state
