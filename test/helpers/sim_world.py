"""Simulated-world test helpers: a noiseless world config and a statistical variance check."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import stats

from ekf_localization.models.sensors.camera import CameraNoise
from ekf_localization.models.sensors.dead_wheels import EncoderNoise
from sim_robot.world.imu_sensor import ImuConfig
from sim_robot.world.world import WorldConfig

MS = 1_000_000
ALPHA = 1e-6  # false-failure probability of each statistical bound (the seeds are fixed anyway)
TINY = 1e-300  # a noise floor that is effectively zero


def noiseless(cfg: WorldConfig) -> WorldConfig:
    """``cfg`` with Q = 0 and sensor noise floors effectively zero."""
    return dataclasses.replace(
        cfg, pose_variance_rate=(0.0, 0.0, 0.0), velocity_variance_per_step=(0.0, 0.0, 0.0),
        dead_wheels=dataclasses.replace(cfg.dead_wheels, noise=EncoderNoise(0.0, TINY)),
        camera=dataclasses.replace(cfg.camera, position_noise=CameraNoise(0.0, TINY),
                                   yaw_noise=CameraNoise(0.0, TINY)),
        imu=ImuConfig(cfg.imu.period_ns, TINY, TINY, TINY))


def assert_variance(samples: np.ndarray, variance: float, name: str) -> None:
    """Two-sided chi-square bound on the sample variance (known mean 0 not assumed)."""
    n = samples.size
    s2 = float(np.var(samples, ddof=1))
    lo = variance * stats.chi2.ppf(ALPHA / 2, n - 1) / (n - 1)
    hi = variance * stats.chi2.ppf(1 - ALPHA / 2, n - 1) / (n - 1)
    assert lo <= s2 <= hi, f"{name}: sample variance {s2:.6g} outside [{lo:.6g}, {hi:.6g}] (n={n})"
    half_width = stats.norm.ppf(1 - ALPHA / 2) * math.sqrt(variance / n)
    assert abs(float(np.mean(samples))) <= half_width, f"{name}: mean {np.mean(samples):.3g} not 0"
