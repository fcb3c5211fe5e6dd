"""Drive kinematics and pose-exponential integration of the simulator (no ROS)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ekf_localization.models.mecanum import MecanumKinematics
from sim_robot.world import pose_exponential as pe
from sim_robot.world.drives import DriveLimits, TankKinematics, scale_to_speed_limit

MEC = MecanumKinematics(0.048, 0.168, 0.18)
TANK = TankKinematics(0.048, 0.2)


def test_mecanum_round_trip_twist_wheels_twist():
    rng = np.random.default_rng(1)
    twists = rng.normal(size=(200, 3))
    np.testing.assert_allclose(MEC.wheels_to_twist(MEC.twist_to_wheels(twists)), twists, atol=1e-12)


def test_mecanum_wheel_signs_follow_eq_24():
    """m1..m4 = rear-left, rear-right, front-left, front-right (docs/simulator.md)."""
    r, k = 0.048, 0.168 + 0.18
    np.testing.assert_allclose(MEC.twist_to_wheels([1.0, 0.0, 0.0]), np.full(4, 1.0 / r))
    np.testing.assert_allclose(MEC.twist_to_wheels([0.0, 1.0, 0.0]), np.array([1, -1, -1, 1]) / r)
    np.testing.assert_allclose(MEC.twist_to_wheels([0.0, 0.0, 1.0]), np.array([-1, 1, -1, 1]) * k / r)


def test_tank_round_trip_and_ignores_vy():
    rng = np.random.default_rng(2)
    twists = rng.normal(size=(200, 3))
    planar = twists.copy()
    planar[:, 1] = 0.0
    np.testing.assert_allclose(TANK.wheels_to_twist(TANK.twist_to_wheels(twists)), planar, atol=1e-12)
    wheels = rng.normal(size=(50, 2))
    np.testing.assert_allclose(TANK.twist_to_wheels(TANK.wheels_to_twist(wheels)), wheels, atol=1e-12)
    # turning in place CCW: left wheel backwards, right forwards, at b·wz/r
    np.testing.assert_allclose(TANK.twist_to_wheels([0.0, 0.0, 1.0]), [-0.2 / 0.048, 0.2 / 0.048])


def test_speed_limit_scales_all_wheels_together():
    w = np.array([[10.0, -40.0, 20.0, 5.0], [1.0, 2.0, 3.0, 4.0]])
    out = scale_to_speed_limit(w, 20.0)
    np.testing.assert_allclose(out[0], w[0] / 2.0)
    np.testing.assert_array_equal(out[1], w[1])
    np.testing.assert_array_equal(scale_to_speed_limit(w, math.inf), w)
    with pytest.raises(ValueError, match="wheel_speed_limit"):
        DriveLimits(wheel_speed_limit=0.0)


def _fd_jacobian(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = h
        cols.append((f(x + e) - f(x - e)) / (2 * h))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("xi", [[0.3, -0.2, 0.7], [0.3, 0.1, 2e-3], [0.05, 0.2, 0.0], [-1.0, 0.4, -3.0]])
def test_body_increment_jacobian_matches_central_differences(xi):
    xi = np.array(xi)
    J = pe.body_increment_jacobian(xi[None])[0]
    J_fd = _fd_jacobian(lambda v: pe.body_increment(v[None])[0], xi)
    np.testing.assert_allclose(J, J_fd, atol=1e-8)


def test_small_angle_series_matches_closed_form():
    """Below |φ| = 1e-2 the series is used; the closed form is still accurate there."""
    phi = np.array([-9.9e-3, -2e-3, 1e-3, 5e-3, 9.9e-3])
    a, b = 0.7, -0.3
    xi = np.column_stack([np.full(phi.size, a), np.full(phi.size, b), phi])
    A, B = np.sin(phi) / phi, (1 - np.cos(phi)) / phi
    dA = (phi * np.cos(phi) - np.sin(phi)) / phi**2
    dB = (phi * np.sin(phi) - (1 - np.cos(phi))) / phi**2
    np.testing.assert_allclose(pe.body_increment(xi)[:, :2],
                               np.column_stack([A * a - B * b, B * a + A * b]), rtol=1e-13, atol=1e-15)
    J = pe.body_increment_jacobian(xi)
    np.testing.assert_allclose(J[:, 0, 2], dA * a - dB * b, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(J[:, 1, 2], dB * a + dA * b, rtol=1e-9, atol=1e-12)


def test_integrate_constant_twist_follows_the_exact_arc():
    v, w, T = 0.8, 0.9, 0.01
    pose = np.array([[0.1, -0.2, 0.3]])
    for _ in range(100):
        pose = pe.integrate(pose, np.array([[v, 0.0, w]]), T)
    R, th0 = v / w, 0.3
    th = th0 + w * 1.0
    expected = [0.1 + R * (math.sin(th) - math.sin(th0)), -0.2 - R * (math.cos(th) - math.cos(th0)), th]
    np.testing.assert_allclose(pose[0], expected, atol=1e-12)


def test_pose_covariance_uses_exact_jacobians():
    pose = np.array([0.4, -1.0, 2.5])
    twist = np.array([0.6, -0.3, 1.7])
    dt = 0.05
    P0 = np.diag([1e-3, 2e-3, 3e-4])
    S = np.array([[2e-3, 1e-4, 0.0], [1e-4, 1e-3, 2e-4], [0.0, 2e-4, 5e-3]])
    _, P = pe.integrate_with_covariance(pose[None], P0[None], twist[None], S[None], dt)
    Jp = _fd_jacobian(lambda p: pe.integrate(p[None], twist[None], dt)[0], pose)
    Jt = _fd_jacobian(lambda t: pe.integrate(pose[None], t[None], dt)[0], twist)
    np.testing.assert_allclose(P[0], Jp @ P0 @ Jp.T + Jt @ S @ Jt.T, rtol=1e-6, atol=1e-12)
    np.testing.assert_array_equal(P[0], P[0].T)
    assert np.all(np.linalg.eigvalsh(P[0]) > 0.0)
