"""The drive's own wheel encoders, as a motor driver reports them (no ROS imports).

Each wheel's angle (rad) is the integral of its actual speed (``World.wheel_speeds``, rad/s,
positive = the wheel pushes the robot forward): the body's own velocity noise (eq. 26, the
wheels slipping on the floor) is not in it. A reading carries

* ``positions``: the angles quantised to whole encoder counts, ``floor(angle / q)·q`` with
  q = ``resolution`` rad (0: exact), as an incremental encoder counts;
* ``velocities``: the wheels' actual speeds at the stamp (rad/s);

at intervals that jitter as a real driver's do (a USB or CAN hub read out by a busy loop):
``min_interval_ns`` plus an exponential delay of mean ``period_ns - min_interval_ns``, cut
at ``max_interval_ns`` and rounded to the physics tick; the defaults give 16-41 ms around
20 ms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WheelEncoderConfig:
    """Mean interval, its bounds (ns), encoder resolution (rad per count); off by default."""

    enabled: bool = False
    period_ns: int = 20_000_000
    min_interval_ns: int = 16_000_000
    max_interval_ns: int = 41_000_000
    resolution: float = 2.0 * math.pi / 537.7  # a 19.2:1 FTC motor's 537.7 counts per wheel turn

    def __post_init__(self) -> None:
        if not (0 < self.min_interval_ns <= self.period_ns <= self.max_interval_ns):
            raise ValueError("wheel encoder intervals need 0 < min_interval_ns <= period_ns "
                             "<= max_interval_ns, "
                             f"got {self.min_interval_ns}, {self.period_ns}, {self.max_interval_ns}")
        if not (math.isfinite(self.resolution) and self.resolution >= 0.0):
            raise ValueError(f"wheel encoder resolution must be a finite angle >= 0 (rad), "
                             f"got {self.resolution!r}")


@dataclass(frozen=True)
class WheelEncoderReading:
    """One encoder read-out for N trials: quantised angles (N, k) rad and speeds (N, k) rad/s; a
    swerve's modules also have their steer angles (N, k) rad in (−π, π] and rates (N, k) rad/s."""

    stamp_ns: int
    positions: np.ndarray
    velocities: np.ndarray
    steer_angles: np.ndarray | None = None
    steer_rates: np.ndarray | None = None


class WheelEncoderSensor:
    """Integrates the wheel angles tick by tick; samples them on a jittered schedule."""

    def __init__(self, config: WheelEncoderConfig, n_trials: int, n_wheels: int, tick_ns: int,
                 rng: np.random.Generator) -> None:
        self.config = config
        self._tick_ns = tick_ns
        self._rng = rng
        self._angles = np.zeros((n_trials, n_wheels))

    def reset(self, t_ns: int) -> int:
        """Angles to 0; the time of the first read-out."""
        self._angles[:] = 0.0
        return t_ns + self.next_interval_ns()

    def next_interval_ns(self) -> int:
        cfg = self.config
        extra = self._rng.exponential(max(cfg.period_ns - cfg.min_interval_ns, 1))
        ns = min(cfg.min_interval_ns + extra, cfg.max_interval_ns)
        return max(self._tick_ns, int(round(ns / self._tick_ns)) * self._tick_ns)

    def integrate(self, wheel_speeds: np.ndarray, dt_s: float) -> None:
        """One physics tick of the wheels turning at ``wheel_speeds`` (N, k) rad/s."""
        self._angles += dt_s * wheel_speeds

    def sample(self, t_ns: int, wheel_speeds: np.ndarray, steer_angles: np.ndarray | None = None,
               steer_rates: np.ndarray | None = None) -> WheelEncoderReading:
        q = self.config.resolution
        positions = np.floor(self._angles / q) * q if q > 0.0 else self._angles.copy()
        steer = None if steer_angles is None else np.array(steer_angles, dtype=float)
        rates = None if steer_rates is None else np.array(steer_rates, dtype=float)
        return WheelEncoderReading(t_ns, positions, np.array(wheel_speeds, dtype=float), steer, rates)
