"""Wheel-encoder speeds from sensor_msgs/JointState records (no ROS imports).

ros2_control's joint_state_broadcaster publishes every joint in one message: names in any
order, positions in rad and, when the hardware interface has them, velocities in rad/s.
:class:`EncoderSpeeds` turns successive messages into the encoders' linear surface speeds
E (m/s): unpowered dead wheels (seed 000 eq. 29-31: ``[E_L E_R E_a]``, or ``[E_L E_R]`` for a
tank) or the drive's own wheels (``geometry`` "mecanum": four, "differential": two):

* joints are matched by name (``EncoderInputConfig.names``, in the geometry's wheel order);
  other joints in the message (an arm's) are ignored;
* each joint's value is multiplied by its ``directions`` sign (+1 or -1: a wheel mounted
  mirrored counts backwards when the robot drives forward);
* speed = wheel_radius · Δposition / Δt with Δt the integer-ns stamp difference. That is
  the mean speed over the interval, so the sample is stamped at the interval's midpoint;
  with ``use_velocities`` and velocities in the message, E = wheel_radius · velocity at
  the message stamp instead;
* a position step implying a speed above ``max_speed`` (an encoder reset, a position that
  wraps at ±π, a glitch) is rejected and the next speed is taken from the new position:
  never a speed spike;
* a message with unequal array lengths, duplicate names, a missing joint, a non-finite used
  value, or a stamp not after the previous one is rejected with its reason (REJECT_* in
  :mod:`ekf_localization.core.measurements`) and leaves the position baseline unchanged.

The speeds' noise (docs/models.md, driven wheels) is, per encoder,
``a·Ê² + b + (r·q)²/(6·Δt²)``: eq. 32's speed term at the filter's predicted speed Ê = h(x̂⁻)
(not the measured one: a quantised slow sample would look certain), the floor b, and the
quantisation of two position readings of resolution q (``position_resolution``, rad; positions
only, Δt each message's own interval).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from ekf_localization.core.measurements import (
    REJECT_ARRAY_LENGTHS,
    REJECT_DUPLICATE_NAMES,
    REJECT_ENCODER_JUMP,
    REJECT_JOINT_MISSING,
    REJECT_NONFINITE,
    REJECT_STAMP_NOT_INCREASING,
    JointStateMeasurement,
)
from ekf_localization.core.units import NS_PER_S

GEOMETRIES = ("dead_wheels", "mecanum", "differential", "swerve")
WHEEL_ORDER = {"dead_wheels": "[left, right, lateral] (or [left, right])",
               "mecanum": "[rear_left, rear_right, front_left, front_right] (seed 000 eq. 24's m1..m4)",
               "differential": "[left, right]",
               "swerve": "[the drive joint of each module] (two or more, in module order)"}
WHEEL_COUNT = {"dead_wheels": (2, 3), "mecanum": (4,), "differential": (2,), "swerve": None}
GUARD_WINDOW_NS = 2_000_000_000  # the units guard looks at the messages of the last 2 s
GUARD_MIN_MESSAGES = 5


@dataclass(frozen=True)
class EncoderInputConfig:
    """A jointN input: which joints are the wheels and how their speeds become E."""

    names: tuple[str, ...]  # joint names in the geometry's wheel order (WHEEL_ORDER)
    geometry: str = "dead_wheels"  # GEOMETRIES: which wheels, hence which rows H
    wheel_radius: float = 0.024  # m: rad -> m along the surface
    half_spacing: float = 0.17  # W, m: the parallel wheels sit at ±W from the centre line
    lateral_offset: float = 0.1  # D, m: lateral wheel behind the centre for D > 0 (eq. 30)
    # dead wheels, each pod's calibration (docs/models.md, "Dead-wheel pods"); empty: eq. 30's
    pod_offsets: tuple[float, ...] = ()  # m, across each pod's rolling direction (left > 0)
    pod_angles: tuple[float, ...] = ()  # rad, each pod's rolling direction from x
    pod_scales: tuple[float, ...] = ()  # each pod's reading per surface distance
    speed_variance_coeff: float = 0.002  # a of eq. 32 (dimensionless)
    speed_variance_floor: float = 6.4516e-07  # b of eq. 32, (m/s)² (0.001 in²/s²)
    use_velocities: bool = False  # use the message's velocities when present
    max_speed: float = 5.0  # m/s: a faster position step is an encoder jump
    tilt_compensation: bool = False  # project the speeds with the IMU's roll/pitch (core.tilt)
    half_wheelbase: float = 0.0  # L, m: driven mecanum wheels sit at ±L along x (eq. 23)
    half_track: float = 0.0  # l, m: driven wheels sit at ±l from the centre line
    strafe_scale: float = 1.0  # mecanum: the robot's ẏ per the ẏ eq. 23 gives from the wheels
    directions: tuple[float, ...] = ()  # +1/-1 per name (empty: all +1)
    position_resolution: float = 0.0  # q, rad of the wheel: one encoder count (0: not quantised)
    speed_variance_at: str = "predicted"  # a·E² at the filter's predicted speed, or "measured" (eq. 32)
    # swerve (models/swerve.py): names are the modules' drive joints, these their steer joints
    steer_names: tuple[str, ...] = ()
    module_positions: tuple[float, ...] = ()  # [x0, y0, x1, y1, ...] m, body frame
    drive_gear_ratio: float = 1.0  # drive joint rad per wheel rad
    coupling_ratio: float = 0.0  # drive joint rad per steer rad (coaxial modules: steering turns the wheel)
    steer_angle_variance: float = 7.6154e-05  # rad², σ_φ² of a steer angle reading
    slip: Any = None  # slip detection settings (inputs.slip.SlipSettings), None: off

    @property
    def signs(self) -> np.ndarray:
        return np.asarray(self.directions or (1.0,) * len(self.names), dtype=float)

    def variances(self, E: np.ndarray, interval_ns: int | None = None) -> np.ndarray:
        """Per encoder, (m/s)²: a·E² + b (eq. 32) at the speed E given (the predicted one when the
        filter has an estimate), plus (r·q)²/(6·Δt²) for a speed differenced over ``interval_ns``
        from positions of resolution q (docs/models.md, driven wheels)."""
        E = np.asarray(E, dtype=float)
        var = self.speed_variance_coeff * E * E + self.speed_variance_floor
        if interval_ns is not None and self.position_resolution > 0.0:
            dt = interval_ns / NS_PER_S
            var = var + (self.wheel_radius * self.position_resolution) ** 2 / (6.0 * dt * dt)
        return var


@dataclass(frozen=True)
class EncoderSample:
    """Encoder speeds E (m/s) in the order of ``EncoderInputConfig.names``, valid at ``stamp_ns``;
    ``interval_ns``: the position difference's interval (None: the message's velocities)."""

    stamp_ns: int
    speeds: np.ndarray
    interval_ns: int | None = None


def read_joints(js: JointStateMeasurement, names: tuple[str, ...], signs: np.ndarray, use_velocities: bool,
                ) -> tuple[np.ndarray | None, np.ndarray | None, str | None]:
    """The ``names`` joints' positions and velocities (times ``signs``) from a message: (q, w, None)
    with q None when the message has no positions and w None unless velocities are used (asked
    for, or the message has nothing else); or (None, None, reason)."""
    msg_names = tuple(str(n) for n in js.names)
    positions = np.asarray(js.positions, dtype=float).ravel()
    velocities = np.asarray(js.velocities, dtype=float).ravel()
    efforts = np.asarray(js.efforts, dtype=float).ravel()
    k = len(msg_names)
    if positions.size not in (0, k) or velocities.size not in (0, k) or efforts.size not in (0, k) \
            or positions.size == velocities.size == 0:
        return None, None, REJECT_ARRAY_LENGTHS
    if len(set(msg_names)) != k:
        return None, None, REJECT_DUPLICATE_NAMES
    index = {n: i for i, n in enumerate(msg_names)}
    try:
        idx = np.array([index[n] for n in names], dtype=np.intp)
    except KeyError:
        return None, None, REJECT_JOINT_MISSING
    q = positions[idx] * signs if positions.size else None
    use_vel = velocities.size == k and (use_velocities or q is None)
    w = velocities[idx] * signs if use_vel else None
    if (q is not None and not np.all(np.isfinite(q))) or (w is not None and not np.all(np.isfinite(w))):
        return None, None, REJECT_NONFINITE
    return q, w, None


class EncoderSpeeds:
    """Successive JointState records -> encoder speed samples (module docstring)."""

    def __init__(self, config: EncoderInputConfig) -> None:
        self.config = config
        self.jumps = 0
        self.last_jump_rate = 0.0  # rad/s of the wheel implied by the last encoder_jump
        self.reset()

    def reset(self) -> None:
        """Forget the position baseline and the last stamp (the filter was reset)."""
        self._last_ns: int | None = None
        self._last_positions: np.ndarray | None = None

    def update(self, js: JointStateMeasurement) -> tuple[EncoderSample | None, str | None]:
        """(sample, None), (None, None) while there is no baseline yet, or (None, reason)."""
        q, w, reason = read_joints(js, self.config.names, self.config.signs, self.config.use_velocities)
        if reason is not None:
            return None, reason
        t = int(js.stamp_ns)
        if self._last_ns is not None and t <= self._last_ns:
            return None, REJECT_STAMP_NOT_INCREASING
        last_ns, last_q = self._last_ns, self._last_positions
        self._last_ns, self._last_positions = t, q
        r = self.config.wheel_radius
        if w is not None:
            speeds, stamp, interval = r * w, t, None
        elif last_q is None:
            return None, None
        else:
            interval = t - last_ns
            speeds = r * (q - last_q) * (NS_PER_S / interval)
            stamp = last_ns + interval // 2
        if not np.all(np.abs(speeds) <= self.config.max_speed):
            self.jumps += 1
            self.last_jump_rate = float(np.max(np.abs(speeds))) / r
            return None, REJECT_ENCODER_JUMP
        return EncoderSample(stamp, speeds, interval), None


def validate_encoder_config(cfg: EncoderInputConfig) -> str | None:
    """What is wrong with ``cfg`` (a sentence naming the field), or None."""
    if cfg.geometry not in GEOMETRIES:
        return "geometry: one of " + ", ".join(GEOMETRIES)
    count = WHEEL_COUNT[cfg.geometry]
    if (len(cfg.names) not in count if count else len(cfg.names) < 2) \
            or not all(isinstance(n, str) and n for n in cfg.names):
        return f"names: non-empty joint names {WHEEL_ORDER[cfg.geometry]}"
    if len(set(cfg.names)) != len(cfg.names):
        return "names: distinct joint names"
    if cfg.directions and (len(cfg.directions) != len(cfg.names) or any(d not in (1.0, -1.0)
                                                                         for d in cfg.directions)):
        return f"directions: {len(cfg.names)} signs, each 1 or -1 (one per name)"
    lengths = {"dead_wheels": (), "differential": ("half_track",), "swerve": ("drive_gear_ratio",),
               "mecanum": ("half_track", "half_wheelbase")}
    for name in ("wheel_radius", "half_spacing", "max_speed") + lengths[cfg.geometry]:
        v = getattr(cfg, name)
        if not (math.isfinite(v) and v > 0.0):
            return f"{name}: a finite value > 0"
    if not math.isfinite(cfg.lateral_offset):
        return "lateral_offset: a finite value"
    if not (math.isfinite(cfg.strafe_scale) and cfg.strafe_scale > 0.0) \
            or (cfg.geometry != "mecanum" and cfg.strafe_scale != 1.0):
        return "strafe_scale: a finite value > 0 with geometry mecanum, else 1.0"
    for name in ("pod_offsets", "pod_angles", "pod_scales"):
        v = getattr(cfg, name)
        if v and (cfg.geometry != "dead_wheels" or len(v) != len(cfg.names)
                  or not all(math.isfinite(x) and (x > 0.0 or name != "pod_scales") for x in v)):
            what = "finite values > 0" if name == "pod_scales" else "finite values"
            return f"{name}: [] or, with geometry dead_wheels, {len(cfg.names)} {what} (one per name)"
    if not (math.isfinite(cfg.speed_variance_coeff) and cfg.speed_variance_coeff >= 0.0):
        return "speed_variance_coeff: a finite value >= 0"
    if not (math.isfinite(cfg.speed_variance_floor) and cfg.speed_variance_floor > 0.0):
        return "speed_variance_floor: a finite variance > 0 ((m/s)²)"
    if cfg.speed_variance_at not in ("predicted", "measured"):
        return "speed_variance_at: predicted or measured"
    if not (math.isfinite(cfg.position_resolution) and cfg.position_resolution >= 0.0):
        return "position_resolution: a finite angle >= 0 (rad of the wheel; 0: not quantised)"
    if cfg.geometry == "swerve":
        return _swerve_problem(cfg)
    return None


def _swerve_problem(cfg: EncoderInputConfig) -> str | None:
    """The swerve fields' list lengths and values (the layout itself: models.swerve.layout_problem)."""
    n = len(cfg.names)
    steer = cfg.steer_names
    if len(steer) != n or not all(isinstance(s, str) and s for s in steer) \
            or len(set(steer) | set(cfg.names)) != 2 * n:
        return f"steer_names: {n} steer joint names, one per drive joint in names, all distinct"
    if len(cfg.module_positions) != 2 * n or not all(math.isfinite(v) for v in cfg.module_positions):
        return f"module_positions: {2 * n} finite numbers [x0, y0, x1, y1, ...] (m), one pair per module"
    if not math.isfinite(cfg.coupling_ratio):
        return "coupling_ratio: a finite value"
    if not (math.isfinite(cfg.steer_angle_variance) and cfg.steer_angle_variance >= 0.0):
        return "steer_angle_variance: a finite variance >= 0 (rad²)"
    return None


