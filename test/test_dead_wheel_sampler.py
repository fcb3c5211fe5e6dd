"""The compiled dead-wheel sample (eq. 29, 30, 32) against the numpy formulas it replaced.

Where numpy's matmul forms its products by fused multiply-adds (this machine's OpenBLAS, for
an (N >= 2, 3) by (3, 3) product and for 3×3 stacks), the kernel's ``kernels.dot3_fma`` gives
the same bits, so every experiment's numbers are unchanged; elsewhere they agree to rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

from ekf_localization.core.kernels import dot3_fma, njit
from ekf_localization.models.sensors.dead_wheels import encoders_to_twist
from sim_robot.world.dead_wheel_sensor import DeadWheelConfig, DeadWheelSensor


@njit(cache=False)
def _rows_fma(X, A, out):  # pragma: no cover - compiled
    for b in range(X.shape[0]):
        for i in range(A.shape[0]):
            out[b, i] = dot3_fma(X[b, 0], X[b, 1], X[b, 2], A[i, 0], A[i, 1], A[i, 2])


def _blas_is_fma() -> bool:
    """Whether numpy's (N, 3) @ (3, 3) here equals the fused multiply-add chain."""
    rng = np.random.default_rng(3)
    X, A = rng.standard_normal((1000, 3)), rng.standard_normal((3, 3))
    out = np.empty((1000, 3))
    _rows_fma(X, A, out)
    return bool(np.array_equal(out, X @ A.T))


def _numpy_sample(cfg: DeadWheelConfig, dt_s, vel, disp, last_disp, distances, z):
    """The numpy formulation the kernel replaced: the model's eq. 32 (EncoderNoise) and
    eq. 29 (encoders_to_twist)."""
    A = cfg.geometry.encoders_from_twist
    average = (disp - last_disp) / dt_s
    true = average if cfg.sampling == "interval_average" else vel
    E_true = true @ A.T
    E = E_true + np.sqrt(cfg.noise.variances(E_true)) * z
    E_avg = average @ A.T
    distances = distances + (E_avg + np.sqrt(cfg.noise.variances(E_avg)) * z) * dt_s
    var = cfg.noise.variances(E)
    twist, twist_cov = encoders_to_twist(cfg.geometry, E, cfg.noise.covariance(E))
    return E, var, twist, twist_cov, distances


@pytest.mark.parametrize("sampling", ["instantaneous", "interval_average"])
@pytest.mark.parametrize("n", [1, 2, 7, 100])
def test_sample_matches_the_numpy_formulas(sampling, n):
    cfg = DeadWheelConfig(sampling=sampling, integrate_pose=False)
    sensor = DeadWheelSensor(cfg, n, np.random.default_rng(7))
    draws = np.random.default_rng(7)  # the same stream as the sensor's
    rng = np.random.default_rng(8)
    disp = np.zeros((n, 3))
    distances = np.zeros((n, 3))
    exact = _blas_is_fma() and n >= 2  # numpy takes a different BLAS path for one row
    for k in range(1, 40):
        vel = rng.standard_normal((n, 3)) * [1.0, 1.0, 3.0]
        last = disp.copy()
        disp = disp + 0.01 * vel + 1e-4 * rng.standard_normal((n, 3))
        reading = sensor.sample(k * 10_000_000, vel, disp)
        expected = _numpy_sample(cfg, 0.01, vel, disp, last, distances, draws.standard_normal((n, 3)))
        distances = expected[4]
        got = (reading.encoders, reading.encoder_variances, reading.twist, reading.twist_cov,
               reading.distances)
        for g, e in zip(got, expected, strict=True):
            if exact:
                assert np.array_equal(g, e)
            else:
                np.testing.assert_allclose(g, e, rtol=1e-14, atol=1e-300)
