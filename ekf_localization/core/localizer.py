"""Time-ordered sensor fusion around the EKF: what ekf_node and the offline replay both run.

:class:`Localizer` owns an :class:`~ekf_localization.core.ekf.ExtendedKalmanFilter` and a
timeline of measurements and commands stamped in integer nanoseconds.

* **Committed state.** The filter state sits at the stamp of the newest measurement or
  command applied. Output is a prediction of a *copy* of it to the requested time
  (:meth:`Localizer.estimate_at`, :meth:`Localizer.advance_to`), so publishing never moves
  the filter and a measurement stamped between the last one and "now" is still in order.
* **Lagged measurements** (``smooth_lagged_data``). Each timeline entry keeps the state it
  was applied to. A measurement older than the newest entry is inserted at its stamp: the
  filter rewinds to the state before the first newer entry and re-applies the newer entries.
  The result equals processing everything in stamp order. Entries older than
  ``history_length`` are dropped; a measurement older than the oldest kept state is rejected
  (``older_than_history``). Without smoothing, a lagged measurement is fused into the current
  state as robot_localization does.
* **Clock.** ``now_ns`` (the receiver's clock: ROS time, or a bag's receive time) rejects
  stale and far-future stamps; the clock going backwards (a bag loop, a simulator restart)
  resets the filter.
* **Bad input** is rejected with a reason and counted per source (:class:`SourceStats`).
  The engine never accepts a non-finite update, so estimates stay finite.

The output is predicted to the requested time when ``predict_to_current_time`` is true (the
default); otherwise it is stamped at the newest measurement (robot_localization's default),
unless ``sensor_timeout`` has passed without one.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from operator import attrgetter
from typing import NamedTuple

import numpy as np

from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.config import EkfConfig, InputConfig
from ekf_localization.core.ekf import STATUS_GATED, STATUS_OK, ExtendedKalmanFilter
from ekf_localization.core.frames import (
    RigidTransform,
    TransformBuffer,
    already_in_filter_frames,
    to_filter_frames,
)
from ekf_localization.core.joint_states import EncoderSample, EncoderSpeeds
from ekf_localization.core.linalg import symmetrise
from ekf_localization.core.linear import LinearMeasurement, select_rows
from ekf_localization.core.measurements import (
    REJECT_FILTER,
    REJECT_FRAME,
    REJECT_GATED,
    REJECT_LIMITS,
    REJECT_NO_TRANSFORM,
    REJECT_NONFINITE,
    REJECT_STAMP_NOT_INCREASING,
    REJECT_TILT_RANGE,
    REJECT_TOO_OLD,
    REJECT_UNREADABLE,
    REJECT_WHEEL_COUNT,
    REJECT_ZERO_STAMP,
    ControlCommand,
    JointStateMeasurement,
    Measurement,
    MeasurementPart,
    PoseMeasurement,
    check_part,
    check_stamp,
    covariance_problem,
    implausible,
)
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.pose_modes import PoseDifferentiator, PoseRelative
from ekf_localization.core.recovery import GatedFixes
from ekf_localization.core.tilt import (
    MAX_TILT_RAD,
    HeightIntegrator,
    TiltHistory,
    TiltSample,
    horizontal_projection,
    project_twist,
    projection_tilt_jacobian,
)
from ekf_localization.core.units import NS_PER_S, seconds_to_ns

# Message parts per input kind: (part name, first RL field, length).
_KIND_PARTS: dict[str, tuple[tuple[str, int, int], ...]] = {
    "odom": (("pose", 0, 6), ("twist", 6, 6)),
    "pose": (("pose", 0, 6),),
    "twist": (("twist", 6, 6),),
    "imu": (("orientation", 3, 3), ("angular_velocity", 9, 3), ("linear_acceleration", 12, 3)),
}
CONTROL_SOURCE = "cmd_vel"
MAX_PREDICTION_STEPS = 1000  # per prediction: 10 s at 10 ms steps; a longer gap (a day) in longer steps
_CONTROL_FIELDS = np.array([0, 1, 2, 3, 4, 5], dtype=np.intp)  # the command twist, fields vx .. vyaw
_POSITION_FIELDS = np.array([0, 1], dtype=np.intp)  # set_pose: x, y
WHEEL_COMMAND_SOURCE = "wheel_command"  # std_msgs/Float64MultiArray wheel speeds (wheel_command_topic)
_ROLL_PITCH = np.array([0, 1], dtype=np.intp)
# differential inputs: the part a pose part becomes, and back
_RATE_PARTS = {"pose": "pose_rate", "orientation": "orientation_rate"}
_SOURCE_PART = {rate: part for part, rate in _RATE_PARTS.items()}
_TWIST_FIELDS = (6, 7, 11)  # vx vy vyaw: the planar body twist
ENCODER_PART = "encoders"
TILT_PART = "tilt"
SET_POSE_SOURCE = "set_pose"
_MAX_FRAME_KEYS = 64  # (input, frame ids) combinations remembered as already in the filter's frames
_ENTRY_KEY = attrgetter("stamp_ns", "seq")  # the history's order (bisected on)


@dataclass(frozen=True, eq=False)
class Estimate:
    """The filter's estimate at ``stamp_ns``: state (n,), covariance (n, n), RL field of each component."""

    stamp_ns: int
    state: np.ndarray
    covariance: np.ndarray
    state_fields: tuple[int, ...]
    extra: tuple[tuple[int, float, float], ...] = ()  # (RL field, value, variance) not in the state

    def is_finite(self) -> bool:
        return bool(np.isfinite(self.state).all() and np.isfinite(self.covariance).all())


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


@dataclass(frozen=True, eq=False)
class _PartPlan:
    """How one part of one input's messages is fused."""

    name: str
    local: np.ndarray  # indices within the part to fuse
    block: tuple[np.ndarray, np.ndarray]  # np.ix_(local, local)
    model: LinearMeasurement
    gate: float
    expected_frame: str
    rows: np.ndarray | None = None  # state components the part observes when the model selects them
    angle_local: tuple[int, ...] = ()  # positions within the part whose residual is wrapped
    nis_key: str = ""  # "input/part": its key in Localizer.nis


_OUTCOME_OF_STATUS = {STATUS_OK: None, STATUS_GATED: REJECT_GATED}  # any other status: REJECT_FILTER


def _outcome(status: int) -> str | None:
    """An update's outcome from its kernel status: None (applied) or the rejection reason."""
    return _OUTCOME_OF_STATUS.get(status, REJECT_FILTER)


