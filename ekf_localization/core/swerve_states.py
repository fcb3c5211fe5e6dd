"""Swerve module states from sensor_msgs/JointState records (no ROS imports).

Each module has a steer joint (position: the wheel's direction φ in the body frame, rad, 0 along
x) and a drive joint (position or velocity, rad of the drive joint). The drive joint turns
``drive_gear_ratio`` G times per wheel turn, and on a coaxial module (MK4i and the like) also
``coupling_ratio`` c times per turn of the steering, so the wheel turns by

    Δwheel = (Δdrive − c·Δφ) / G

and rolls ``wheel_radius`` · Δwheel along the floor. :class:`SwerveSpeeds` turns successive
messages into a :class:`SwerveSample`: each module's speed along its wheel (m/s) and its steer
angle, stamped like the encoder speeds of core.joint_states: from positions, the mean over the
interval at its middle (the angle at the middle, halfway between the two readings); from the
message's velocities (``use_velocities``), at the message (the steer angle is then the message's
position; a message without positions has no angle and is rejected as ``field_not_provided``).
Steer angle steps are taken modulo 2π (a steer joint that wraps at ±π is read across the wrap).
The message checks (names, array lengths, finite values, increasing stamps, speeds within
``max_speed``) are those of core.joint_states.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.joint_states import EncoderInputConfig, read_joints
from ekf_localization.core.measurements import (
    REJECT_ENCODER_JUMP,
    REJECT_NOT_PROVIDED,
    REJECT_STAMP_NOT_INCREASING,
    JointStateMeasurement,
)
from ekf_localization.core.units import NS_PER_S


@dataclass(frozen=True)
class SwerveSample:
    """Module speeds along the wheel (N,) m/s and steer angles (N,) rad at ``stamp_ns``;
    ``interval_ns``: the position difference's interval (None: the message's velocities)."""

    stamp_ns: int
    speeds: np.ndarray
    angles: np.ndarray
    interval_ns: int | None = None


class SwerveSpeeds:
    """Successive JointState records -> :class:`SwerveSample` (module docstring)."""

    def __init__(self, config: EncoderInputConfig) -> None:
        self.config = config
        n = len(config.names)
        self._joints = tuple(config.names) + tuple(config.steer_names)
        self._signs = np.concatenate([config.signs, np.ones(n)])
        self._n = n
        self.jumps = 0
        self.last_jump_rate = 0.0  # rad/s of the wheel implied by the last encoder_jump
        self.reset()

    def reset(self) -> None:
        self._last_ns: int | None = None
        self._last_q: np.ndarray | None = None

    def update(self, js: JointStateMeasurement) -> tuple[SwerveSample | None, str | None]:
        """(sample, None), (None, None) while there is no baseline yet, or (None, reason)."""
        cfg, n = self.config, self._n
        q, w, reason = read_joints(js, self._joints, self._signs, cfg.use_velocities)
        if reason is not None:
            return None, reason
        if q is None:
            return None, REJECT_NOT_PROVIDED  # no steer angle without positions
        t = int(js.stamp_ns)
        if self._last_ns is not None and t <= self._last_ns:
            return None, REJECT_STAMP_NOT_INCREASING
        last_ns, last_q = self._last_ns, self._last_q
        self._last_ns, self._last_q = t, q
        G, c = cfg.drive_gear_ratio, cfg.coupling_ratio
        if w is not None:
            wheel = (w[:n] - c * w[n:]) / G
            angles, stamp, interval = wrap_angles(q[n:]), t, None
        elif last_q is None:
            return None, None
        else:
            interval = t - last_ns
            turned = wrap_angles(q[n:] - last_q[n:])
            wheel = (q[:n] - last_q[:n] - c * turned) / G * (NS_PER_S / interval)
            angles = wrap_angles(last_q[n:] + 0.5 * turned)
            stamp = last_ns + interval // 2
        speeds = cfg.wheel_radius * wheel
        if not np.all(np.abs(speeds) <= cfg.max_speed):
            self.jumps += 1
            self.last_jump_rate = float(np.max(np.abs(wheel)))
            return None, REJECT_ENCODER_JUMP
        return SwerveSample(stamp, speeds, angles, interval), None
