"""The simulated swerve drive: steered modules with limits, on a floor of limited grip (no ROS).

Each of the k modules (``models.swerve.SwerveKinematics``: positions in the body frame) has a
steer angle φ (rad, continuous) and a wheel rate ω (rad/s). Every physics tick of Δt:

1. targets: the commanded twist's module speeds and angles (the inverse kinematics, each module
   taking the nearer of (s, φ) and (−s, φ + π)), all speeds scaled together so that no wheel
   exceeds ``wheel_speed_limit``;
2. steering: φ moves toward its target at most ``steer_rate_limit``·Δt;
3. drive: ω moves toward its target rate times cos(steer error) (a module pointing away from its
   target does not push the wrong way) at most ``drive_acceleration_limit``·Δt;
4. floor: the modules' velocity vectors uᵢ = r·ω (cos φ, sin φ) ask for the body twist v* of their
   least-squares fit; the change this asks of each contact point, A_i (v* − v), is limited to
   ``traction_limit``·Δt (the floor's grip, μ·g): the twist moves toward v* by the largest
   fraction every module's grip allows. A module whose wheel outruns the floor slips: its
   slip ``|uᵢ − A_i v|`` (m/s) is what the wheel says and the body does not do.

The drive joint the encoders read turns ``drive_gear_ratio`` times per wheel turn plus
``coupling_ratio`` times per steering turn (a coaxial module: :meth:`SwerveDrive.joint_rates`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.models.swerve import SwerveKinematics

MODULE_HALF_SPACING_M = 0.26  # modules at (±0.26, ±0.26) m: a 0.52 m square wheelbase


def _square(h: float) -> np.ndarray:
    """Modules FL, FR, RL, RR at (±h, ±h)."""
    return np.array([[h, h], [h, -h], [-h, h], [-h, -h]])


@dataclass(frozen=True)
class SwerveDriveConfig:
    """A swerve drive's geometry and limits (``math.inf``: no limit)."""

    kinematics: SwerveKinematics = field(
        default_factory=lambda: SwerveKinematics(_square(MODULE_HALF_SPACING_M)))
    wheel_radius: float = 0.0508  # m (4 in wheels)
    steer_rate_limit: float = 12.0  # rad/s
    drive_acceleration_limit: float = 100.0  # rad/s² of the wheel (5.1 m/s² at the rim)
    wheel_speed_limit: float = 90.0  # rad/s of the wheel (4.6 m/s)
    traction_limit: float = 8.0  # m/s²: the most the floor changes a contact point's velocity
    drive_gear_ratio: float = 6.75  # drive joint rad per wheel rad
    coupling_ratio: float = 50.0 / 14.0  # drive joint rad per steering rad (coaxial module)

    def __post_init__(self) -> None:
        for name in ("wheel_radius", "steer_rate_limit", "drive_acceleration_limit", "wheel_speed_limit",
                     "traction_limit", "drive_gear_ratio"):
            v = float(getattr(self, name))
            if math.isnan(v) or v <= 0.0 or (name in ("wheel_radius", "drive_gear_ratio") and math.isinf(v)):
                raise ValueError(f"swerve {name} must be > 0, got {v!r}")
        if not math.isfinite(self.coupling_ratio):
            raise ValueError(f"swerve coupling_ratio must be finite, got {self.coupling_ratio!r}")

    @property
    def n_modules(self) -> int:
        return self.kinematics.n_modules


class SwerveDrive:
    """k modules of N trials stepped together (module docstring)."""

    def __init__(self, config: SwerveDriveConfig, n_trials: int) -> None:
        self.config = config
        self._A = config.kinematics.module_rows  # (2k, 3)
        self._fit = np.linalg.pinv(self._A)  # (3, 2k): the least-squares twist of module vectors
        self._n = n_trials
        self.reset()

    def reset(self) -> None:
        k = self.config.n_modules
        self.angles = np.zeros((self._n, k))  # continuous steer angles, rad
        self.steer_rates = np.zeros((self._n, k))
        self.wheel_rates = np.zeros((self._n, k))  # rad/s of the wheel
        self.twist = np.zeros((self._n, 3))  # the body's drive twist (noise-free)
        self.slip = np.zeros((self._n, k))  # m/s, wheel velocity minus contact-point velocity

    def joint_rates(self) -> np.ndarray:
        """(N, k) drive joint rad/s: gear ratio × wheel + coupling × steering rate."""
        cfg = self.config
        return cfg.drive_gear_ratio * self.wheel_rates + cfg.coupling_ratio * self.steer_rates

    def step(self, command: np.ndarray, dt: float) -> np.ndarray:
        """One tick toward the commanded twist (N, 3); returns the body twist (N, 3)."""
        cfg = self.config
        speeds, target = cfg.kinematics.twist_to_modules(command, current_angles=self.angles)
        peak = np.max(np.abs(speeds), axis=1, keepdims=True) / cfg.wheel_radius
        scale = np.ones_like(peak)
        np.divide(cfg.wheel_speed_limit, peak, out=scale, where=peak > cfg.wheel_speed_limit)
        error = wrap_angles(target - self.angles)
        turn = np.clip(error, -cfg.steer_rate_limit * dt, cfg.steer_rate_limit * dt)
        self.steer_rates = turn / dt
        self.angles = self.angles + turn
        want = scale * speeds / cfg.wheel_radius * np.cos(error - turn)
        dw = cfg.drive_acceleration_limit * dt
        self.wheel_rates = self.wheel_rates + np.clip(want - self.wheel_rates, -dw, dw)
        s = cfg.wheel_radius * self.wheel_rates
        u = np.stack([s * np.cos(self.angles), s * np.sin(self.angles)], axis=-1).reshape(self._n, -1)
        change = (u @ self._fit.T) - self.twist  # toward the modules' least-squares twist
        asked = (change @ self._A.T).reshape(self._n, -1, 2)
        peak_ask = np.max(np.hypot(asked[..., 0], asked[..., 1]), axis=1, keepdims=True)
        grip = np.ones_like(peak_ask)
        np.divide(cfg.traction_limit * dt, peak_ask, out=grip, where=peak_ask > cfg.traction_limit * dt)
        self.twist = self.twist + grip * change
        rest = (u - self.twist @ self._A.T).reshape(self._n, -1, 2)
        self.slip = np.hypot(rest[..., 0], rest[..., 1])
        return self.twist.copy()