def _count_outcomes(stats: SourceStats, old: tuple[str | None, ...], new: tuple[str | None, ...]) -> None:
    """An entry's outcomes went from ``old`` (() on its first pass) to ``new``: the counts follow."""
    for o in old:
        if o is None:
            stats.applied -= 1
        else:
            stats.rejected[o] -= 1
    for o in new:
        if o is None:
            stats.applied += 1
        else:
            stats.rejected[o] += 1


class _Command(NamedTuple):
    """A command and the one it replaces: ``previous`` (itself a chain while commands arrive
    faster than control_latency) acts until stamp + control_latency."""

    stamp_ns: int
    u: np.ndarray
    previous: _Command | None
    drive: bool = True  # a cmd_vel command (latency, coasting); False: an acceleration input


class _Snapshot(NamedTuple):
    t_ns: int
    x: np.ndarray
    P: np.ndarray
    control: _Command | None  # the command in effect


@dataclass(eq=False)
class _Entry:
    """One timeline entry: a message's updates or a command, and the state it was applied to."""

    stamp_ns: int
    seq: int
    source: str
    updates: tuple[tuple[_PartPlan, np.ndarray, np.ndarray], ...] = ()  # (plan, z, R)
    control: np.ndarray | None = None  # a command entry when set
    outcomes: tuple[str | None, ...] = ()  # per update: None (applied) or a reason
    prior: _Snapshot | None = None  # the state it was applied to (a rewind restores it)


