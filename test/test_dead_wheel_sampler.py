"""The dead-wheel sample against seed 000's formulas: eq. 30 (true speeds), 32 (noise), 29 (twist).

The sampler and the expectations use the same standard-normal draws, so they agree to rounding:
a sum of k products differs from the exact one by at most γ_k·Σ|terms| (γ_k = k·u/(1 − k·u),
u = 2⁻⁵³), a few 1e-16 of the terms' magnitudes here. ``REL`` = 1e-12 of that magnitude is far
above every such bound and far below any error of a formula.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers.sim_world import assert_variance

from ekf_localization.models.sensors.dead_wheels import encoders_to_twist, speed_variance
from sim_robot.world.dead_wheel_sensor import DeadWheelConfig, DeadWheelSensor

REL = 1e-12
PERIOD_NS = 10_000_000


def _eq30(twist: np.ndarray, W: float, D: float) -> np.ndarray:
    """[E_L E_R E_a] = [ẋ − Wθ̇, ẋ + Wθ̇, ẏ − Dθ̇]."""
    vx, vy, wz = twist.T
    return np.column_stack([vx - W * wz, vx + W * wz, vy - D * wz])


def _eq29(E: np.ndarray, W: float, D: float) -> np.ndarray:
    """[ẋ ẏ θ̇] from θ̇ = (E_R − E_L)/(2W), ẋ = (E_R + E_L)/2, ẏ = E_a + Dθ̇."""
    EL, ER, Ea = E.T
    wz = (ER - EL) / (2.0 * W)
    return np.column_stack([(ER + EL) / 2.0, Ea + D * wz, wz])


def _terms(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Σ_j |M_ij·X_j| per row of X: the magnitude that bounds the rounding of X Mᵀ."""
    return np.abs(X) @ np.abs(M).T


def _assert_close(got: np.ndarray, want: np.ndarray, magnitude: np.ndarray, what: str) -> None:
    err = np.abs(got - want)
    assert np.all(err <= REL * magnitude), f"{what}: max error {err.max():.3g}"


@pytest.mark.parametrize("sampling", ["instantaneous", "interval_average"])
@pytest.mark.parametrize("n", [1, 2, 7, 100])
def test_sample_follows_eq_29_30_32(sampling, n):
    cfg = DeadWheelConfig(sampling=sampling, integrate_pose=False)
    W, D = cfg.geometry.half_track, cfg.geometry.lateral_offset
    a, b = cfg.noise.speed_variance_coeff, cfg.noise.variance_floor
    sensor = DeadWheelSensor(cfg, n, np.random.default_rng(7))
    draws = np.random.default_rng(7)  # the same stream as the sensor's
    rng = np.random.default_rng(8)
    disp = np.zeros((n, 3))
    distances = np.zeros((n, 3))
    dt = PERIOD_NS * 1e-9
    A, M = cfg.geometry.encoders_from_twist, cfg.geometry.twist_from_encoders
    distance_terms = np.zeros((n, 3))
    for k in range(1, 40):
        vel = rng.standard_normal((n, 3)) * [1.0, 1.0, 3.0]
        last = disp.copy()
        disp = disp + dt * vel + 1e-4 * rng.standard_normal((n, 3))
        r = sensor.sample(k * PERIOD_NS, vel, disp)
        z = draws.standard_normal((n, 3))

        average = (disp - last) / dt
        true = average if sampling == "interval_average" else vel
        E_true = _eq30(true, W, D)
        noise = np.sqrt(a * E_true**2 + b) * z  # eq. 32 at the true speed
        E = E_true + noise
        _assert_close(r.encoders, E, _terms(true, A) + np.abs(noise), "encoders")
        _assert_close(r.encoder_variances, a * E**2 + b, a * E**2 + b, "encoder variances")

        _assert_close(r.twist, _eq29(E, W, D), _terms(E, M), "twist")
        want_twist, want_cov = encoders_to_twist(cfg.geometry, E, cfg.noise.covariance(E))
        _assert_close(r.twist, want_twist, _terms(E, M), "twist (model)")
        _assert_close(r.twist_cov, want_cov, np.abs(M) @ cfg.noise.covariance(E) @ np.abs(M).T,
                      "twist covariance")

        E_avg = _eq30(average, W, D)
        avg_noise = np.sqrt(a * E_avg**2 + b) * z  # the distance over the period: the same draw
        distances = distances + (E_avg + avg_noise) * dt
        distance_terms += (_terms(average, A) + np.abs(avg_noise)) * dt
        _assert_close(r.distances, distances, k * distance_terms, "distances")


def test_sampled_noise_has_the_variance_of_eq_32():
    """Residuals E − E_true over 20 000 trials at a fixed seed: chi-square bounds on eq. 32's
    variance (``helpers.sim_world.assert_variance``, false-failure probability 1e-6 each),
    separately where the floor and where the speed term dominates."""
    n = 20_000
    cfg = DeadWheelConfig(integrate_pose=False)
    a, b = cfg.noise.speed_variance_coeff, cfg.noise.variance_floor
    sensor = DeadWheelSensor(cfg, n, np.random.default_rng(21))
    vel = np.zeros((n, 3))
    vel[n // 2:] = [2.0, -1.5, 3.0]  # |E| of 1.5-2.5 m/s: a·E² is 10⁴ times the floor
    r = sensor.sample(PERIOD_NS, vel, vel * PERIOD_NS * 1e-9)
    E_true = vel @ cfg.geometry.encoders_from_twist.T
    variance = speed_variance(E_true, a, b)
    for part, name in ((slice(0, n // 2), "at rest (floor)"), (slice(n // 2, n), "moving (a·E²)")):
        for i, encoder in enumerate(("E_L", "E_R", "E_a")):
            unit = (r.encoders[part, i] - E_true[part, i]) / np.sqrt(variance[part, i])
            assert_variance(unit, 1.0, f"{encoder} {name}")
