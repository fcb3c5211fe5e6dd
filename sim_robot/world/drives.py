"""Drive kinematics and wheel limits of the simulated robot (no ROS imports).

Both drives map a body twist ``[vx vy wz]`` (REP-103: x forward, y left, yaw CCW) to
wheel angular speeds (rad/s, positive = the wheel pushes the robot forward) and back.

* Mecanum: ``ekf_localization.models.mecanum.MecanumKinematics`` (seed 000, eq. 23-24).
  Wheel order ``[m1 m2 m3 m4]`` = rear-left, rear-right, front-left, front-right; rollers
  in the standard X pattern (the top rollers form an X seen from above). Signs of each
  wheel for a positive motion (from eq. 24 inverted):

  ============  ====  ====  ====  ====
  motion         m1    m2    m3    m4
  ============  ====  ====  ====  ====
  +vx forward     +     +     +     +
  +vy left        +     -     -     +
  +wz CCW         -     +     -     +
  ============  ====  ====  ====  ====

* Tank (differential): ``TankKinematics`` below, wheels ``[left right]``; vy is ignored.

Limits (``DriveLimits``) model the motors: the commanded wheel speeds are scaled down
together when one exceeds the speed limit (the usual FTC normalisation, which keeps the
direction of motion), and the actual wheel speeds move toward the command at most
``wheel_acceleration_limit · Δt`` per physics tick, again scaling the change of all
wheels together so a step command ramps along a straight line in wheel space.
Both limits are in rad/s and rad/s², so they do not depend on the length unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ekf_localization.models.mecanum import MecanumKinematics

DRIVES = ("mecanum", "tank", "swerve")  # swerve: sim_robot.world.swerve_drive


class DriveKinematics(Protocol):
    """What the world needs from a drive: the forward and inverse wheel matrices."""

    @property
    def forward_matrix(self) -> np.ndarray: ...  # (3, k) wheels -> body twist

    @property
    def inverse_matrix(self) -> np.ndarray: ...  # (k, 3) body twist -> wheels


@dataclass(frozen=True)
class TankKinematics:
    """Differential drive: wheel radius r and half track b (wheel centre to centre line)."""

    wheel_radius: float
    half_track: float

    def __post_init__(self) -> None:
        for name in ("wheel_radius", "half_track"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name} must be a positive finite number, got {v!r}")

    @property
    def forward_matrix(self) -> np.ndarray:
        """(3, 2) wheels [left right] -> body twist: vx = r(wl+wr)/2, vy = 0, wz = r(wr-wl)/(2b)."""
        r, b = self.wheel_radius, self.half_track
        return np.array([[0.5 * r, 0.5 * r], [0.0, 0.0], [-0.5 * r / b, 0.5 * r / b]])

    @property
    def inverse_matrix(self) -> np.ndarray:
        """(2, 3) body twist -> wheels: wl = (vx - b·wz)/r, wr = (vx + b·wz)/r (vy ignored)."""
        r, b = self.wheel_radius, self.half_track
        return np.array([[1.0 / r, 0.0, -b / r], [1.0 / r, 0.0, b / r]])

    def wheels_to_twist(self, wheels: np.ndarray) -> np.ndarray:
        return np.asarray(wheels, dtype=float) @ self.forward_matrix.T

    def twist_to_wheels(self, twist: np.ndarray) -> np.ndarray:
        return np.asarray(twist, dtype=float) @ self.inverse_matrix.T


@dataclass(frozen=True)
class DriveLimits:
    """Wheel speed (rad/s) and acceleration (rad/s²) limits; ``math.inf`` disables a limit."""

    wheel_speed_limit: float = math.inf
    wheel_acceleration_limit: float = math.inf

    def __post_init__(self) -> None:
        for name in ("wheel_speed_limit", "wheel_acceleration_limit"):
            v = getattr(self, name)
            if math.isnan(v) or v <= 0.0:
                raise ValueError(f"{name} must be > 0 (math.inf disables it), got {v!r}")


def scale_to_speed_limit(wheels: np.ndarray, limit: float) -> np.ndarray:
    """Scale each row of (N, k) wheel speeds so that max |w| <= limit, keeping ratios."""
    wheels = np.asarray(wheels, dtype=float)
    if math.isinf(limit):
        return wheels.copy()
    peak = np.max(np.abs(wheels), axis=-1, keepdims=True)
    scale = np.ones_like(peak)
    np.divide(limit, peak, out=scale, where=peak > limit)  # only rows above the limit shrink
    return wheels * scale


def make_drive(drive: str, mecanum: MecanumKinematics, tank: TankKinematics) -> DriveKinematics:
    """The kinematics object for ``drive`` ("mecanum" or "tank")."""
    if drive == "mecanum":
        return mecanum
    if drive == "tank":
        return tank
    raise ValueError(f"drive must be one of {DRIVES}, got {drive!r}")
