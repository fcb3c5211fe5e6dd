"""IMU: roll, pitch, yaw (integrated heading), yaw rate (gyro z) and planar body acceleration.

Each output is the truth plus independent Gaussian noise of the configured variance:
yaw in the field frame (an IMU whose heading was initialised with the known start
heading), wrapped to (-π, π]; yaw rate = true wz; acceleration = the world's true body
acceleration ``[ax ay]`` (``World.truth_accel``, length unit/s², gravity not included, also
on a ramp) averaged by the world over the IMU's sample period (an accelerometer's low-pass
filter: a drive's tick-to-tick switching is not aliased). Roll and pitch are the robot's tilt
on the field surface (a ramp, ``sim_robot.world.ramp``; 0 on level ground) plus noise of
``tilt_variance``, drawn from a separate random stream so that the other outputs' noise does
not depend on it. The yaw rate
is about the body z axis (on a slope: the heading rate times cos(pitch) / cos(roll)).

A miscalibrated gyro: the yaw rate it reports is ``yaw_rate_scale * true + yaw_rate_bias``
plus its noise (docs/models.md, "IMU yaw-rate scale and bias"); the yaw output, the IMU's
own fused heading, stays the true heading plus noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.angles import wrap_angles


@dataclass(frozen=True)
class ImuConfig:
    """Sample period (ns) and noise variances: rad², (rad/s)², (length unit/s²)²; SI defaults."""

    period_ns: int = 10_000_000
    yaw_variance: float = math.radians(0.5) ** 2
    yaw_rate_variance: float = 1e-4
    accel_variance: float = 0.01
    enabled: bool = True
    tilt_variance: float = math.radians(0.5) ** 2  # rad², roll and pitch
    yaw_rate_scale: float = 1.0  # reported / true yaw rate
    yaw_rate_bias: float = 0.0  # rad/s, added to the reported yaw rate

    def __post_init__(self) -> None:
        if not (isinstance(self.period_ns, int) and self.period_ns > 0):
            raise ValueError(f"imu period_ns must be a positive int, got {self.period_ns!r}")
        if not (math.isfinite(self.yaw_rate_scale) and self.yaw_rate_scale > 0.0):
            raise ValueError(f"imu yaw_rate_scale must be finite and > 0, got {self.yaw_rate_scale!r}")
        if not math.isfinite(self.yaw_rate_bias):
            raise ValueError(f"imu yaw_rate_bias must be finite, got {self.yaw_rate_bias!r}")
        for name in ("yaw_variance", "yaw_rate_variance", "accel_variance", "tilt_variance"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"imu {name} must be finite and > 0, got {v!r}")


@dataclass(frozen=True)
class ImuReading:
    """One IMU sample for N trials."""

    stamp_ns: int
    yaw: np.ndarray  # (N,)
    yaw_rate: np.ndarray  # (N,)
    accel: np.ndarray  # (N, 2) body frame
    yaw_variance: float
    yaw_rate_variance: float
    accel_variance: float
    tilt: np.ndarray | None = None  # (N, 2) roll, pitch
    tilt_variance: float = math.radians(0.5) ** 2


class ImuSensor:
    def __init__(self, config: ImuConfig, n_trials: int, rng: np.random.Generator,
                 tilt_rng: np.random.Generator | None = None) -> None:
        self.config = config
        self.n = n_trials
        self._rng = rng
        self._tilt_rng = tilt_rng if tilt_rng is not None else np.random.default_rng(0)
        self._std = np.sqrt([config.yaw_variance, config.yaw_rate_variance,
                             config.accel_variance, config.accel_variance])

    def sample(self, t_ns: int, yaw: np.ndarray, yaw_rate: np.ndarray, accel: np.ndarray,
               tilt: np.ndarray | None = None) -> ImuReading:
        z = self._rng.standard_normal((self.n, 4)) * self._std
        cfg = self.config
        true_tilt = np.zeros((self.n, 2)) if tilt is None else np.asarray(tilt, dtype=float)
        noisy_tilt = true_tilt + self._tilt_rng.standard_normal((self.n, 2)) * math.sqrt(cfg.tilt_variance)
        gyro = cfg.yaw_rate_scale * yaw_rate + cfg.yaw_rate_bias
        return ImuReading(t_ns, wrap_angles(yaw + z[:, 0]), gyro + z[:, 1], accel + z[:, 2:4],
                          cfg.yaw_variance, cfg.yaw_rate_variance, cfg.accel_variance, noisy_tilt,
                          cfg.tilt_variance)
