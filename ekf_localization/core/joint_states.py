"""Dead-wheel encoder speeds from sensor_msgs/JointState records (no ROS imports).

ros2_control's joint_state_broadcaster publishes every joint in one message: names in any
order, positions in rad and, when the hardware interface has them, velocities in rad/s.
:class:`EncoderSpeeds` turns successive messages into the encoders' linear surface speeds
E (m/s) that seed 000 fuses (eq. 29-31: ``[E_L E_R E_a]``, or ``[E_L E_R]`` for a tank):

* joints are matched by name (``EncoderInputConfig.names``: left, right[, lateral]);
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

The speeds' noise is eq. 32, ``a·E² + b`` per encoder (``speed_variance_coeff`` a,
``speed_variance_floor`` b in (m/s)²), evaluated at the measured speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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


@dataclass(frozen=True)
class EncoderInputConfig:
    """A jointN input: which joints are the dead wheels and how their speeds become E."""

    names: tuple[str, ...]  # left, right[, lateral] joint names
    wheel_radius: float = 0.024  # m: rad -> m along the surface
    half_spacing: float = 0.17  # W, m: the parallel wheels sit at ±W from the centre line
    lateral_offset: float = 0.1  # D, m: lateral wheel behind the centre for D > 0 (eq. 30)
    speed_variance_coeff: float = 0.002  # a of eq. 32 (dimensionless)
    speed_variance_floor: float = 6.4516e-07  # b of eq. 32, (m/s)² (0.001 in²/s²)
    use_velocities: bool = False  # use the message's velocities when present
    max_speed: float = 5.0  # m/s: a faster position step is an encoder jump
    tilt_compensation: bool = False  # project the speeds with the IMU's roll/pitch (core.tilt)

    def variances(self, E: np.ndarray) -> np.ndarray:
        """Eq. 32 per encoder, (m/s)²."""
        E = np.asarray(E, dtype=float)
        return self.speed_variance_coeff * E * E + self.speed_variance_floor


@dataclass(frozen=True)
class EncoderSample:
    """Encoder speeds E (m/s) in the order of ``EncoderInputConfig.names``, valid at ``stamp_ns``."""

    stamp_ns: int
    speeds: np.ndarray


class EncoderSpeeds:
    """Successive JointState records -> encoder speed samples (module docstring)."""

    def __init__(self, config: EncoderInputConfig) -> None:
        self.config = config
        self.jumps = 0
        self.reset()

    def reset(self) -> None:
        """Forget the position baseline and the last stamp (the filter was reset)."""
        self._last_ns: int | None = None
        self._last_positions: np.ndarray | None = None

    def update(self, js: JointStateMeasurement) -> tuple[EncoderSample | None, str | None]:
        """(sample, None), (None, None) while there is no baseline yet, or (None, reason)."""
        names = tuple(str(n) for n in js.names)
        positions = np.asarray(js.positions, dtype=float).ravel()
        velocities = np.asarray(js.velocities, dtype=float).ravel()
        efforts = np.asarray(js.efforts, dtype=float).ravel()
        k = len(names)
        if positions.size != k or velocities.size not in (0, k) or efforts.size not in (0, k):
            return None, REJECT_ARRAY_LENGTHS
        if len(set(names)) != k:
            return None, REJECT_DUPLICATE_NAMES
        index = {n: i for i, n in enumerate(names)}
        try:
            idx = np.array([index[n] for n in self.config.names], dtype=np.intp)
        except KeyError:
            return None, REJECT_JOINT_MISSING
        q = positions[idx]
        use_vel = self.config.use_velocities and velocities.size == k
        w = velocities[idx] if use_vel else None
        if not np.all(np.isfinite(q)) or (w is not None and not np.all(np.isfinite(w))):
            return None, REJECT_NONFINITE
        t = int(js.stamp_ns)
        if self._last_ns is not None and t <= self._last_ns:
            return None, REJECT_STAMP_NOT_INCREASING
        last_ns, last_q = self._last_ns, self._last_positions
        self._last_ns, self._last_positions = t, q
        r = self.config.wheel_radius
        if w is not None:
            speeds, stamp = r * w, t
        elif last_q is None:
            return None, None
        else:
            speeds = r * (q - last_q) * (NS_PER_S / (t - last_ns))
            stamp = last_ns + (t - last_ns) // 2
        if not np.all(np.abs(speeds) <= self.config.max_speed):
            self.jumps += 1
            return None, REJECT_ENCODER_JUMP
        return EncoderSample(stamp, speeds), None


def validate_encoder_config(cfg: EncoderInputConfig) -> str | None:
    """What is wrong with ``cfg`` (a sentence naming the field), or None."""
    if len(cfg.names) not in (2, 3) or not all(isinstance(n, str) and n for n in cfg.names):
        return "names: 2 (left, right) or 3 (left, right, lateral) non-empty joint names"
    if len(set(cfg.names)) != len(cfg.names):
        return "names: distinct joint names"
    for name in ("wheel_radius", "half_spacing", "max_speed"):
        v = getattr(cfg, name)
        if not (math.isfinite(v) and v > 0.0):
            return f"{name}: a finite value > 0"
    if not math.isfinite(cfg.lateral_offset):
        return "lateral_offset: a finite value"
    if not (math.isfinite(cfg.speed_variance_coeff) and cfg.speed_variance_coeff >= 0.0):
        return "speed_variance_coeff: a finite value >= 0"
    if not (math.isfinite(cfg.speed_variance_floor) and cfg.speed_variance_floor > 0.0):
        return "speed_variance_floor: a finite variance > 0 ((m/s)²)"
    return None
