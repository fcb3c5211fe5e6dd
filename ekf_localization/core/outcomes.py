"""What happened to the Localizer's input, and what it outputs (no ROS imports).

:class:`Estimate` is the published state; :class:`SourceStats` counts each input's messages
(ekf_node's /diagnostics); :class:`AddResult` says what happened to one message's parts;
:class:`Innovation` is one update's residual for consistency checks and tuning.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

CONTROL_SOURCE = "cmd_vel"
WHEEL_COMMAND_SOURCE = "wheel_command"  # std_msgs/Float64MultiArray wheel speeds (wheel_command_topic)
SET_POSE_SOURCE = "set_pose"


@dataclass(frozen=True, eq=False)
class Estimate:
    """The filter's estimate at ``stamp_ns``: state (n,), covariance (n, n), RL field of each component."""

    stamp_ns: int
    state: np.ndarray
    covariance: np.ndarray
    state_fields: tuple[int, ...]
    extra: tuple[tuple[int, float, float], ...] = ()  # (RL field, value, variance) not in the state

    def is_finite(self) -> bool:
        # (a finite sum is the usual case: one reduction each; else the exact test)
        total = np.add.reduce(self.state) + np.add.reduce(self.covariance, axis=None)
        return math.isfinite(total) or bool(np.isfinite(self.state).all()
                                            and np.isfinite(self.covariance).all())


@dataclass
class SourceStats:
    """Per-input counters. ``applied`` and ``rejected`` count message parts (pose, twist, ...)."""

    received: int = 0
    applied: int = 0
    applied_as_current: int = 0  # lagged and fused into the current state (smooth_lagged_data false)
    zero_variances_floored: int = 0  # parts whose zero fused variance was set to zero_variance_floor
    rejected: Counter = field(default_factory=Counter)
    last_stamp_ns: int | None = None
    # on the receiver's clock (None without one): when messages came, when one was last applied
    first_received_clock_ns: int | None = None
    last_received_clock_ns: int | None = None
    last_applied_clock_ns: int | None = None
    last_stamp_lag_ns: int | None = None  # clock minus stamp of the newest message received
    recoveries: int = 0  # kidnapped-robot recoveries from this input's pose fixes
    slips: int = 0  # times this input's wheels were found slipping (inputs.slip)
    widened: int = 0  # updates whose R the residual check widened (first passes; core.ekf update)
    fault: str | None = None  # set by the input's handler: what is likely wrong (an ERROR on /diagnostics)

    def note_received(self, now_ns: int | None, stamp_ns: int) -> None:
        self.received += 1
        if now_ns is not None:
            if self.first_received_clock_ns is None:
                self.first_received_clock_ns = now_ns
            self.last_received_clock_ns = now_ns
            self.last_stamp_lag_ns = now_ns - stamp_ns

    def note_applied(self, now_ns: int | None) -> None:
        if now_ns is not None:
            self.last_applied_clock_ns = now_ns

    def unapplied_for_ns(self, now_ns: int) -> int | None:
        """How long messages have come without one being applied (None: none came, or one is)."""
        if self.first_received_clock_ns is None:
            return None
        since = self.last_applied_clock_ns if self.last_applied_clock_ns is not None \
            else self.first_received_clock_ns
        return now_ns - since

    def recount(self, old: tuple[str | None, ...], new: tuple[str | None, ...]) -> None:
        """A message's parts' outcomes (None: applied) went from ``old`` (() the first time) to
        ``new`` (a replay after a rewind may change them): the counts follow."""
        for o in old:
            if o is None:
                self.applied -= 1
            else:
                self.rejected[o] -= 1
        for o in new:
            if o is None:
                self.applied += 1
            else:
                self.rejected[o] += 1

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())


@dataclass(frozen=True)
class AddResult:
    """What happened to one message: parts applied and (part, reason) pairs rejected."""

    applied: tuple[str, ...] = ()
    rejected: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True, eq=False)
class Innovation:
    """One measurement update's innovation, for consistency checks and tuning (off by default).

    ``seq`` identifies the timeline entry: after a rewind the same (seq, part) is reported
    again with the re-applied values; the last report is the one that stands.
    """

    source: str  # input name, e.g. "odom0"
    part: str  # "pose", "twist", ...
    seq: int
    stamp_ns: int
    nu: np.ndarray  # z - h(x) (m,), angles wrapped
    S: np.ndarray  # H P Hᵀ + R (m, m)
    accepted: bool  # False: gated or the update failed


class NisTally:
    """Running [sum of NIS, count] per update plan ("source/part"), with each one's dimension."""

    def __init__(self, dims: dict[str, int]) -> None:
        self.dims = dims
        self.sums = {key: [0.0, 0] for key in dims}

    def add(self, key: str, nis: float) -> None:
        acc = self.sums[key]
        acc[0] += nis
        acc[1] += 1

    def totals(self) -> dict[str, list[float]]:
        """"source/part" -> [sum of NIS, count, dimension] of the plans with a count (a copy)."""
        return {key: [float(t), int(c), self.dims[key]] for key, (t, c) in self.sums.items() if c > 0}
