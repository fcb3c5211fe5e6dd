"""Time-ordered sensor fusion around the EKF: what ekf_node, bag_replay, ekf_tune and the
benchmarks all run, one path for every message (no ROS imports).

:class:`Localizer` only orchestrates. A message goes: the receiver's clock and duplicate checks
-> its input's handler (core.fusion_context: each input kind owns its path from record to
updates) -> the checks across inputs -> the timeline (core.timeline: in stamp order, a lagged
message rewinds and replays) -> the EKF update -> the counters (per input, NIS, /diagnostics).
Commands (cmd_vel, wheel commands) go to the timeline as process inputs (core.command_model,
whose guard drops commands the drive does not follow).

* **Output** (core.filter_output, its base class): a prediction of a copy of the committed
  state; publishing never moves the filter.
* **Clock.** ``now_ns`` (ROS time, or a bag's receive time) rejects stale and far-future
  stamps; the clock going backwards (a bag loop, a simulator restart) resets the filter.
* **Bad input** is rejected with a reason and counted per source; estimates stay finite.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.command_model import Command, CommandInput
from ekf_localization.core.config import EkfConfig
from ekf_localization.core.duplicates import RecentMessages, content_digest
from ekf_localization.core.ekf import ExtendedKalmanFilter
from ekf_localization.core.filter_output import FilterOutput
from ekf_localization.core.fusion_context import Fused, FusionContext
from ekf_localization.core.input_frames import InputFrames
from ekf_localization.core.measurements import (
    REJECT_DUPLICATE,
    REJECT_UNREADABLE,
    REJECT_WHEEL_COUNT,
    ControlCommand,
    PoseMeasurement,
)
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.outcomes import (
    CONTROL_SOURCE,
    SET_POSE_SOURCE,
    WHEEL_COMMAND_SOURCE,
    AddResult,
    Estimate,
    Innovation,
    NisTally,
    SourceStats,
)
from ekf_localization.core.pose_recovery import PoseRecovery
from ekf_localization.core.receive_clock import ReceiveClock
from ekf_localization.core.set_pose import checked_pose
from ekf_localization.core.tilt_input import TiltInput
from ekf_localization.core.timeline import Entry, Timeline
from ekf_localization.core.units import NS_PER_S, seconds_to_ns
from ekf_localization.core.update_step import UpdateStep

__all__ = ["CONTROL_SOURCE", "SET_POSE_SOURCE", "WHEEL_COMMAND_SOURCE", "AddResult", "Estimate",
           "Innovation", "Localizer", "SourceStats"]


class Localizer(FilterOutput):
    """The estimation core of ekf_node: see the module docstring.

    ``spec`` is the motion model ``config.model`` names (``models.registry.make_localizer``
    looks it up); its process model is built from ``config``.
    """

    def __init__(self, config: EkfConfig, spec: MotionModelSpec,
                 warn: Callable[[str], None] | None = None) -> None:
        if spec.name != config.model:
            raise ValueError(f"config.model is {config.model!r} but the model given is {spec.name!r}")
        self.config, self.spec, self.model = config, spec, spec.build(config)
        self._warn = warn or (lambda text: None)
        self.state_fields = spec.state_fields
        if len(self.state_fields) != self.model.n:
            raise ValueError(f"model state has {self.model.n} components, layout {len(self.state_fields)}")
        fields = list(self.state_fields)
        self._field_to_state = {f: i for i, f in enumerate(fields)}
        self._x_is_angle = np.asarray(self.model.x_is_angle, dtype=bool)
        x0 = np.asarray(config.initial_state, dtype=float)[fields].copy()
        for i in np.flatnonzero(self._x_is_angle):
            x0[i] = wrap_angle(x0[i])
        self._P0 = np.asarray(config.initial_estimate_covariance, dtype=float)[np.ix_(fields, fields)].copy()
        self.stats: dict[str, SourceStats] = {name: SourceStats() for name in (
            *(inp.name for inp in config.inputs), CONTROL_SOURCE, WHEEL_COMMAND_SOURCE, SET_POSE_SOURCE)}
        self._clock = ReceiveClock(config.max_measurement_age_ns, config.future_stamp_tolerance_ns)
        self._frames = InputFrames(config, self._warn)
        self.transforms = self._frames.transforms
        self._tilt = TiltInput(max(config.history_length_ns, 0) + seconds_to_ns(1.0), config.base_link_frame)
        ctx = FusionContext(config, spec, self._field_to_state, self._x_is_angle, self.stats, self._frames,
                            self._tilt, self._warn, self.estimate_at, self._add_process_input,
                            lambda source, var, stamp: self._insert(Entry(stamp, source, widen=var)))
        self._handlers = {inp.name: inp.handler(inp, ctx) for inp in config.inputs}
        self.checks = ctx.checks  # the checks across inputs (e.g. inputs.slip), run on every update
        plans = {name: h.plans for name, h in self._handlers.items()}
        self._nis = NisTally({p.nis_key: p.model.m for ps in plans.values() for p in ps})
        self._recovery = PoseRecovery(config.recovery, plans, self._x_is_angle)
        self._commands = CommandInput(config, spec, self.state_fields)
        self.command_guard = self._commands.guard
        self._recent = RecentMessages()  # the same message delivered twice is fused once
        self.resets = self.predict_failures = self.nonfinite_outputs = self.pose_recoveries = 0
        self.last_reset_reason = self.last_recovery = ""
        self._last_output_ns: int | None = None
        history = config.history_length_ns if config.smooth_lagged_data else None
        self._step = UpdateStep(self.stats, self._nis, self.command_guard, self.model)
        self._timeline = self._step.timeline = Timeline(ExtendedKalmanFilter(self.model, x0, self._P0),
                                                        self._commands.model, history, self._step)

    def start(self, t_ns: int) -> None:
        """Initialise at ``t_ns`` with ``initial_state`` (done by the first measurement otherwise)."""
        self._timeline.start(int(t_ns))
        self._last_output_ns = None

    def reset(self, reason: str) -> None:
        """Forget everything but the counters; the next measurement starts the filter again."""
        self.resets += 1
        self.last_reset_reason = reason
        self._warn(f"filter reset: {reason}")
        self._timeline.clear()
        self._last_output_ns = None
        self._frames.reset()
        self._recent.clear()
        self._tilt.clear()
        for part in (*self._handlers.values(), *self.checks):
            part.reset()

    def _observe_clock(self, now_ns: int | None) -> int | None:
        back = self._clock.observe(now_ns)
        if back is not None:
            self.reset(f"time went backwards by {back / NS_PER_S:.3f} s (bag loop or simulator restart?)")
        return None if now_ns is None else self._clock.now_ns

    # --- input -------------------------------------------------------------------------------

    def add_measurement(self, source: str, measurement: Any, now_ns: int | None = None) -> AddResult:
        """Check and fuse one record of input ``source`` (e.g. "odom0") at its stamp."""
        stats = self.stats[source]
        now = self._observe_clock(now_ns)
        stamp = int(measurement.stamp_ns)
        stats.note_received(now, stamp)
        reason = self._clock.stamp_problem(stamp)
        if reason is None and self._recent.is_duplicate(source, stamp, content_digest(measurement)):
            reason = REJECT_DUPLICATE
        if reason is not None:
            stats.rejected[reason] += 1
            return AddResult(rejected=(("message", reason),))
        stamp = self._clock.not_ahead(stamp)
        fused = self._handlers[source].fuse(measurement, stamp)
        rejected = list(fused.rejected)
        updates = self._cross_checked(source, fused, rejected)
        for _, reason in rejected:
            stats.rejected[reason] += 1
        stats.applied += len(fused.applied)
        if rejected and rejected[0][0] == "message":  # nothing of the message was used
            return AddResult(rejected=tuple(rejected))
        stats.last_stamp_ns = stamp
        if not updates:
            if fused.applied or fused.fresh:
                stats.note_applied(now)
            return AddResult(applied=fused.applied, rejected=tuple(rejected))
        return self._add_updates(source, stats, fused.stamp_ns, updates, fused.applied, rejected, now)

    def _cross_checked(self, source: str, fused: Fused, rejected: list[tuple[str, str]]) -> tuple:
        """The updates that pass every check across inputs (the others join ``rejected``)."""
        if not self.checks:
            return fused.updates
        kept = []
        for plan, z, R in fused.updates:
            reason = next((r for c in self.checks
                           if (r := c.check(source, plan, z, R, fused.stamp_ns)) is not None), None)
            if reason is None:
                kept.append((plan, z, R))
            else:
                rejected.append((plan.name, reason))
        return tuple(kept)

    def note_unreadable(self, source: str) -> None:
        """Count a message of input ``source`` that could not be read (no stamp: nothing is fused)."""
        stats = self.stats[source]
        stats.received += 1
        stats.rejected[REJECT_UNREADABLE] += 1

    def _add_updates(self, source: str, stats: SourceStats, stamp: int, updates: tuple,
                     applied_input: tuple[str, ...], rejected: list[tuple[str, str]],
                     now: int | None) -> AddResult:
        """Put one message's checked updates on the timeline at ``stamp``; what happened to each."""
        entry = Entry(stamp, source, updates=updates)
        outcome = self._insert(entry)
        if outcome is not None:
            stats.rejected[outcome] += len(updates)
            return AddResult(rejected=tuple(rejected) + tuple((p.name, outcome) for p, _, _ in updates))
        applied = applied_input
        for (plan, z, R), o in zip(updates, entry.outcomes, strict=True):
            if o is None:
                applied += (plan.name,)
            else:
                rejected.append((plan.name, o))
            self._note_pose_outcome(source, plan, z, R, stamp, o)
        if applied:
            stats.note_applied(now)
        return AddResult(applied=applied, rejected=tuple(rejected))

    def _insert(self, entry: Entry) -> str | None:
        """``entry`` on the timeline; a filter whose prediction became non-finite is reset."""
        stamp = entry.stamp_ns
        outcome = self._timeline.insert(entry)
        if outcome is None and entry.stamp_ns != stamp:  # lagged, no smoothing: fused into the current state
            self.stats[entry.source].applied_as_current += 1
        if self._timeline.diverged:
            self.predict_failures += 1
            self.reset("the prediction became non-finite (a finite but absurd measurement or command "
                       "was fused: set a rejection threshold)")
        return outcome

    def _add_process_input(self, source: str, u: np.ndarray, stamp: int) -> str | None:
        """A message's process input (e.g. an IMU's acceleration) in effect from ``stamp`` on."""
        return self._insert(Entry(stamp, source, command=u, drive=False))

    def add_wheel_command(self, stamp_ns: int, speeds, now_ns: int | None = None) -> str | None:
        """Commanded wheel speeds (rad/s, in ``wheel_order``): the body twist of seed 000 eq. 23-24,
        then as :meth:`add_control`. Returns a rejection reason, or None."""
        twist = self._commands.twist_of_wheels(speeds)
        if twist is None:
            stats = self.stats[WHEEL_COMMAND_SOURCE]
            stats.received += 1
            stats.rejected[REJECT_WHEEL_COUNT] += 1
            return REJECT_WHEEL_COUNT
        return self._add_command(WHEEL_COMMAND_SOURCE, twist, int(stamp_ns), now_ns)

    def add_control(self, command: ControlCommand, now_ns: int | None = None) -> str | None:
        """A cmd_vel command, in effect from its stamp + control_latency for ``control_timeout``.
        Returns a rejection reason, or None."""
        return self._add_command(CONTROL_SOURCE, np.asarray(command.twist, dtype=float),
                                 int(command.stamp_ns), now_ns)

    def _add_command(self, source: str, twist: np.ndarray, stamp: int, now_ns: int | None) -> str | None:
        stats = self.stats[source]
        stats.received += 1
        now = self._observe_clock(now_ns)
        if not self._commands.used:
            return None
        tilt = self._tilt.at(stamp) if self.config.control_tilt_compensation else None
        u, reason = self._commands.model_input(twist, tilt)
        reason = reason or self._clock.stamp_problem(stamp)
        if reason is None and self._recent.is_duplicate(source, stamp, hash(twist.tobytes())):
            reason = REJECT_DUPLICATE
        # Kept even ahead of this node's clock: the drive acts at stamp + latency, and a waiting
        # command never moves the state past the clock.
        if reason is None and self.initialized:
            reason = self._insert(Entry(self._commands.acting_stamp(stamp, now), source, command=u))
        elif reason is None:  # not started: the command acts from the start
            self._timeline.pending = Command(stamp, u, None)
        if reason is not None:
            stats.rejected[reason] += 1
            return reason
        stats.applied += 1
        stats.last_stamp_ns = stamp
        return None

    # --- set_pose and kidnapped-robot recovery --------------------------------------------------

    def set_pose(self, pose: PoseMeasurement, now_ns: int | None = None) -> str | None:
        """Put the filter at ``pose`` from its stamp on (core.set_pose); returns a rejection
        reason, or None. The history is cleared: older measurements are then rejected."""
        stats = self.stats[SET_POSE_SOURCE]
        stats.received += 1
        self._observe_clock(now_ns)
        checked = checked_pose(pose, self.config, self._clock, self._field_to_state, self._x_is_angle,
                               self._P0)
        if isinstance(checked, str):
            stats.rejected[checked] += 1
            return checked
        stamp, rows, values, C = checked
        self._put_pose(stamp, rows, values, C)
        stats.applied += 1
        stats.last_stamp_ns = stamp
        return None

    def _put_pose(self, stamp: int, rows: list[int], vals: np.ndarray, C: np.ndarray) -> None:
        """Restart the filter at ``stamp`` with state ``rows`` = ``vals`` (covariance ``C``)."""
        angles = [wrap_angle(v) if self._x_is_angle[r] else v for r, v in zip(rows, vals, strict=True)]
        self._timeline.put_pose(stamp, rows, np.array(angles), C)
        self._last_output_ns = None
        self._frames.reset()

    def _note_pose_outcome(self, source: str, plan, z: np.ndarray, R: np.ndarray, stamp: int,
                           outcome: str | None) -> None:
        """Kidnapped-robot recovery (core.recovery): re-initialise the pose once a run of gated
        absolute pose fixes agrees."""
        recovered = self._recovery.note(source, plan, z, stamp, outcome, self.estimate_at)
        if recovered is None:
            return
        values, self.last_recovery = recovered
        self._put_pose(stamp, [int(r) for r in plan.rows], values, R)
        self.pose_recoveries += 1
        self.stats[source].recoveries += 1
        self._warn(f"kidnapped-robot recovery: {self.last_recovery}")
