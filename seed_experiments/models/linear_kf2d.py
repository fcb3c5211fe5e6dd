"""The minimal linear Kalman filter of seed 004: 2D position, wheel-speed motion, scaled fix.

State ``[x y]`` (m). Motion (seed 004 eq. 1), predicted at 8 Hz::

    ẋ = r/2·(u_r + u_l) + w_x      ẏ = r/2·(u_r + u_l) + w_y

with wheel speeds u = [u_r, u_l] (rad/s) and wheel radius r = 0.1 m (0.1 m/s at 1 rad/s).
Measurement at 1 Hz: ``z = diag(1, 2)·[x y] + [r_x r_y]``.

Every noise figure is a standard deviation (the seed's own conclusion: N(0, 0.1) etc. are
standard deviations, and ``numpy.random.normal`` takes one): w_x, w_y have 0.1, 0.15 m per
motion step; r_x, r_y have 0.05, 0.075 (in measurement units). They are squared into the
variances of Q and R here. The filter is the EKF engine on a linear model, which is the
Kalman filter exactly.
"""

from __future__ import annotations

import numpy as np

from ekf_localization.core.linear import LinearMeasurement, LinearProcessModel
from ekf_localization.core.units import NS_PER_S

MOTION_PERIOD_NS = 125_000_000  # 8 Hz
MEASUREMENT_PERIOD_NS = NS_PER_S  # 1 Hz
WHEEL_RADIUS = 0.1  # m
MEASUREMENT_MATRIX = np.diag([1.0, 2.0])


def _stds(name: str, value: tuple[float, float] | np.ndarray) -> np.ndarray:
    s = np.asarray(value, dtype=float)
    if s.shape != (2,) or not np.all(np.isfinite(s)) or np.any(s < 0.0):
        raise ValueError(f"{name} must be two finite non-negative standard deviations, got {value!r}")
    return s


def motion_model(wheel_radius: float = WHEEL_RADIUS,
                 process_std_per_step: tuple[float, float] = (0.1, 0.15)) -> LinearProcessModel:
    """x' = x + Δt·r/2·(u_r + u_l)·[1, 1]; Q = diag(process_std_per_step²) at every motion step.

    Control U is (N, 2) = [u_r, u_l] in rad/s.
    """
    if not (np.isfinite(wheel_radius) and wheel_radius > 0.0):
        raise ValueError(f"wheel_radius must be a positive length in metres, got {wheel_radius!r}")
    B = 0.5 * float(wheel_radius) * np.ones((2, 2))
    return LinearProcessModel(B, variance_per_step=_stds("process_std_per_step", process_std_per_step) ** 2)


def position_measurement() -> LinearMeasurement:
    """z = diag(1, 2)·[x y]."""
    return LinearMeasurement(MEASUREMENT_MATRIX)


def measurement_covariance(measurement_std: tuple[float, float] = (0.05, 0.075)) -> np.ndarray:
    """R = diag(measurement_std²) (measurement units: m for z_1, 2·m for z_2)."""
    return np.diag(_stds("measurement_std", measurement_std) ** 2)