class _EncoderInput:
    """A jointN input: its speed tracker and the model's encoder rows H (``spec.dead_wheel_rows``)."""

    def __init__(self, inp: InputConfig, spec: MotionModelSpec, field_to_state: dict[int, int]) -> None:
        cfg = inp.encoders
        self.config = cfg
        self.speeds = EncoderSpeeds(cfg)
        self.gate = inp.threshold(ENCODER_PART)
        if spec.dead_wheel_rows is None:
            raise ValueError(f"model '{spec.name}' has no dead-wheel encoder measurement ({inp.name})")
        H = spec.dead_wheel_rows(cfg.half_spacing, cfg.lateral_offset)
        # the body-twist components [vx vy vyaw] the state has, as (index in the twist, state column)
        present = [j for j, f in enumerate(_TWIST_FIELDS) if f in field_to_state]
        self.twist_idx = np.array(present, dtype=np.intp)
        self.cols = np.array([field_to_state[_TWIST_FIELDS[j]] for j in present], dtype=np.intp)
        self.H = H
        self.M = H[:, self.cols]  # encoders <- body twist (square: 3x3 or 2x2)
        self.M_inv = np.linalg.inv(self.M)
        self.plan = _PartPlan(ENCODER_PART, np.arange(H.shape[0], dtype=np.intp),
                              np.ix_(np.arange(H.shape[0]), np.arange(H.shape[0])),
                              LinearMeasurement(H), self.gate, "", nis_key=f"{inp.name}/{ENCODER_PART}")

    def update(self, sample: EncoderSample,
               tilt: TiltSample | None) -> tuple[_PartPlan, np.ndarray, np.ndarray]:
        """(plan, z = E, R = diag(a·E² + b) (eq. 32)); with a tilt, H = M·P⁻¹ and R gets the tilt term."""
        E = np.ascontiguousarray(sample.speeds, dtype=float)
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
        plan = replace(self.plan, model=LinearMeasurement(H))
        return plan, E, symmetrise(R)


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
        self._ekf = ExtendedKalmanFilter(self.model, self._x0, self._P0)
        self._scratch = ExtendedKalmanFilter(self.model, self._x0, self._P0)
        self._plans = {inp.name: self._make_plans(inp) for inp in config.inputs if inp.kind != "joint"}
        self._encoders = {inp.name: _EncoderInput(inp, spec, self._field_to_state)
                          for inp in config.inputs if inp.kind == "joint"}
        self._tilt_sources = {inp.name for inp in config.inputs if inp.tilt_source}
        self._tilt_compensated = {inp.name for inp in config.inputs
                                  if inp.tilt_compensation or (inp.encoders is not None
                                                               and inp.encoders.tilt_compensation)}
        if config.control_tilt_compensation:
            self._tilt_compensated.add(CONTROL_SOURCE)
        self._twist_idx = np.array([j for j, f in enumerate(_TWIST_FIELDS) if f in self._field_to_state],
                                   dtype=np.intp)
        self._tilt = TiltHistory(self._history_length_for_tilt(config))
        self._height = HeightIntegrator()
        self._inputs = {inp.name: inp for inp in config.inputs}
        self._used: dict[str, set[str]] = {}  # per input: the message parts it reads (_used_parts)
        # (input, frame_id, child_frame_id) -> whether such messages are already in the filter's frames
        self._frames_identity: dict[tuple[str, str, str | None], bool] = {}
        # robot_localization's _differential / _relative pose inputs (core.pose_modes)
        self._pose_modes = {inp.name: PoseDifferentiator() if inp.differential else PoseRelative()
                            for inp in config.inputs if inp.differential or inp.relative}
        # frames: tf2 / /tf and /tf_static (fed by the node or bag_replay) and the static_transforms parameter
        self.transforms = TransformBuffer()
        for parent, child, xyz_ypr in config.static_transforms:
            self.transforms.set_static(parent, child, RigidTransform.from_xyz_ypr(*xyz_ypr))
        self._warned_transforms: set[tuple[str, str, str]] = set()
        self._warned_floor: set[str] = set()
        # inputs whose messages carry the model's process input (e.g. an IMU's ax, seed 001 eq. 2)
        self._process_inputs = {inp.name: plan for inp in config.inputs
                                if (plan := self._process_input_plan(inp)) is not None}
        self.stats: dict[str, SourceStats] = {inp.name: SourceStats() for inp in config.inputs}
        self.stats[CONTROL_SOURCE] = SourceStats()
        self.stats[WHEEL_COMMAND_SOURCE] = SourceStats()
        self._twist_from_wheels = None
        if config.wheel_radius > 0.0 and spec.twist_from_wheels is not None:
            wheels, self._twist_from_wheels = spec.twist_from_wheels(config)
            # array index of each of the model's wheels in the message
            self._wheel_index = np.array([config.wheel_order.index(w) for w in wheels], dtype=np.intp)
        self.stats[SET_POSE_SOURCE] = SourceStats()
        self._smooth = config.smooth_lagged_data
        self._history_ns = config.history_length_ns if self._smooth else 0
        self._max_step_ns = max(1, config.max_prediction_step_ns)
        self._control_timeout_ns = config.control_timeout_ns
        self._control_latency_ns = config.control_latency_ns if config.use_control else 0
        # after a command stream stops: coast to rest (a zero command)
        self._coast = spec.control_from_twist(np.zeros(6)) if spec.takes_control else None
        self._control_limits = np.asarray(config.control_velocity_limits, dtype=float)
        # per update plan ("source/part", its NIS_ROW): running (sum of NIS, count) of first passes
        nis_plans = [plan for plans in self._plans.values() for plan in plans]
        nis_plans += [enc.plan for enc in self._encoders.values()]
        self._nis_row = {plan.nis_key: i for i, plan in enumerate(nis_plans)}
        self._nis_dim = [len(plan.local) for plan in nis_plans]
        self._nis_sums = np.zeros((len(nis_plans), 2))
        self._bounds = config.plausible_bounds
        # kidnapped-robot recovery: the runs of gated absolute pose fixes (x, y and/or yaw in the world)
        keep = 3 * config.recovery.min_duration_ns + NS_PER_S
        self._gated = {(name, plan.name): GatedFixes(config.recovery, self._x_is_angle[plan.rows], keep)
                       for name, plans in self._plans.items() for plan in plans
                       if plan.name == "pose" and plan.rows is not None and len(plan.rows)}
        self.pose_recoveries = 0
        self.last_recovery = ""
        self.resets = 0
        self.rewinds = 0
        self.predict_failures = 0  # committed predictions that were not finite (each resets the filter)
        self.nonfinite_outputs = 0  # estimates withheld because they were not finite
        self.last_reset_reason = ""
        self._clock_ns: int | None = None
        self._version = 0
        self._variance_scale = {inp.name: float(inp.variance_scale) for inp in config.inputs}
        self._max_age_ns = config.max_measurement_age_ns
        self._predict_to_now = config.predict_to_current_time
        self._sensor_timeout_ns = config.sensor_timeout_ns
        self._future_tolerance_ns = config.future_stamp_tolerance_ns
        self._recovery_sources = {name for name, _ in self._gated}
        # Called with every update's Innovation when set (tools: tuning, consistency reports).
        self.innovation_listener: Callable[[Innovation], None] | None = None
        self._clear()

    # --- set-up ------------------------------------------------------------------------------

    @staticmethod
    def _history_length_for_tilt(config: EkfConfig) -> int:
        """Tilt samples are kept as long as a lagged measurement can reach back (plus a margin)."""
        return max(config.history_length_ns, 0) + seconds_to_ns(1.0)

    def _make_plans(self, inp: InputConfig) -> tuple[_PartPlan, ...]:
        plans = []
        for name, first, length in _KIND_PARTS[inp.kind]:
            target = first  # the fields a part measures: a differential pose measures their rates
            if inp.differential and name in _RATE_PARTS:
                name, target = _RATE_PARTS[name], first + 6
            local = [j for j in range(length)
                     if inp.config[first + j] and (target + j) in self._field_to_state]
            if not local:
                continue
            rows = [self._field_to_state[target + j] for j in local]
            angle_rows = tuple(r for r in rows if self._x_is_angle[r])
            frame = self.config.world_frame if name == "pose" else self.config.base_link_frame
            idx = np.array(local, dtype=np.intp)
            plans.append(_PartPlan(name, idx, np.ix_(idx, idx), select_rows(self.model.n, rows, angle_rows),
                                   inp.threshold(_SOURCE_PART.get(name, name)), frame,
                                   np.array(rows, dtype=np.intp),
                                   tuple(i for i, r in enumerate(rows) if r in angle_rows),
                                   f"{inp.name}/{name}"))
        return tuple(plans)

    def _process_input_plan(self, inp: InputConfig) -> tuple[str, np.ndarray] | None:
        """(part name, indices within it) of ``spec.input_fields`` when ``inp`` fuses any of them:
        such an input supplies the whole input vector, from one part of its messages."""
        fields = self.spec.input_fields
        if not any(inp.config[f] for f in fields):
            return None
        for name, first, length in _KIND_PARTS.get(inp.kind, ()):
            if all(first <= f < first + length for f in fields):
                return name, np.array([f - first for f in fields], dtype=np.intp)
        return None

    def _clear(self) -> None:
        for mode in getattr(self, "_pose_modes", {}).values():
            mode.reset()
        self._initialized = False
        self._t_ns = 0  # time of the committed state
        self._control: _Command | None = None
        self._history: list[_Entry] = []  # in _ENTRY_KEY order
        self._seq = 0
        self._newest_measurement_ns: int | None = None
        self._last_output_ns: int | None = None
        self._cache: tuple[int, _Snapshot] | None = None
        self._pending_control: _Command | None = None
        # the entry whose prior is the initial state, while in the history, and how far back
        # that state may move for a lagged measurement
        self._start_entry: _Entry | None = None
        self._start_floor_ns: int | None = None
        self._diverged = False
        self._version += 1

    # --- public state ------------------------------------------------------------------------

    @property
    def nis(self) -> dict[str, list[float]]:
        """"source/part" -> [sum of NIS, count, dimension] over every first-pass update (a copy)."""
        return {key: [float(self._nis_sums[i, 0]), int(self._nis_sums[i, 1]), self._nis_dim[i]]
                for key, i in self._nis_row.items() if self._nis_sums[i, 1] > 0}

    @property
    def initialized(self) -> bool:
        return self._initialized

    @property
    def time_ns(self) -> int | None:
        """Stamp of the committed state (None before the first measurement)."""
        return self._t_ns if self._initialized else None

    @property
    def clock_ns(self) -> int | None:
        return self._clock_ns

    @property
    def history_size(self) -> int:
        return len(self._history)

    @property
    def earliest_insertable_ns(self) -> int | None:
        """Oldest stamp a measurement may have and still be applied at its own time."""
        if not self._initialized:
            return None
        if not self._history:
            return self._t_ns
        first = self._history[0]
        if first is self._start_entry:
            return self._start_floor_ns
        return first.prior.t_ns

    @property
    def newest_measurement_ns(self) -> int | None:
        return self._newest_measurement_ns

    def committed(self) -> Estimate | None:
        """The committed state itself (not predicted)."""
        if not self._initialized:
            return None
        return Estimate(self._t_ns, self._ekf.x.copy(), self._ekf.P.copy(), self.state_fields)

    # --- time --------------------------------------------------------------------------------

    def start(self, t_ns: int) -> None:
        """Initialise at ``t_ns`` with ``initial_state`` (done by the first measurement otherwise)."""
        self._clear()
        self._ekf.x[:] = self._x0  # .x / .P are views into the filter's arrays
        self._ekf.P[:] = self._P0
        self._t_ns = int(t_ns)
        self._initialized = True

    def reset(self, reason: str) -> None:
        """Forget everything but the counters; the next measurement starts the filter again."""
        self.resets += 1
        self.last_reset_reason = reason
        self._warn(f"filter reset: {reason}")
        self._clear()
        for enc in self._encoders.values():
            enc.speeds.reset()
        self._tilt.clear()
        self._height.reset()

    def _observe_clock(self, now_ns: int | None) -> None:
        if now_ns is None:
            return
        now_ns = int(now_ns)
        if self._clock_ns is not None and now_ns < self._clock_ns:
            back = self._clock_ns - now_ns
            self._clock_ns = now_ns
            self.reset(f"time went backwards by {back / 1e9:.3f} s (bag loop or simulator restart?)")
        self._clock_ns = now_ns

    def _stamp_problem(self, stamp_ns: int) -> str | None:
        return check_stamp(stamp_ns, self._clock_ns, self._max_age_ns, self._future_tolerance_ns)

    # --- input -------------------------------------------------------------------------------

    def add_measurement(self, source: str, measurement: Measurement, now_ns: int | None = None) -> AddResult:
        """Validate and fuse one message from input ``source`` (e.g. "odom0") at its stamp."""
        stats = self.stats[source]
        clock = self._clock_ns
        if now_ns is not None:
            if clock is not None and now_ns < clock:
                self._observe_clock(now_ns)  # backwards: a reset
            clock = self._clock_ns = int(now_ns)
        stamp = int(measurement.stamp_ns)
        stats.note_received(None if now_ns is None else clock, stamp)
        reason = check_stamp(stamp, clock, self._max_age_ns, self._future_tolerance_ns)
        if reason is not None:
            stats.rejected[reason] += 1
            return AddResult(rejected=(("message", reason),))
        if clock is not None and stamp > clock:
            stamp = clock  # ahead within future_stamp_tolerance (clock skew): applied now
        if isinstance(measurement, JointStateMeasurement):
            return self._add_joint_state(source, measurement, stats,
                                         self._clock_ns if now_ns is not None else None)
        parts, no_transform = self._in_filter_frames(source, measurement, stamp)
        updates = []
        rejected = []
        applied_input: tuple[str, ...] = ()
        if source in self._tilt_sources:
            reason = no_transform.get("orientation") or self._add_tilt(parts["orientation"], stamp)
            if reason is None:
                stats.applied += 1
                applied_input = (TILT_PART,)
            else:
                stats.rejected[reason] += 1
                rejected.append((TILT_PART, reason))
        scale = self._variance_scale[source]
        for plan in self._plans[source]:
            reason = no_transform.get(plan.name)
            if plan.name not in parts and reason is None:
                continue  # a differential input's first pose: no velocity yet
            part = parts.get(plan.name)
            if reason is None:
                # a part that passes the checks has no zero fused variance (Cholesky needs > 0): the
                # floor is tried only on a part that fails them
                reason = check_part(part, plan.local, plan.expected_frame)
                if reason is not None:
                    part = self._floor_zero_variances(source, part, plan.local)
                    reason = check_part(part, plan.local, plan.expected_frame)
                reason = reason or implausible(part.values, part.first_field, plan.local, self._bounds)
            if reason is not None:
                stats.rejected[reason] += 1
                rejected.append((plan.name, reason))
                continue
            z = np.asarray(part.values, dtype=float)[plan.local]
            R = np.asarray(part.covariance, dtype=float)[plan.block]
            if plan.name == "twist" and source in self._tilt_compensated:
                z, R = self._project_twist(plan, z, R, stamp)
            if scale != 1.0:
                R = R * scale
            updates.append((plan, np.ascontiguousarray(z), np.ascontiguousarray(R)))
        stats.last_stamp_ns = stamp
        if source in self._process_inputs:
            part_name, local = self._process_inputs[source]
            reason = no_transform.get(part_name)
            if reason is None:
                reason = self._add_process_input(source, parts[part_name], local, stamp, stats)
            else:
                stats.rejected[reason] += 1
            if reason is None:
                applied_input = (part_name,)
            else:
                rejected.append((part_name, reason))
        if not updates:
            if applied_input:
                stats.note_applied(self._clock_ns if now_ns is not None else None)
            return AddResult(applied=applied_input, rejected=tuple(rejected))
        return self._add_updates(source, stats, stamp, updates, applied_input, rejected, now_ns)

    def note_unreadable(self, source: str) -> None:
        """Count a message of input ``source`` that could not be read (no stamp: nothing is fused)."""
        stats = self.stats[source]
        stats.received += 1
        stats.rejected[REJECT_UNREADABLE] += 1

    def _add_updates(self, source: str, stats: SourceStats, stamp: int,
                     updates: list[tuple[_PartPlan, np.ndarray, np.ndarray]], applied_input: tuple[str, ...],
                     rejected: list[tuple[str, str]], now_ns: int | None) -> AddResult:
        """Put one message's checked updates on the timeline at ``stamp``; what happened to each."""
        entry = _Entry(stamp, 0, source, updates=tuple(updates))
        outcome = self._insert(entry, stats)
        if self._diverged:
            self._reset_if_diverged()
        if outcome is not None:
            stats.rejected[outcome] += len(updates)
            return AddResult(rejected=tuple(rejected) + tuple((p.name, outcome) for p, _, _ in updates))
        return self._result(source, stats, stamp, updates, entry.outcomes, applied_input, rejected, now_ns)

    def _result(self, source: str, stats: SourceStats, stamp: int,
                updates: list[tuple[_PartPlan, np.ndarray, np.ndarray]] | tuple,
                outcomes: tuple[str | None, ...], applied_input: tuple[str, ...],
                rejected: list[tuple[str, str]], now_ns: int | None) -> AddResult:
        """What happened to each part of a message whose updates were applied (``outcomes``)."""
        applied = applied_input + tuple(p.name for (p, _, _), o in zip(updates, outcomes, strict=True)
                                        if o is None)
        if applied:
            stats.note_applied(self._clock_ns if now_ns is not None else None)
        for (plan, z, R), o in zip(updates, outcomes, strict=True):
            if plan.name == "pose":
                self._note_pose_outcome(source, plan, z, R, stamp, o)
            if o is not None:
                rejected.append((plan.name, o))
        return AddResult(applied=applied, rejected=tuple(rejected))

    def _used_parts(self, source: str) -> set[str]:
        names = self._used.get(source)
        if names is not None:
            return names
        names = self._used[source] = {_SOURCE_PART.get(plan.name, plan.name) for plan in self._plans[source]}
        if source in self._tilt_sources:
            names.add("orientation")
        if source in self._process_inputs:
            names.add(self._process_inputs[source][0])
        return names

    def _in_filter_frames(self, source: str, measurement: Measurement,
                          stamp: int) -> tuple[dict[str, MeasurementPart], dict[str, str]]:
        """The parts ``source`` uses, in the filter's frames (core.frames), and those without a transform."""
        all_parts = measurement.parts()
        if self._frames_known(source, measurement, all_parts):  # nothing to transform
            return {part.name: part for part in all_parts}, {}
        return self._to_filter_frames(source, all_parts, stamp)

    def _frames_known(self, source: str, measurement: Measurement,
                      all_parts: tuple[MeasurementPart, ...]) -> bool:
        """Whether every part ``source`` uses is already in the filter's frames, by name (remembered
        per (input, frame_id, child_frame_id))."""
        key = (source, measurement.frame_id, getattr(measurement, "child_frame_id", None))
        known = self._frames_identity.get(key)
        if known is None:
            known = source not in self._pose_modes and self._in_filter_frames_by_name(source, all_parts)
            if len(self._frames_identity) < _MAX_FRAME_KEYS:
                self._frames_identity[key] = known
        return known

    def _in_filter_frames_by_name(self, source: str, parts: tuple[MeasurementPart, ...]) -> bool:
        cfg = self.config
        inp = self._inputs[source]
        used = self._used_parts(source)

        def pose_of(part: MeasurementPart) -> str:
            return (part.child_frame_id if inp.pose_use_child_frame else inp.pose_frame) or ""

        return all(already_in_filter_frames(part, cfg.world_frame, cfg.base_link_frame, pose_of(part))
                   for part in parts if part.name in used)

    def _to_filter_frames(self, source: str, all_parts: tuple[MeasurementPart, ...],
                          stamp: int) -> tuple[dict[str, MeasurementPart], dict[str, str]]:
        cfg = self.config
        inp = self._inputs[source]
        used = self._used_parts(source)
        parts: dict[str, MeasurementPart] = {}
        missing: dict[str, str] = {}
        for part in all_parts:
            if part.name not in used or not part.provided:
                parts[part.name] = part
                continue
            pose_of = (part.child_frame_id if inp.pose_use_child_frame else inp.pose_frame) or ""
            mode = self._pose_modes.get(source) if part.name in _RATE_PARTS else None
            own = part.frame_id.strip().lstrip("/") or cfg.world_frame  # a mode works in the sensor's frame
            world = cfg.world_frame if mode is None else own
            out, gap = to_filter_frames(part, stamp, self.transforms.lookup, world,
                                        cfg.base_link_frame, pose_of)
            if out is None:
                missing[part.name] = REJECT_NO_TRANSFORM
                key = (source, *gap)
                if key not in self._warned_transforms:
                    self._warned_transforms.add(key)
                    self._warn(f"{source}: no transform {gap[0]} <- {gap[1]} (from tf2, /tf, /tf_static or "
                               f"static_transforms): its data is rejected as {REJECT_NO_TRANSFORM}")
                parts[part.name] = part
            elif mode is None:
                parts[part.name] = out
            else:
                self._apply_pose_mode(mode, out, stamp, parts, missing)
        return parts, missing

    def _apply_pose_mode(self, mode, part: MeasurementPart, stamp: int, parts: dict[str, MeasurementPart],
                         missing: dict[str, str]) -> None:
        """A pose / orientation part in its own frame -> its rates (differential) or relative pose."""
        if isinstance(mode, PoseRelative):
            values, cov = mode.update(part.values, part.covariance)
            frame = self.config.world_frame if part.name == "pose" else self.config.base_link_frame
            parts[part.name] = replace(part, frame_id=frame, values=values, covariance=cov)
            return
        rate_name = _RATE_PARTS[part.name]
        out = mode.update(stamp, part.values, part.covariance)
        if out == "not_increasing":
            missing[rate_name] = REJECT_STAMP_NOT_INCREASING
        elif out is not None:
            parts[rate_name] = MeasurementPart(rate_name, part.first_field + 6, self.config.base_link_frame,
                                               out[0], out[1])

    def _floor_zero_variances(self, source: str, part: MeasurementPart, fused: np.ndarray) -> MeasurementPart:
        """A zero variance on a fused field becomes ``zero_variance_floor`` (as robot_localization
        does; diff_drive_controller publishes all-zero covariances by default): counted, warned once."""
        cov = np.asarray(part.covariance, dtype=float)
        if cov.ndim != 2 or not part.provided:
            return part
        d = cov[fused, fused]
        zero = d == 0.0
        if not zero.any():
            return part
        cov = cov.copy()
        idx = fused[zero]
        cov[idx, idx] = self.config.zero_variance_floor
        self.stats[source].zero_variances_floored += 1
        if source not in self._warned_floor:
            self._warned_floor.add(source)
            self._warn(f"{source}: zero variance on a fused field ({part.name}); using "
                       f"zero_variance_floor = {self.config.zero_variance_floor:g}")
        return replace(part, covariance=cov)

    def _add_joint_state(self, source: str, js: JointStateMeasurement, stats: SourceStats,
                         clock_ns: int | None) -> AddResult:
        """Encoder speeds from a JointState record (core.joint_states), fused with eq. 33's H."""
        enc = self._encoders[source]
        sample, reason = enc.speeds.update(js)
        if reason is not None:
            stats.rejected[reason] += 1
            return AddResult(rejected=((ENCODER_PART, reason),))
        stats.last_stamp_ns = int(js.stamp_ns)
        if sample is None:  # the first message: a position baseline, no speed yet
            stats.note_applied(clock_ns)
            return AddResult()
        tilt = self._tilt.at(sample.stamp_ns) if source in self._tilt_compensated else None
        entry = _Entry(sample.stamp_ns, 0, source, updates=(enc.update(sample, tilt),))
        outcome = self._insert(entry, stats)
        self._reset_if_diverged()
        if outcome is not None:
            stats.rejected[outcome] += 1
            return AddResult(rejected=((ENCODER_PART, outcome),))
        if entry.outcomes[0] is not None:
            return AddResult(rejected=((ENCODER_PART, entry.outcomes[0]),))
        stats.note_applied(clock_ns)
        return AddResult(applied=(ENCODER_PART,))

    def _add_tilt(self, part: MeasurementPart, stamp: int) -> str | None:
        """Roll and pitch of an IMU orientation (REP-145: covariance[0] = -1 means none) as the tilt."""
        reason = check_part(part, _ROLL_PITCH, self.config.base_link_frame)
        if reason is not None:
            return reason
        roll, pitch = float(part.values[0]), float(part.values[1])
        if max(abs(roll), abs(pitch)) > MAX_TILT_RAD:
            return REJECT_TILT_RANGE
        cov = np.asarray(part.covariance, dtype=float)[:2, :2].copy()
        self._tilt.add(TiltSample(stamp, roll, pitch, cov))
        est = self.estimate_at(stamp) if self._initialized else None
        if est is not None:  # z climbs at the tilt's stamp, with the velocity estimated at that stamp
            self._height.update(stamp, *self._horizontal_velocity(est.state, est.covariance), roll, pitch)
        return None

    def _horizontal_velocity(self, x: np.ndarray, P: np.ndarray) -> tuple[float, float, np.ndarray]:
        """(ẋ_h, ẏ_h, their 2x2 covariance) of a state (ẏ_h = 0 for a model without vy)."""
        f = self._field_to_state
        cols = [f[c] for c in (6, 7) if c in f]
        C = np.zeros((2, 2))
        C[np.ix_(range(len(cols)), range(len(cols)))] = P[np.ix_(cols, cols)]
        return float(x[f[6]]), float(x[f[7]]) if 7 in f else 0.0, C

    def _project_twist(self, plan: _PartPlan, z: np.ndarray, R: np.ndarray,
                       stamp: int) -> tuple[np.ndarray, np.ndarray]:
        """A body twist measured along the surface -> the horizontal velocity (core.tilt)."""
        tilt = self._tilt.at(stamp)
        if tilt is None:
            return z, R
        rows = np.array([_TWIST_FIELDS.index(6 + int(j)) for j in plan.local], dtype=np.intp)
        return project_twist(z, R, rows, tilt.roll, tilt.pitch, tilt.covariance)

    def tilt_at(self, stamp_ns: int) -> TiltSample | None:
        """The IMU's roll/pitch in effect at ``stamp_ns`` (None without a tilt source or sample)."""
        return self._tilt.at(stamp_ns) if self._tilt_sources else None

    def add_wheel_command(self, stamp_ns: int, speeds, now_ns: int | None = None) -> str | None:
        """Commanded wheel speeds (rad/s, in ``wheel_order``): the body twist of eq. 23-24, then
        as :meth:`add_control`. Returns a rejection reason, or None."""
        stats = self.stats[WHEEL_COMMAND_SOURCE]
        w = np.asarray(speeds, dtype=float).ravel()
        if self._twist_from_wheels is None or w.shape != (len(self._wheel_index),):
            stats.received += 1
            stats.rejected[REJECT_WHEEL_COUNT] += 1
            return REJECT_WHEEL_COUNT
        v = self._twist_from_wheels @ w[self._wheel_index]
        twist = np.array([v[0], v[1], 0.0, 0.0, 0.0, v[2]]) if np.all(np.isfinite(w)) else np.full(6, np.nan)
        return self._add_command(WHEEL_COMMAND_SOURCE, twist, int(stamp_ns), now_ns)

    def add_control(self, command: ControlCommand, now_ns: int | None = None) -> str | None:
        """A cmd_vel command, in effect from its stamp for ``control_timeout``.

        Returns a rejection reason, or None.
        """
        return self._add_command(CONTROL_SOURCE, np.asarray(command.twist, dtype=float),
                                 int(command.stamp_ns), now_ns)

    def _add_command(self, source: str, twist: np.ndarray, stamp: int, now_ns: int | None) -> str | None:
        stats = self.stats[source]
        stats.received += 1
        self._observe_clock(now_ns)
        if not self.config.use_control or self.spec.control_from_twist is None:
            return None
        u = self.spec.control_from_twist(twist)
        reason = None if np.all(np.isfinite(u)) else REJECT_NONFINITE
        if reason is None and np.any((self._control_limits > 0.0) & (np.abs(twist) > self._control_limits)):
            reason = REJECT_LIMITS
        reason = reason or implausible(twist, 6, _CONTROL_FIELDS, self._bounds)
        if reason is None and CONTROL_SOURCE in self._tilt_compensated:
            tilt = self._tilt.at(stamp)
            if tilt is not None:  # the command's body velocity along the surface -> horizontal
                u = horizontal_projection(tilt.roll, tilt.pitch) @ u
        reason = reason or self._stamp_problem(stamp)
        if reason is None and self._initialized:
            entry = _Entry(stamp, 0, source, control=u)
            reason = self._insert(entry, stats)
            self._reset_if_diverged()
        elif reason is None:  # not started: the command applies from the start
            self._pending_control = _Command(stamp, u, None)
        if reason is not None:
            stats.rejected[reason] += 1
            return reason
        stats.applied += 1
        stats.last_stamp_ns = stamp
        return None

    def _add_process_input(self, source: str, part: MeasurementPart, local: np.ndarray, stamp: int,
                           stats: SourceStats) -> str | None:
        """The model's process input (``spec.input_fields`` of ``part``) in effect from ``stamp`` on."""
        reason = check_part(part, local, self.config.base_link_frame) \
            or implausible(part.values, part.first_field, local, self._bounds)
        if reason is None:
            u = np.asarray(part.values, dtype=float)[local]
            reason = self._insert(_Entry(stamp, 0, source, control=u), stats)
            self._reset_if_diverged()
        if reason is None:
            stats.applied += 1
        else:
            stats.rejected[reason] += 1
        return reason

    def set_pose(self, pose: PoseMeasurement, now_ns: int | None = None) -> str | None:
        """Put the filter at ``pose`` (x, y, yaw; velocities kept) from its stamp on.

        Returns a rejection reason, or None.

        An all-zero or invalid pose covariance keeps ``initial_estimate_covariance`` for x, y, yaw.
        A zero stamp means "now". The history is cleared: older measurements are then rejected.
        """
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
        elif pose.stamp_ns <= 0 and self._clock_ns is None:  # "now" without a clock: no time at all
            reason = REJECT_ZERO_STAMP
        reason = reason or implausible(pose.pose, 0, _POSITION_FIELDS, self._bounds)
        stamp = int(pose.stamp_ns) if pose.stamp_ns > 0 else (self._clock_ns or 0)
        reason = reason or (self._stamp_problem(stamp) if pose.stamp_ns > 0 else None)
        if reason is not None:
            stats.rejected[reason] += 1
            return reason
        rows = [self._field_to_state[f] for f in fields]
        C = np.asarray(pose.covariance, dtype=float)[np.ix_(fields, fields)]
        if covariance_problem(C) is not None:
            C = self._P0[np.ix_(rows, rows)]
        self._put_pose(stamp, rows, vals, C)
        stats.applied += 1
        stats.last_stamp_ns = stamp
        return None

    def _put_pose(self, stamp: int, rows: list[int], vals: np.ndarray, C: np.ndarray) -> None:
        """Restart the filter at ``stamp`` with state ``rows`` = ``vals`` (covariance ``C``, no
        correlation with the rest); the other components are kept. The history is cleared."""
        if self._initialized:
            est = self.estimate_at(max(stamp, self.earliest_insertable_ns or stamp))
            x, P = est.state.copy(), est.covariance.copy()
        else:
            x, P = self._x0.copy(), self._P0.copy()
        control = self._control if self._initialized else self._pending_control
        self._clear()
        for r, v in zip(rows, vals, strict=True):
            x[r] = wrap_angle(v) if self._x_is_angle[r] else v
        P[rows, :] = 0.0
        P[:, rows] = 0.0
        P[np.ix_(rows, rows)] = C
        self._ekf.set_state(x, P)
        self._t_ns = stamp
        self._control = control
        self._initialized = True
        self._newest_measurement_ns = stamp

    def _note_pose_outcome(self, source: str, plan: _PartPlan, z: np.ndarray, R: np.ndarray, stamp: int,
                           outcome: str | None) -> None:
        """Kidnapped-robot recovery (core.recovery): a gated absolute pose fix joins its input's run;
        once the run agrees, the pose is re-initialised from it. An applied fix ends the run."""
        run = self._gated.get((source, plan.name))
        if run is None:
            return
        if outcome != REJECT_GATED:
            if outcome is None:
                run.clear()
            return
        est = self.estimate_at(stamp)
        if est is None:
            return
        h = plan.model.h(est.state[None])[0]
        innovation = z - h
        for i in plan.angle_local:
            innovation[i] = wrap_angle(innovation[i])
        correction = run.add(stamp, innovation)
        if correction is None:
            return
        rows = [int(r) for r in plan.rows]
        linear = [c for c, r in zip(correction, rows, strict=True) if not self._x_is_angle[r]]
        offset = float(np.linalg.norm(linear))
        self._put_pose(stamp, rows, h + correction, R)
        self.pose_recoveries += 1
        self.stats[source].recoveries += 1
        self.last_recovery = (f"{source}: {len(run)} pose fixes in a row failed the gate but agreed: pose "
                              f"re-initialised from them ({offset:.2f} m away)")
        self._warn(f"kidnapped-robot recovery: {self.last_recovery}")
        run.clear()

    # --- the timeline ------------------------------------------------------------------------

    def _insert(self, entry: _Entry, stats: SourceStats) -> str | None:
        """Apply ``entry`` at its stamp. Returns a rejection reason for the whole entry, or None."""
        s = entry.stamp_ns
        if not self._initialized:
            self.start(s)  # the initial state is put at the first measurement's stamp ...
            if self._smooth:  # ... or at a lagged one's before it, up to history_length earlier
                self._start_floor_ns = max(0, s - self._history_ns)
            if self._pending_control is not None and self.config.use_control:
                self._control = self._pending_control
            self._pending_control = None
        self._seq += 1
        entry.seq = self._seq
        if not self._smooth:
            if s < self._t_ns:  # lagged: fused into the current state, as robot_localization does
                stats.applied_as_current += 1
                entry.stamp_ns = self._t_ns
            self._process(entry)
            if entry.control is None:
                self._note_measurement(entry.stamp_ns)
            return None
        if self._history and s < self._history[-1].stamp_ns:
            kept = 0
            first = self._history[kept]
            if s < first.prior.t_ns:
                if first is not self._start_entry or s < self._start_floor_ns:
                    return REJECT_TOO_OLD
                first.prior = first.prior._replace(t_ns=s)  # the initial state, now at s
                self._start_entry = entry
            i = bisect_right(self._history, (s, entry.seq), kept, key=_ENTRY_KEY)
            self._restore(self._history[i].prior)
            replay = self._history[i:]
            self._history.insert(i, entry)
            self._process(entry)
            for e in replay:
                self._process(e)
            self.rewinds += 1
        else:
            if s < self._t_ns:
                return REJECT_TOO_OLD
            self._history.append(entry)
            self._process(entry)
            if entry.seq == 1 and self._start_floor_ns is not None:
                self._start_entry = entry
        if entry.control is None:
            self._note_measurement(s)
        self._prune(self._history[-1].stamp_ns - self._history_ns)
        return None

    def _reset_if_diverged(self) -> None:
        if self._diverged:
            self.predict_failures += 1
            self.reset("the prediction became non-finite (a finite but absurd measurement or command "
                       "was fused: set a rejection threshold)")

    def _note_measurement(self, stamp_ns: int) -> None:
        if self._newest_measurement_ns is None or stamp_ns > self._newest_measurement_ns:
            self._newest_measurement_ns = stamp_ns

    def _prune(self, cutoff: int) -> None:
        """Forget the entries stamped before ``cutoff`` (the newest entry's stamp - history_length)."""
        del self._history[:bisect_left(self._history, (cutoff,), key=_ENTRY_KEY)]

    def _snapshot(self) -> _Snapshot:
        return _Snapshot(self._t_ns, self._ekf.x.copy(), self._ekf.P.copy(), self._control)

    def _restore(self, snap: _Snapshot) -> None:
        self._ekf.x[:] = snap.x
        self._ekf.P[:] = snap.P
        self._t_ns = snap.t_ns
        self._control = snap.control

    def _process(self, entry: _Entry) -> None:
        """Predict the committed state to the entry's stamp and apply it."""
        if self._smooth:  # the state a rewind restores (no history, so no rewind, without smoothing)
            entry.prior = self._snapshot()
        self._t_ns, self._control, ok = self._propagate(self._ekf, self._t_ns, entry.stamp_ns, self._control)
        self._diverged |= not ok
        self._version += 1
        if entry.control is not None:
            if entry.source in (CONTROL_SOURCE, WHEEL_COMMAND_SOURCE):
                self._control = _Command(entry.stamp_ns, entry.control,
                                         self._acting_from(self._control, entry.stamp_ns))
            else:  # spec.input_fields from a message (e.g. an IMU's ax): no latency, no coasting
                self._control = _Command(entry.stamp_ns, entry.control, None, drive=False)
            return
        first_pass = not entry.outcomes
        outcomes = []
        listener = self.innovation_listener
        for plan, z, R in entry.updates:
            innovation = self._innovation(entry, plan, z, R) if listener is not None else None
            result = self._ekf.update(plan.model, z, R, gate_sigmas=plan.gate)
            status, d2 = result.status, result.mahalanobis ** 2
            if innovation is not None:
                listener(Innovation(*innovation, status == STATUS_OK))
            outcomes.append(_outcome(status))
            if first_pass and d2 < math.inf:  # nan: the update stopped before the distance
                acc = self._nis_sums[self._nis_row[plan.nis_key]]
                acc[0] += d2
                acc[1] += 1.0
        outcomes_t = tuple(outcomes)
        if outcomes_t != entry.outcomes:  # first pass, or a re-pass after a rewind changed them
            _count_outcomes(self.stats[entry.source], entry.outcomes, outcomes_t)
            entry.outcomes = outcomes_t

    def _innovation(self, entry: _Entry, plan: _PartPlan, z: np.ndarray, R: np.ndarray) -> tuple:
        """(source, part, seq, stamp, ν, S) of an update about to be applied to the committed state.

        When the plan's model selects ``plan.rows`` of the state, ν = z - x[rows] and
        S = P[rows, rows] + R; otherwise ν = z - h(x), S = H P Hᵀ + R.
        """
        x, P = self._ekf.x, self._ekf.P
        rows = plan.rows
        if rows is not None:
            nu = z - x[rows]
            S = P[np.ix_(rows, rows)] + R
        else:
            H = plan.model.jacobian(x[None])[0]
            nu = z - plan.model.h(x[None])[0]
            S = H @ P @ H.T + R
        for i in plan.angle_local:
            nu[i] = wrap_angle(nu[i])
        return entry.source, plan.name, entry.seq, entry.stamp_ns, nu, 0.5 * (S + S.T)

    def _propagate(self, ekf: ExtendedKalmanFilter, t_ns: int, to_ns: int,
                   control: tuple[int, np.ndarray] | None
                   ) -> tuple[int, tuple[int, np.ndarray] | None, bool]:
        """Predict ``ekf`` from ``t_ns`` to ``to_ns`` in steps of at most max_prediction_step
        (at most MAX_PREDICTION_STEPS steps: a longer gap takes longer steps).

        A command acts from ``control_latency`` after its stamp (its predecessor until then)
        for ``control_timeout``; then the model coasts to rest (a zero command). Before any
        command the model holds its velocity. Steps are split where the command changes.
        Returns the new (time, control, all steps finite).
        """
        step = self._max_step_ns
        if control is None and to_ns - t_ns <= step:  # the common case: one step, no command
            return (to_ns, None, ekf.predict(to_ns - t_ns, None)) if to_ns > t_ns else (t_ns, None, True)
        ok = True
        if to_ns - t_ns > MAX_PREDICTION_STEPS * step:  # a long gap: bounded time, longer steps
            step = -(-(to_ns - t_ns) // MAX_PREDICTION_STEPS)
        while t_ns < to_ns:
            u, change = self._command_at(control, t_ns)
            end = min(to_ns, t_ns + step, change)
            ok &= ekf.predict(end - t_ns, u)
            t_ns = end
        return t_ns, control, ok

    def _acting_from(self, control: _Command | None, t_ns: int) -> _Command | None:
        """The command chain as far as it can act at or after ``t_ns`` (older links dropped)."""
        if control is None:
            return None
        if t_ns >= control.stamp_ns + (self._control_latency_ns if control.drive else 0):
            return control._replace(previous=None)
        return control._replace(previous=self._acting_from(control.previous, t_ns))

    def _command_at(self, control: _Command | None, t_ns: int) -> tuple[np.ndarray | None, float]:
        """The model input in effect at ``t_ns`` and the time it next changes."""
        if control is None:
            return None, math.inf
        start = control.stamp_ns + (self._control_latency_ns if control.drive else 0)
        if t_ns < start:  # its predecessors until then
            u, change = self._command_at(control.previous, t_ns)
            return u, min(change, start)
        expiry = start + self._control_timeout_ns
        if t_ns < expiry:
            return control.u, expiry
        return (self._coast if control.drive else None), math.inf

    # --- output ------------------------------------------------------------------------------

    def estimate_at(self, t_ns: int) -> Estimate | None:
        """The estimate at ``t_ns`` without changing the filter: predicted forward from the
        committed state with the process model (commands included), or from the history
        for an earlier time (None if older than it)."""
        if not self._initialized:
            return None
        t_ns = int(t_ns)
        if t_ns == self._t_ns:  # the committed state itself (publish_on_measurement): no prediction
            return Estimate(t_ns, self._ekf.x.copy(), self._ekf.P.copy(), self.state_fields)
        if t_ns > self._t_ns:
            base = self._snapshot_view()
            if self._cache is not None and self._cache[0] == self._version and self._cache[1].t_ns <= t_ns:
                base = self._cache[1]
        else:
            earliest = self.earliest_insertable_ns
            if t_ns < earliest:
                return None
            k = bisect_right(self._history, (t_ns, math.inf), key=_ENTRY_KEY)
            base = self._history[k].prior  # of the first entry after t
        sc = self._scratch
        sc.x[:] = base.x
        sc.P[:] = base.P
        t, control, ok = self._propagate(sc, base.t_ns, t_ns, base.control)
        x, P = sc.x.copy(), sc.P.copy()
        if not ok:
            x[:] = math.nan  # withheld by advance_to
        elif t_ns >= self._t_ns:
            self._cache = (self._version, _Snapshot(t, x, P, control))
        return Estimate(t_ns, x.copy(), P.copy(), self.state_fields)

    def _snapshot_view(self) -> _Snapshot:
        return _Snapshot(self._t_ns, self._ekf.x, self._ekf.P, self._control)

    def advance_to(self, now_ns: int) -> Estimate | None:
        """The estimate to publish at clock time ``now_ns``, or None (not started, or nothing new).

        Stamped at ``now_ns`` when ``predict_to_current_time``; otherwise at the newest
        measurement, or at ``now_ns`` once ``sensor_timeout`` has passed without one. Output
        stamps strictly increase (a lagged measurement does not republish an old stamp).
        """
        self._observe_clock(now_ns)
        if not self._initialized:
            return None
        now_ns = int(now_ns)
        newest = self._newest_measurement_ns
        if self._predict_to_now or newest is None or now_ns - newest >= self._sensor_timeout_ns:
            t = max(now_ns, self._t_ns)
        else:
            t = max(newest, self._t_ns)
        if self._last_output_ns is not None and t <= self._last_output_ns:
            return None
        est = self.estimate_at(t)
        if est is None:
            return None
        if not est.is_finite():
            self.nonfinite_outputs += 1
            return None
        self._last_output_ns = t
        tilt = self.tilt_at(t)
        if tilt is not None:
            est = self._with_attitude(est, tilt)
        return est

    def _with_attitude(self, est: Estimate, tilt: TiltSample) -> Estimate:
        """The estimate with z (integrated, core.tilt.HeightIntegrator) and the IMU's roll/pitch."""
        z, z_var = self._height.current()  # as of the newest tilt sample: never extrapolated with a
        # tilt that may be stale (a late IMU would otherwise overshoot the climb)
        extra = ((2, z, z_var), (3, tilt.roll, float(tilt.covariance[0, 0])),
                 (4, tilt.pitch, float(tilt.covariance[1, 1])))
        return Estimate(est.stamp_ns, est.state, est.covariance, est.state_fields, extra)
