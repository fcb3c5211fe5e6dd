"""What an input kind's handler is, and what the Localizer lends it (no ROS imports).

The Localizer knows no input kind. Each input (``odom0``, ``imu0``, ``joint0``, ...) has a
handler, built once by its kind (``ekf_localization.inputs``) from the input's settings and a
:class:`FusionContext`. For every message that passed the clock and duplicate checks, the
handler turns the record into updates for the timeline:

    record -> (stamp, ((plan, z, R), ...), applied parts, rejected (part, reason) pairs)

where each plan carries the measurement model (H or h, its gate, its NIS key). A handler
rejects what it cannot fuse with a reason; it never raises on bad data.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.input_frames import InputFrames
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.outcomes import Estimate, SourceStats
from ekf_localization.core.part_plans import PartPlan
from ekf_localization.core.tilt_input import TiltInput


class Fused(NamedTuple):
    """A message's result from its handler."""

    stamp_ns: int  # where its updates act (an encoder speed: the interval's middle)
    updates: tuple[tuple[PartPlan, np.ndarray, np.ndarray], ...]  # (plan, z, R), checked
    applied: tuple[str, ...] = ()  # parts used without an update (tilt, a process input)
    rejected: tuple[tuple[str, str], ...] = ()  # (part, reason)
    fresh: bool = False  # counts as applied though it has no update (an encoder baseline)


class Handler(Protocol):
    """One input's whole path from record to updates."""

    plans: tuple[PartPlan, ...]  # every plan its updates can use (NIS keys, pose recovery)

    def fuse(self, record: Any, stamp_ns: int) -> Fused: ...

    def reset(self) -> None:
        """Forget what earlier messages left (baselines, previous poses) after a filter reset."""


@dataclass
class FusionContext:
    """The Localizer's shared parts a handler may use: built once, never per message.

    ``frames`` puts message parts in the filter's frames (TF); ``tilt`` keeps the IMU's roll
    and pitch for ramps; ``estimate_at(t)`` is the filter's estimate at t without changing it
    (None before the start); ``add_process_input(source, u, stamp)`` puts a process input on
    the timeline and returns a rejection reason or None; ``widen(source, variances, stamp)`` adds
    the (n,) variances to the covariance's diagonal from ``stamp`` on (a slip: the next pose fix is
    then accepted rather than gated), a reason or None; ``checks`` are the checks across
    inputs (:class:`CrossCheck`), which the Localizer runs on every update before it is fused.
    """

    config: EkfConfig
    spec: MotionModelSpec
    field_to_state: dict[int, int]
    x_is_angle: np.ndarray
    stats: dict[str, SourceStats]
    frames: InputFrames
    tilt: TiltInput
    warn: Callable[[str], None]
    estimate_at: Callable[[int], Estimate | None]
    add_process_input: Callable[[str, np.ndarray, int], str | None]
    widen: Callable[[str, np.ndarray, int], str | None]
    checks: list[CrossCheck] = field(default_factory=list)


class CrossCheck(Protocol):
    """A check that compares one input's update with the others' (e.g. wheel speeds against the
    IMU's yaw rate): the reason to refuse the update, or None. It names no input kind."""

    def check(self, source: str, plan: PartPlan, z: np.ndarray, R: np.ndarray,
              stamp_ns: int) -> str | None: ...

    def reset(self) -> None: ...