class UnitsGuard:
    """An encoder input's health over the last 2 s of message stamps: a fault text when more than
    half of at least GUARD_MIN_MESSAGES messages were refused, naming the likely cause (wrong
    units when most refusals imply a wheel faster than ``max_speed``), else None."""

    def __init__(self, config: EncoderInputConfig, name: str) -> None:
        self.config = config
        self.name = name
        self._window: deque[tuple[int, str | None, float]] = deque()

    def reset(self) -> None:
        self._window.clear()

    def note(self, stamp_ns: int, reason: str | None, jump_rate: float = 0.0) -> str | None:
        """Record one message's outcome (``reason`` None: accepted) and return the fault, or None."""
        w = self._window
        if w and stamp_ns < w[-1][0]:  # a stamp going back (a restarted driver): a new window
            w.clear()
        w.append((stamp_ns, reason, jump_rate))
        while w[0][0] < stamp_ns - GUARD_WINDOW_NS:
            w.popleft()
        refused = [(r, rate) for _, r, rate in w if r is not None]
        if len(w) < GUARD_MIN_MESSAGES or 2 * len(refused) <= len(w):
            return None
        share = 100.0 * len(refused) / len(w)
        reasons = Counter(r for r, _ in refused)
        cfg = self.config
        if reasons.most_common(1)[0][0] == REJECT_ENCODER_JUMP:
            rate = float(np.median([rate for r, rate in refused if r == REJECT_ENCODER_JUMP]))
            what = "velocities must be rad/s" if cfg.use_velocities else "positions must be radians"
            return (f"{what} of the wheel; got ~{rate:.3g} rad/s, above {self.name}_max_speed "
                    f"{cfg.max_speed:g} m/s = {cfg.max_speed / cfg.wheel_radius:.3g} rad/s at wheel_radius "
                    f"{cfg.wheel_radius:g} m ({share:.0f} % of messages refused in 2 s)")
        listed = ", ".join(f"{r} {n}" for r, n in reasons.most_common(3))
        return f"{share:.0f} % of messages refused in 2 s ({listed})"
