"""Time-ordered sensor fusion around the EKF: what ekf_node, bag_replay, ekf_tune and the
benchmarks all run, one path for every message. :class:`Localizer` composes core.timeline
(committed state, history, rewinds), core.command_model and core.command_guard (which command
acts when, and whether the drive follows it), core.part_plans and core.input_frames (message
parts, checked, in the filter's frames), core.encoder_input, core.tilt_input, core.recovery.

* **Output** is a prediction of a *copy* of the committed state to the requested time
  (:meth:`Localizer.estimate_at`, :meth:`Localizer.advance_to`): publishing never moves the
  filter. With ``predict_to_current_time`` false it is stamped at the newest measurement
  (robot_localization's default) until ``sensor_timeout`` passes without one.
* **Clock.** ``now_ns`` (the receiver's clock: ROS time, or a bag's receive time) rejects
  stale and far-future stamps; the clock going backwards (a bag loop, a simulator restart)
  resets the filter.
* **Bad input** is rejected with a reason and counted per source (:class:`SourceStats`).
  The engine never accepts a non-finite update, so estimates stay finite.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.command_guard import CommandGuard
from ekf_localization.core.command_model import Command, CommandInput, CommandModel
from ekf_localization.core.config import EkfConfig
from ekf_localization.core.duplicates import RecentMessages, content_digest
from ekf_localization.core.ekf import STATUS_GATED, STATUS_OK, ExtendedKalmanFilter
from ekf_localization.core.encoder_input import ENCODER_PART, EncoderInput
from ekf_localization.core.input_frames import InputFrames
from ekf_localization.core.measurements import (
    REJECT_DUPLICATE,
    REJECT_FILTER,
    REJECT_FRAME,
    REJECT_GATED,
    REJECT_NO_FRAME,
    REJECT_NONFINITE,
    REJECT_UNREADABLE,
    REJECT_WHEEL_COUNT,
    REJECT_ZERO_STAMP,
    ControlCommand,
    Measurement,
    MeasurementPart,
    PoseMeasurement,
    check_part,
    covariance_problem,
    implausible,
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
from ekf_localization.core.part_plans import (
    SOURCE_PART,
    PartPlan,
    floor_zero_variances,
    fusion_plan,
    make_plans,
    process_input_plan,
)
from ekf_localization.core.pose_recovery import PoseRecovery
from ekf_localization.core.receive_clock import ReceiveClock
from ekf_localization.core.tilt import TiltSample, horizontal_projection
from ekf_localization.core.tilt_input import TiltInput, horizontal_velocity
from ekf_localization.core.timeline import Entry, Timeline
from ekf_localization.core.units import NS_PER_S, seconds_to_ns

__all__ = ["CONTROL_SOURCE", "ENCODER_PART", "SET_POSE_SOURCE", "WHEEL_COMMAND_SOURCE", "AddResult",
           "Estimate", "Innovation", "Localizer", "SourceStats"]

_POSITION_FIELDS = np.array([0, 1], dtype=np.intp)  # set_pose: x, y
TILT_PART = "tilt"
_OUTCOME_OF_STATUS = {STATUS_OK: None, STATUS_GATED: REJECT_GATED}  # any other status: REJECT_FILTER


class Localizer:
    """The estimation core of ekf_node: see the module docstring.

    ``spec`` is the motion model ``config.model`` names (``models.registry.make_localizer``
    looks it up); its process model is built from ``config``.
    """

    def __init__(self, config: EkfConfig, spec: MotionModelSpec,
                 warn: Callable[[str], None] | None = None) -> None:
        if spec.name != config.model:
            raise ValueError(f"config.model is {config.model!r} but the model given is {spec.name!r}")
        self.config = config
        self.spec = spec
        self.model = spec.build(config)
        self._warn = warn or (lambda text: None)
        self.state_fields = spec.state_fields
        n = self.model.n
        if len(self.state_fields) != n:
            raise ValueError(f"model state has {n} components, layout has {len(self.state_fields)}")
        self._field_to_state = {f: i for i, f in enumerate(self.state_fields)}
        self._x_is_angle = np.asarray(self.model.x_is_angle, dtype=bool)
        fields = list(self.state_fields)
        x0 = np.asarray(config.initial_state, dtype=float)[fields].copy()
        for i in np.flatnonzero(self._x_is_angle):
            x0[i] = wrap_angle(x0[i])
        self._x0 = x0
        self._P0 = np.asarray(config.initial_estimate_covariance, dtype=float)[np.ix_(fields, fields)].copy()
        self._plans = {inp.name: make_plans(inp, self._field_to_state, self._x_is_angle, config.world_frame,
                                            config.base_link_frame) for inp in config.inputs}
        self._encoders = {inp.name: EncoderInput(inp, spec, self._field_to_state)
                          for inp in config.inputs if inp.kind == "joint"}
        # kinds with their own measurement (ekf_localization.inputs.kind.Fusion)
        base = config.base_link_frame
        self._fusions = {inp.name: (inp.fusion, fusion_plan(inp, self._field_to_state, n, base))
                         for inp in config.inputs if inp.fusion is not None}
        # inputs whose messages carry the model's process input (e.g. an IMU's ax, seed 001 eq. 2)
        self._process_inputs = {inp.name: plan for inp in config.inputs
                                if (plan := process_input_plan(inp, spec.input_fields)) is not None}
        # tilt on ramps (core.tilt): the IMUs that give it, the inputs projected with it
        self._tilt_sources = {inp.name for inp in config.inputs if inp.tilt_source}
        self._tilt_compensated = {inp.name for inp in config.inputs
                                  if inp.tilt_compensation or (inp.encoders is not None
                                                               and inp.encoders.tilt_compensation)}
        if config.control_tilt_compensation:
            self._tilt_compensated.add(CONTROL_SOURCE)
        self._tilt = TiltInput(max(config.history_length_ns, 0) + seconds_to_ns(1.0), config.base_link_frame)
        self._frames = InputFrames(config, {name: self._used_parts(name) for name in self._plans}, self._warn)
        self.transforms = self._frames.transforms
        self.stats: dict[str, SourceStats] = {inp.name: SourceStats() for inp in config.inputs}
        for name in (CONTROL_SOURCE, WHEEL_COMMAND_SOURCE, SET_POSE_SOURCE):
            self.stats[name] = SourceStats()
        self._commands = CommandInput(config, spec)
        self._recent = RecentMessages()  # the same message delivered twice is fused once
        self._variance_scale = {inp.name: float(inp.variance_scale) for inp in config.inputs}
        # per update plan ("source/part"): running [sum of NIS, count] of first passes, and its dimension
        plans = [plan for plans in self._plans.values() for plan in plans]
        plans += [enc.plan for enc in self._encoders.values()]
        plans += [plan for _, plan in self._fusions.values()]
        self._nis = NisTally({plan.nis_key: len(plan.local) for plan in plans})
        self._bounds = config.plausible_bounds
        self._recovery = PoseRecovery(config.recovery, self._plans, self._x_is_angle)
        self._warned_floor: set[str] = set()
        self.pose_recoveries = 0
        self.last_recovery = ""
        self.resets = 0
        self.predict_failures = 0  # committed predictions that were not finite (each resets the filter)
        self.nonfinite_outputs = 0  # estimates withheld because they were not finite
        self.last_reset_reason = ""
        self._clock = ReceiveClock(config.max_measurement_age_ns, config.future_stamp_tolerance_ns)
        self._last_output_ns: int | None = None
        # Called with every update's Innovation when set (tools: tuning, consistency reports).
        self.innovation_listener: Callable[[Innovation], None] | None = None
        latency = config.control_latency_ns if config.use_control else 0
        coast = spec.control_from_twist(np.zeros(6)) if spec.takes_control else None  # at rest
        commands = CommandModel(latency, config.control_timeout_ns, config.max_prediction_step_ns, coast)
        commands.guard = self.command_guard = CommandGuard.of(config, self.state_fields, self._commands.used)
        history = config.history_length_ns if config.smooth_lagged_data else None
        self._timeline = Timeline(ExtendedKalmanFilter(self.model, self._x0, self._P0), commands, history,
                                  self._apply)

    def _used_parts(self, source: str) -> set[str]:
        """The names of the message parts input ``source`` reads."""
        names = {SOURCE_PART.get(plan.name, plan.name) for plan in self._plans[source]}
        if source in self._tilt_sources:
            names.add("orientation")
        if source in self._process_inputs:
            names.add(self._process_inputs[source][0])
        return names

    # --- public state ------------------------------------------------------------------------

    @property
    def nis(self) -> dict[str, list[float]]:
        """"source/part" -> [sum of NIS, count, dimension] over every first-pass update (a copy)."""
        return self._nis.totals()

    @property
    def initialized(self) -> bool:
        return self._timeline.initialized

    @property
    def time_ns(self) -> int | None:
        """Stamp of the committed state (None before the first measurement)."""
        return self._timeline.t_ns if self._timeline.initialized else None

    @property
    def clock_ns(self) -> int | None:
        return self._clock.now_ns

    @property
    def frame_cache(self) -> tuple[int, int, int]:
        """(entries, cap, evictions) of the per-frame bookkeeping (core.input_frames)."""
        return self._frames.frame_cache

    @property
    def history_size(self) -> int:
        return len(self._timeline.history)

    @property
    def history(self) -> list[Entry]:
        """The timeline's entries, oldest first: those applied, then the commands still deferred."""
        return [*self._timeline.history, *self._timeline.deferred]

    @property
    def rewinds(self) -> int:
        return self._timeline.rewinds

    @property
    def skipped_rewinds(self) -> int:  # lagged entries dropped as overloaded (timeline.MAX_REPLAY_ENTRIES)
        return self._timeline.skipped_rewinds

    @property
    def earliest_insertable_ns(self) -> int | None:
        """Oldest stamp a measurement may have and still be applied at its own time."""
        return self._timeline.earliest_insertable_ns

    @property
    def newest_measurement_ns(self) -> int | None:
        return self._timeline.newest_measurement_ns

    def committed(self) -> Estimate | None:
        """The committed state itself (not predicted)."""
        tl = self._timeline
        if not tl.initialized:
            return None
        return Estimate(tl.t_ns, tl.ekf.x.copy(), tl.ekf.P.copy(), self.state_fields)

    # --- time --------------------------------------------------------------------------------

    def start(self, t_ns: int) -> None:
        """Initialise at ``t_ns`` with ``initial_state`` (done by the first measurement otherwise)."""
        self._timeline.start(int(t_ns))
        self._last_output_ns = None

    def reset(self, reason: str) -> None:
        """Forget everything but the counters; the next measurement starts the filter again."""
        self.resets += 1
        self.last_reset_reason = reason
        self._warn(f"filter reset: {reason}")
        self._clear()

    def _clear(self) -> None:
        self._timeline.clear()
        self._last_output_ns = None
        self._frames.reset()
        self._recent.clear()
        for enc in self._encoders.values():
            enc.speeds.reset()
        self._tilt.clear()

    def _observe_clock(self, now_ns: int | None) -> None:
        back = self._clock.observe(now_ns)
        if back is not None:
            self.reset(f"time went backwards by {back / NS_PER_S:.3f} s (bag loop or simulator restart?)")

    # --- input -------------------------------------------------------------------------------

    def add_measurement(self, source: str, measurement: Measurement, now_ns: int | None = None) -> AddResult:
        """Validate and fuse one message from input ``source`` (e.g. "odom0") at its stamp.

        1. Check its stamp against the clock, and that it is no copy of a recent message.
        2. Put each part it uses in the filter's frames.
        3. Take the tilt and the process input it carries. 4. Check each fused part (values,
        covariance, frame, bounds). 5. Put the parts' updates on the timeline at the stamp."""
        stats = self.stats[source]
        self._observe_clock(now_ns)
        stamp = int(measurement.stamp_ns)
        stats.note_received(self._clock.now_ns if now_ns is not None else None, stamp)
        reason = self._clock.stamp_problem(stamp)  # 1.
        if reason is None and self._recent.is_duplicate(source, stamp, content_digest(measurement)):
            reason = REJECT_DUPLICATE
        if reason is not None:
            stats.rejected[reason] += 1
            return AddResult(rejected=(("message", reason),))
        stamp = self._clock.not_ahead(stamp)
        if source in self._encoders or source in self._fusions:
            return self._add_single(source, measurement, stamp, stats, now_ns)
        measurement = self._frames.with_frame(source, measurement)
        if measurement is None:  # an empty frame_id: no frame is guessed
            stats.rejected[REJECT_NO_FRAME] += 1
            return AddResult(rejected=(("message", REJECT_NO_FRAME),))
        parts, no_transform = self._frames.parts(source, measurement, stamp)  # 2.
        rejected: list[tuple[str, str]] = []
        applied_input: tuple[str, ...] = ()
        if source in self._tilt_sources:  # 3.
            reason = no_transform.get("orientation") \
                or self._tilt.add(parts["orientation"], stamp, lambda t: horizontal_velocity(
                    self.estimate_at(t) if self.initialized else None, self._field_to_state))
            if reason is None:
                stats.applied += 1
                applied_input = (TILT_PART,)
            else:
                stats.rejected[reason] += 1
                rejected.append((TILT_PART, reason))
        if source in self._process_inputs:
            part_name, local = self._process_inputs[source]
            reason = no_transform.get(part_name) \
                or self._add_process_input(source, parts[part_name], local, stamp)
            if reason is None:
                stats.applied += 1
                applied_input += (part_name,)
            else:
                stats.rejected[reason] += 1
                rejected.append((part_name, reason))
        updates = []
        for plan in self._plans[source]:  # 4.
            if plan.name not in parts and plan.name not in no_transform:
                continue  # a differential input's first pose: no velocity yet
            update = self._checked(source, plan, parts.get(plan.name), stamp, no_transform.get(plan.name))
            if isinstance(update, str):
                stats.rejected[update] += 1
                rejected.append((plan.name, update))
            else:
                updates.append(update)
        stats.last_stamp_ns = stamp
        if not updates:
            if applied_input:
                stats.note_applied(self._clock.now_ns if now_ns is not None else None)
            return AddResult(applied=applied_input, rejected=tuple(rejected))
        return self._add_updates(source, stats, stamp, tuple(updates), applied_input, rejected, now_ns)  # 5.

    def _add_single(self, source: str, measurement, stamp: int, stats: SourceStats,
                    now_ns: int | None) -> AddResult:
        """A message that makes one update of its own: dead-wheel encoders (a JointState, stamped
        at the interval's middle) or a kind with its own measurement (inputs.kind.Fusion)."""
        if source in self._encoders:
            tilt_at = self._tilt.at if source in self._tilt_compensated else None
            update = self._encoders[source].fuse(measurement, tilt_at)
            part = ENCODER_PART
        else:
            fusion, plan = self._fusions[source]
            zR = fusion.fuse(measurement, self.config.base_link_frame)
            update = zR if isinstance(zR, str) else (stamp, plan, zR[0], zR[1] * self._variance_scale[source])
            part = plan.name
        if isinstance(update, str):
            stats.rejected[update] += 1
            return AddResult(rejected=((part, update),))
        stats.last_stamp_ns = stamp
        if update is None:  # a baseline, nothing to fuse yet
            stats.note_applied(self._clock.now_ns if now_ns is not None else None)
            return AddResult()
        return self._add_updates(source, stats, update[0], (update[1:],), (), [], now_ns)

    def _checked(self, source: str, plan: PartPlan, part: MeasurementPart | None, stamp: int,
                 reason: str | None) -> tuple[PartPlan, np.ndarray, np.ndarray] | str:
        """(plan, z, R) of a part that passes every check, or the reason it does not."""
        if reason is None:
            reason = check_part(part, plan.local, plan.expected_frame)
            if reason is not None:  # a zero fused variance fails the checks: try the floor
                part = self._floor_zero_variances(source, part, plan.local)
                reason = check_part(part, plan.local, plan.expected_frame)
            reason = reason or implausible(part.values, part.first_field, plan.local, self._bounds)
        if reason is not None:
            return reason
        z = np.asarray(part.values, dtype=float)[plan.local]
        R = np.asarray(part.covariance, dtype=float)[plan.block]
        if plan.name == "twist" and source in self._tilt_compensated:
            z, R = self._tilt.project_twist(plan.local, z, R, stamp)
        return plan, z, R * self._variance_scale[source]

    def note_unreadable(self, source: str) -> None:
        """Count a message of input ``source`` that could not be read (no stamp: nothing is fused)."""
        stats = self.stats[source]
        stats.received += 1
        stats.rejected[REJECT_UNREADABLE] += 1

    def _add_updates(self, source: str, stats: SourceStats, stamp: int, updates: tuple,
                     applied_input: tuple[str, ...], rejected: list[tuple[str, str]],
                     now_ns: int | None) -> AddResult:
        """Put one message's checked updates on the timeline at ``stamp``; what happened to each."""
        entry = Entry(stamp, source, updates=updates)
        outcome = self._insert(entry)
        if outcome is not None:
            stats.rejected[outcome] += len(updates)
            return AddResult(rejected=tuple(rejected) + tuple((p.name, outcome) for p, _, _ in updates))
        applied = applied_input + tuple(p.name for (p, _, _), o in zip(updates, entry.outcomes, strict=True)
                                        if o is None)
        if applied:
            stats.note_applied(self._clock.now_ns if now_ns is not None else None)
        for (plan, z, R), o in zip(updates, entry.outcomes, strict=True):
            if plan.name == "pose":
                self._note_pose_outcome(source, plan, z, R, stamp, o)
            if o is not None:
                rejected.append((plan.name, o))
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

    def _apply(self, entry: Entry) -> None:
        """The timeline's step for a message entry: its updates, counted (first pass or replay)."""
        first_pass = not entry.outcomes
        outcomes = []
        ekf = self._timeline.ekf
        guard, tl = self.command_guard, self._timeline
        for plan, z, R in entry.updates:
            prior = ekf.x.copy()
            result = ekf.update(plan.model, z, R, gate_sigmas=plan.gate, r_checked=plan.r_checked)
            if guard is not None and first_pass:  # core.command_guard
                guard.observe(entry.stamp_ns, plan.rows, prior, result.y, result.S, result.mahalanobis ** 2,
                              tl.commands.at(tl.command, entry.stamp_ns)[0], self.model, plan.model)
            if self.innovation_listener is not None and result.S is not None:
                self.innovation_listener(Innovation(entry.source, plan.name, entry.seq, entry.stamp_ns,
                                                    result.y, result.S, result.accepted))
            outcomes.append(_OUTCOME_OF_STATUS.get(result.status, REJECT_FILTER))
            if first_pass and not math.isnan(result.mahalanobis):  # nan: stopped before the distance
                self._nis.add(plan.nis_key, result.mahalanobis ** 2)
        outcomes_t = tuple(outcomes)
        if outcomes_t != entry.outcomes:  # first pass, or a re-pass after a rewind changed them
            self.stats[entry.source].recount(entry.outcomes, outcomes_t)
            entry.outcomes = outcomes_t

    def _floor_zero_variances(self, source: str, part: MeasurementPart, fused: np.ndarray) -> MeasurementPart:
        """A zero variance on a fused field becomes ``zero_variance_floor`` (as robot_localization
        does; diff_drive_controller publishes all-zero covariances by default): counted, warned once."""
        floored = floor_zero_variances(part, fused, self.config.zero_variance_floor)
        if floored is not part:
            self.stats[source].zero_variances_floored += 1
            if source not in self._warned_floor:
                self._warned_floor.add(source)
                self._warn(f"{source}: zero variance on a fused field ({part.name}); using "
                           f"zero_variance_floor = {self.config.zero_variance_floor:g}")
        return floored

    # --- tilt (core.tilt_input) ------------------------------------------------------------

    def tilt_at(self, stamp_ns: int) -> TiltSample | None:
        """The IMU's roll/pitch in effect at ``stamp_ns`` (None without a tilt source or sample)."""
        return self._tilt.at(stamp_ns) if self._tilt_sources else None

    # --- commands (core.command_model) ---------------------------------------------------------

    def add_wheel_command(self, stamp_ns: int, speeds, now_ns: int | None = None) -> str | None:
        """Commanded wheel speeds (rad/s, in ``wheel_order``): the body twist of eq. 23-24, then
        as :meth:`add_control`. Returns a rejection reason, or None."""
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
        self._observe_clock(now_ns)
        if not self._commands.used:
            return None
        u, reason = self._commands.model_input(twist)
        reason = reason or self._clock.stamp_problem(stamp)
        if reason is None and self._recent.is_duplicate(source, stamp, hash(twist.tobytes())):
            reason = REJECT_DUPLICATE
        # Kept even ahead of this node's clock: the drive acts at stamp + latency, and a waiting
        # command never moves the state past the clock (test_deferred_commands: skewed clocks).
        tilt = self._tilt.at(stamp) if CONTROL_SOURCE in self._tilt_compensated else None
        if reason is None and tilt is not None:  # the body velocity along the surface -> horizontal
            u = horizontal_projection(tilt.roll, tilt.pitch) @ u
        if reason is None and self.initialized:
            reason = self._insert(Entry(stamp, source, command=u))
        elif reason is None:  # not started: the command acts from the start
            self._timeline.pending = Command(stamp, u, None)
        if reason is not None:
            stats.rejected[reason] += 1
            return reason
        stats.applied += 1
        stats.last_stamp_ns = stamp
        return None

    def _add_process_input(self, source: str, part: MeasurementPart, local: np.ndarray,
                           stamp: int) -> str | None:
        """The model's process input (``spec.input_fields`` of ``part``) in effect from ``stamp`` on."""
        reason = check_part(part, local, self.config.base_link_frame) \
            or implausible(part.values, part.first_field, local, self._bounds)
        if reason is not None:
            return reason
        u = np.asarray(part.values, dtype=float)[local]
        return self._insert(Entry(stamp, source, command=u, drive=False))

    # --- set_pose and kidnapped-robot recovery --------------------------------------------------

    def set_pose(self, pose: PoseMeasurement, now_ns: int | None = None) -> str | None:
        """Put the filter at ``pose`` (x, y, yaw; velocities kept) from its stamp on; returns a
        rejection reason, or None. An all-zero, invalid or implausible (std beyond the field, or
        pi) covariance keeps P0's. A zero stamp means "now". The history is cleared: older
        measurements are then rejected."""
        stats = self.stats[SET_POSE_SOURCE]
        stats.received += 1
        self._observe_clock(now_ns)
        fields = [f for f in (0, 1, 5) if f in self._field_to_state]
        vals = np.asarray(pose.pose, dtype=float)[fields]
        reason = None
        if not np.all(np.isfinite(vals)):
            reason = REJECT_NONFINITE
        elif pose.frame_id.lstrip("/") != self.config.world_frame:
            reason = REJECT_FRAME
        elif pose.stamp_ns <= 0 and self._clock.now_ns is None:  # "now" without a clock: no time at all
            reason = REJECT_ZERO_STAMP
        reason = reason or implausible(pose.pose, 0, _POSITION_FIELDS, self._bounds)
        stamp = int(pose.stamp_ns) if pose.stamp_ns > 0 else (self._clock.now_ns or 0)
        reason = reason or (self._clock.stamp_problem(stamp) if pose.stamp_ns > 0 else None)
        if reason is not None:
            stats.rejected[reason] += 1
            return reason
        stamp = self._clock.not_ahead(stamp)
        rows = [self._field_to_state[f] for f in fields]
        C = np.asarray(pose.covariance, dtype=float)[np.ix_(fields, fields)]
        big = np.diag(C) > np.where(self._x_is_angle[rows], math.pi, self.config.max_plausible_position) ** 2
        if covariance_problem(C) is not None or big.any():  # beyond the field: no pose information
            C = self._P0[np.ix_(rows, rows)]
        self._put_pose(stamp, rows, vals, C)
        stats.applied += 1
        stats.last_stamp_ns = stamp
        return None

    def _put_pose(self, stamp: int, rows: list[int], vals: np.ndarray, C: np.ndarray) -> None:
        """Restart the filter at ``stamp`` with state ``rows`` = ``vals`` (covariance ``C``)."""
        angles = [wrap_angle(v) if self._x_is_angle[r] else v for r, v in zip(rows, vals, strict=True)]
        self._timeline.put_pose(stamp, rows, np.array(angles), C)
        self._last_output_ns = None
        self._frames.reset()

    def _note_pose_outcome(self, source: str, plan: PartPlan, z: np.ndarray, R: np.ndarray, stamp: int,
                           outcome: str | None) -> None:
        """Kidnapped-robot recovery (core.recovery): re-initialise the pose once a run of gated
        fixes agrees."""
        def state_at(t: int) -> np.ndarray | None:
            est = self.estimate_at(t)
            return None if est is None else est.state

        recovered = self._recovery.note(source, plan, z, stamp, outcome, state_at)
        if recovered is None:
            return
        values, self.last_recovery = recovered
        self._put_pose(stamp, [int(r) for r in plan.rows], values, R)
        self.pose_recoveries += 1
        self.stats[source].recoveries += 1
        self._warn(f"kidnapped-robot recovery: {self.last_recovery}")

    # --- output ------------------------------------------------------------------------------

    def estimate_at(self, t_ns: int) -> Estimate | None:
        """The estimate at ``t_ns`` without changing the filter: predicted forward from the
        committed state with the process model (commands included), or from the history
        for an earlier time (None if older than it)."""
        xP = self._timeline.estimate_at(int(t_ns))
        if xP is None:
            return None
        return Estimate(int(t_ns), xP[0], xP[1], self.state_fields)

    def advance_to(self, now_ns: int) -> Estimate | None:
        """The estimate to publish at clock time ``now_ns``, or None (not started, or nothing new).

        Stamped at ``now_ns`` when ``predict_to_current_time``; otherwise at the newest
        measurement, or at ``now_ns`` once ``sensor_timeout`` has passed without one. Output
        stamps strictly increase (a lagged measurement does not republish an old stamp).
        """
        self._observe_clock(now_ns)
        tl = self._timeline
        if not tl.initialized:
            return None
        now_ns = int(now_ns)
        newest = tl.newest_measurement_ns
        if self.config.predict_to_current_time or newest is None \
                or now_ns - newest >= self.config.sensor_timeout_ns:
            t = max(now_ns, tl.t_ns)
        else:
            t = max(newest, tl.t_ns)
        if self._last_output_ns is not None and t <= self._last_output_ns:
            return None
        est = self.estimate_at(t)
        if est is None:
            return None
        if not est.is_finite():
            self.nonfinite_outputs += 1
            return None
        self._last_output_ns = t
        extra = self._tilt.attitude(t) if self._tilt_sources else ()
        if extra:  # z (dead-reckoned on the ramp) and the IMU's roll and pitch
            est = Estimate(est.stamp_ns, est.state, est.covariance, est.state_fields, extra)
        return est
