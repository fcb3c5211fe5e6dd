"""core.process_noise.DiagonalNoise and the models' Q built on it: the formula of each model, bit for
bit, for steps that change every call (sensor stamps jitter), and one array rewritten in place."""

from __future__ import annotations

import numpy as np

from ekf_localization.core.process_noise import DiagonalNoise
from ekf_localization.models.differential import DifferentialModel
from ekf_localization.models.mecanum import MecanumModel

STEPS = [0.01, 0.0105, 0.0, 0.0095, 0.01, 2.5]


def test_diagonal_noise_is_its_formula_for_every_step_in_one_array() -> None:
    rate, per_step, accel = np.array([1e-3, 2e-3, 3.0]), np.array([0.0, 0.5, 0.0]), np.array([0.0, 0.0, 4.0])
    noise = DiagonalNoise(rate, per_step, accel)
    first = noise.at(STEPS[0])
    for dt in STEPS:
        Q = noise.at(dt)
        assert Q is first and Q.shape == (1, 3, 3) and Q.flags.c_contiguous
        want = np.diag(rate * dt + per_step + accel * dt * dt)
        assert np.array_equal(Q[0], want), dt


def test_mecanum_noise_is_eq_26_with_and_without_a_command() -> None:
    m = MecanumModel(pose_variance_rate=np.array([1e-3, 2e-3, 3e-3]),
                     velocity_variance_per_step=np.array([0.1, 0.2, 0.3]),
                     velocity_variance_rate=np.array([4.0, 5.0, 6.0]))
    u = np.zeros((1, 3))
    for dt in STEPS:
        for U in (None, u):
            vel = m.velocity_variance_rate * dt + (m.velocity_variance_per_step if U is not None else 0.0)
            want = np.diag(np.concatenate([m.pose_variance_rate * dt, vel]))
            assert np.array_equal(m.noise(np.zeros((1, 6)), U, dt)[0], want), (dt, U is None)


def test_tank_noise_adds_the_acceleration_input_term_only_with_an_input() -> None:
    m = DifferentialModel()
    a = np.zeros((1, 1))
    for dt in STEPS:
        for U in (None, a):
            q_v = m.speed_variance_rate * dt + (m.acceleration_variance * dt * dt if U is not None else 0.0)
            want = np.diag([m.pose_variance_rate[0] * dt, m.pose_variance_rate[1] * dt, q_v,
                            m.heading_variance_rate * dt, m.yaw_rate_variance_rate * dt])
            assert np.array_equal(m.noise(np.zeros((1, 5)), U, dt)[0], want), (dt, U is None)
