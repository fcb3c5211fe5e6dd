"""The drive response (first-order lag + acceleration limits): exact steps, derivatives, noise."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ekf_localization.models.drive_response import DriveResponse, axis_noise, axis_response

INF = math.inf


def respond(v0: float, c: float, T: float, tau: float, acc: float = INF, dec: float = INF) -> np.ndarray:
    out = np.empty(4)
    axis_response(v0, c, T, tau, acc, dec, out)
    return out


def stepped(v0: float, c: float, T: float, n: int, **kw) -> tuple[float, float]:
    """n equal steps: (final velocity, summed displacement)."""
    v, D = v0, 0.0
    for _ in range(n):
        r = respond(v, c, T / n, **kw)
        v, D = r[0], D + r[2]
    return v, D


def test_lag_matches_the_closed_form() -> None:
    r = respond(0.2, 1.0, 0.07, 0.05)
    E = math.exp(-0.07 / 0.05)
    assert r[0] == pytest.approx(1.0 + (0.2 - 1.0) * E, abs=1e-15)
    assert r[1] == pytest.approx(E, abs=1e-15)
    assert r[2] == pytest.approx(1.0 * 0.07 + (0.2 - 1.0) * 0.05 * (1 - E), abs=1e-15)


def test_zero_time_constant_is_eq25() -> None:
    r = respond(0.3, -0.4, 0.01, 0.0)
    assert r[0] == -0.4 and r[1] == 0.0


@pytest.mark.parametrize("tau, acc", [(0.0, INF), (0.0, 2.0), (0.05, INF), (0.05, 2.0)])
def test_on_the_command_the_derivative_is_the_decay(tau: float, acc: float) -> None:
    r = respond(0.5, 0.5, 0.01, tau, acc, acc)
    assert r[0] == 0.5 and r[2] == pytest.approx(0.005, abs=1e-15)
    assert r[1] == pytest.approx(math.exp(-0.01 / tau) if tau > 0 else 0.0, abs=1e-15)


@pytest.mark.parametrize("v0, c", [(0.0, 1.0), (0.9, -0.7), (-0.2, 0.0), (1.2, 0.3)])
def test_one_long_step_equals_ten_short_ones_without_limits(v0: float, c: float) -> None:
    one = respond(v0, c, 0.1, 0.04)
    v10, D10 = stepped(v0, c, 0.1, 10, tau=0.04)
    assert v10 == pytest.approx(one[0], abs=1e-12)
    assert pytest.approx(one[2], abs=1e-12) == D10


@pytest.mark.parametrize("v0, c, tau, acc, dec", [
    (0.0, 1.0, 0.03, 2.9, 4.0),     # ramp, then lag
    (0.8, -0.9, 0.03, 2.9, 4.0),    # decelerate through zero, then accelerate
    (0.8, -0.9, 0.0, 2.9, 4.0),     # pure rate limits (the simulator's drive)
    (-1.0, 0.0, 0.05, 2.0, 1.5),    # stop
    (0.2, 0.25, 0.05, 2.0, 1.5),    # small change: lag only
])
def test_piecewise_solution_is_step_independent_and_matches_the_ode(v0, c, tau, acc, dec) -> None:
    T = 0.6
    one = respond(v0, c, T, tau, acc, dec)
    v20, D20 = stepped(v0, c, T, 20, tau=tau, acc=acc, dec=dec)
    assert v20 == pytest.approx(one[0], abs=1e-9)
    assert pytest.approx(one[2], abs=1e-9) == D20

    def rhs(_t, y):
        v = y[0]
        rate = (c - v) / tau if tau > 0 else math.copysign(1e9, c - v)
        limit = dec if (v != 0 and (v > 0) != (rate > 0)) else acc
        return [float(np.clip(rate, -limit, limit)), v]

    # an ODE solution of the same law (τ = 0: a ramp at the limit, compared to the closed form)
    if tau > 0:
        sol = solve_ivp(rhs, (0, T), [v0, 0.0], rtol=1e-10, atol=1e-12, max_step=1e-3)
        assert one[0] == pytest.approx(sol.y[0, -1], abs=1e-6)
        assert one[2] == pytest.approx(sol.y[1, -1], abs=1e-6)
    else:
        t_dec = abs(v0) / dec
        t_acc = abs(c) / acc
        assert one[0] == pytest.approx(c, abs=1e-12) and t_dec + t_acc < T
        D = 0.5 * v0 * t_dec + 0.5 * c * t_acc + c * (T - t_dec - t_acc)
        assert one[2] == pytest.approx(D, abs=1e-12)


@pytest.mark.parametrize("v0, c, T, tau, acc, dec", [
    (0.1, 1.0, 0.01, 0.05, INF, INF),
    (0.1, 1.0, 0.2, 0.05, 2.9, 4.0),
    (0.7, -0.9, 0.3, 0.03, 2.9, 4.0),
    (0.7, -0.9, 0.3, 0.0, 2.9, 4.0),
    (-0.5, 0.0, 0.08, 0.04, 1.0, 3.0),
    (0.3, 0.31, 0.05, 0.1, 2.0, 2.0),
])
def test_derivatives_match_finite_differences(v0, c, T, tau, acc, dec) -> None:
    r = respond(v0, c, T, tau, acc, dec)
    h = 1e-6
    hi = respond(v0 + h, c, T, tau, acc, dec)
    lo = respond(v0 - h, c, T, tau, acc, dec)
    assert r[1] == pytest.approx((hi[0] - lo[0]) / (2 * h), abs=1e-6)
    assert r[3] == pytest.approx((hi[2] - lo[2]) / (2 * h), abs=1e-6)


def test_noise_is_the_exact_ou_integral_and_composes() -> None:
    tau, var = 0.05, 0.01
    out = np.empty(3)
    axis_noise(0.1, tau, var, out)
    # the linear system [∫, v]: d/dt ∫ = v, dv/dt = -v/τ + w, q = 2 var/τ; ten steps of Φ P Φᵀ + Q
    steps = 10
    dt = 0.1 / steps
    E = math.exp(-dt / tau)
    Phi = np.array([[1.0, tau * (1 - E)], [0.0, E]])
    q = np.empty(3)
    axis_noise(dt, tau, var, q)
    Qd = np.array([[q[0], q[1]], [q[1], q[2]]])
    P = np.zeros((2, 2))
    for _ in range(steps):
        P = Phi @ P @ Phi.T + Qd
    np.testing.assert_allclose(P, [[out[0], out[1]], [out[1], out[2]]], rtol=1e-10, atol=1e-15)
    assert out[2] == pytest.approx(var * (1 - math.exp(-2 * 0.1 / tau)))
    # Monte Carlo of the continuous process (Euler at 10 µs) agrees with the variance of ∫
    rng = np.random.default_rng(3)
    h = 1e-5
    v = np.zeros(4000)
    D = np.zeros(4000)
    for _ in range(int(0.1 / h)):
        D += v * h
        v += -v / tau * h + math.sqrt(2 * var / tau * h) * rng.standard_normal(v.size)
    assert np.var(v) == pytest.approx(out[2], rel=0.08)
    assert np.var(D) == pytest.approx(out[0], rel=0.08)


def test_small_step_noise_series_is_continuous() -> None:
    a = np.empty(3)
    b = np.empty(3)
    tau = 0.05
    axis_noise(tau * 0.999e-3, tau, 1.0, a)
    axis_noise(tau * 1.001e-3, tau, 1.0, b)
    assert a[0] > 0 and b[0] == pytest.approx(a[0] * (1.001 / 0.999) ** 3, rel=1e-3)


def test_zero_time_constant_noise_is_the_per_step_variance() -> None:
    out = np.empty(3)
    axis_noise(0.01, 0.0, 0.45, out)
    np.testing.assert_array_equal(out, [0.0, 0.0, 0.45])


def test_parameters_are_checked() -> None:
    d = DriveResponse(time_constant_s=[0.0, 0.0, 0.02], acceleration_limit=[2.9, 2.9, 8.3])
    assert len(d.params) == 15
    assert d.respond([0, 0, 0], [1, 0, 0], 0.01)[0, 0] == pytest.approx(0.029)
    with pytest.raises(ValueError, match="acceleration_limit"):
        DriveResponse(acceleration_limit=[0.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="time_constant_s"):
        DriveResponse(time_constant_s=[-1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="latency_ns"):
        DriveResponse(latency_ns=0.002)


# --- the mecanum model in drive-response mode --------------------------------------------------
def _drive_model(yaw_variance: float = 1e-2):
    from ekf_localization.models.mecanum import MecanumModel

    return MecanumModel(pose_variance_rate=np.zeros(3), drive=DriveResponse(
        time_constant_s=[0.04, 0.06, 0.03], velocity_variance=[1e-3, 2e-3, yaw_variance]))


def _run(ekf, steps: int, T_ns: int, u: np.ndarray) -> None:
    for _ in range(steps):
        assert ekf.predict(T_ns // steps, u)


def test_mecanum_drive_step_is_independent_of_the_prediction_step() -> None:
    from ekf_localization.core.ekf import ExtendedKalmanFilter

    u = np.array([0.8, -0.3, 0.0])
    x0 = np.array([0.1, -0.2, 0.7, 0.2, 0.1, 0.0])
    P0 = np.diag([1e-4, 1e-4, 1e-12, 1e-2, 1e-2, 1e-12])
    # heading known and not turning: the pose is linear in the velocities, everything is exact
    straight = _drive_model(yaw_variance=0.0)
    one = ExtendedKalmanFilter(straight, x0, P0)
    ten = ExtendedKalmanFilter(straight, x0, P0)
    _run(one, 1, 100_000_000, u)
    _run(ten, 10, 100_000_000, u)
    np.testing.assert_allclose(ten.x, one.x, atol=1e-12)
    np.testing.assert_allclose(ten.P, one.P, atol=1e-12)
    # turning, uncertain heading: the velocities and their covariance are still exact
    model = _drive_model()
    one = ExtendedKalmanFilter(model, x0, P0)
    ten = ExtendedKalmanFilter(model, x0, P0)
    x0[5] = 1.5
    P0[5, 5] = 0.05
    one.set_state(x0, P0)
    ten.set_state(x0, P0)
    u[2] = -1.0
    _run(one, 1, 100_000_000, u)
    _run(ten, 10, 100_000_000, u)
    np.testing.assert_allclose(ten.x[3:], one.x[3:], atol=1e-12)
    np.testing.assert_allclose(ten.P[3:, 3:], one.P[3:, 3:], atol=1e-12)


def _assert_fused_predict_equals_python(model, n: int, k: int, seed: int, u_max: float,
                                        states: slice = slice(None)) -> np.ndarray:
    """One 20 ms predict of 5 seeded trials, each in its own filter: the fused kernel's x (the
    ``states`` columns) and P equal f and F P Fᵀ + Q from the model's Python path on the 5 trials
    at once. Returns that Q."""
    from ekf_localization.core.ekf import ExtendedKalmanFilter

    rng = np.random.default_rng(seed)
    X = rng.uniform(-1, 1, (5, n))
    P = np.eye(n) * 0.01
    U = rng.uniform(-u_max, u_max, (5, k))
    filters = [ExtendedKalmanFilter(model, x, P) for x in X]
    for f, u in zip(filters, U, strict=True):
        f.predict(20_000_000, u)
    Xn, F = model.f_and_jacobian(X, U, 0.02)
    Q = model.noise(X, U, 0.02)
    np.testing.assert_allclose(np.stack([f.x for f in filters])[:, states], Xn[:, states], atol=1e-14)
    np.testing.assert_allclose(np.stack([f.P for f in filters]), F @ P @ np.swapaxes(F, 1, 2) + Q, atol=1e-14)
    return Q


def test_fused_kernel_equals_the_python_path() -> None:
    Q = _assert_fused_predict_equals_python(_drive_model(), 6, 3, 7, 1.0, states=slice(3, None))
    assert np.all(np.linalg.eigvalsh(Q) >= -1e-18)


def test_wheel_mode_reproduces_the_simulated_drive() -> None:
    """The simulator's wheels (speed limit, straight-line ramp at the acceleration limit), noise
    off: predicted over 10 ms from the true velocity, the model lands on the true velocity."""
    from ekf_localization.models.mecanum import MecanumModel
    from sim_robot.world.drives import DriveLimits
    from sim_robot.world.world import World, WorldConfig

    cfg = WorldConfig(limits=DriveLimits(32.67, 60.0), pose_variance_rate=(0.0, 0.0, 0.0),
                      velocity_variance_per_step=(0.0, 0.0, 0.0))
    model = MecanumModel(drive=DriveResponse(wheels_from_twist=cfg.mecanum.inverse_matrix,
                                             wheel_acceleration_limit=60.0, wheel_speed_limit=32.67))
    world = World(cfg, 1, 0)
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(40):
        c = rng.uniform([-1.5, -1.5, -4.0], [1.5, 1.5, 4.0])  # often beyond the speed limit
        world.set_command(c)
        for _ in range(rng.integers(1, 30)):
            x0 = world.truth.copy()
            world.advance(10_000_000)
            pred = model.f(x0, c[None], 0.01)
            worst = max(worst, float(np.max(np.abs(pred[0, 3:] - world.truth[0, 3:]))))
    assert worst < 1e-9


# --- the tank (differential) model in drive-response mode ---------------------------------------
def test_pose_exponential_is_exact_for_a_constant_twist() -> None:
    """On the command (no lag): one 0.5 s step while turning equals fifty 10 ms steps, and the
    closed-form arc."""
    from ekf_localization.models.differential import DifferentialModel

    tank = DifferentialModel(drive=DriveResponse())
    x0 = np.array([[0.2, -0.1, 0.4, 0.3, 1.2]])
    u = np.array([[0.4, 1.2]])
    one = tank.f(x0, u, 0.5)
    many = x0
    for _ in range(50):
        many = tank.f(many, u, 0.01)
    np.testing.assert_allclose(many, one, atol=1e-12)
    th1 = 0.3 + 1.2 * 0.5
    rho = 0.4 / 1.2
    arc = [0.2 + rho * (math.sin(th1) - math.sin(0.3)), -0.1 - rho * (math.cos(th1) - math.cos(0.3))]
    np.testing.assert_allclose(one[0, :2], arc, atol=1e-14)


def test_tank_drive_step_is_independent_of_the_prediction_step() -> None:
    from ekf_localization.core.ekf import ExtendedKalmanFilter
    from ekf_localization.models.differential import DifferentialModel

    model = DifferentialModel(pose_variance_rate=np.zeros(2), speed_variance_rate=0.0,
                              heading_variance_rate=0.0, yaw_rate_variance_rate=0.0, drive=DriveResponse(
                                  time_constant_s=[0.04, 0.0, 0.03], velocity_variance=[1e-3, 0.0, 0.0]))
    x0 = np.array([0.1, -0.2, 0.2, 0.7, 0.0])
    P0 = np.diag([1e-4, 1e-4, 1e-2, 1e-12, 1e-12])
    one = ExtendedKalmanFilter(model, x0, P0)
    ten = ExtendedKalmanFilter(model, x0, P0)
    u = np.array([0.8, 0.0])  # straight (heading known, not turning): the pose is linear in v, all exact
    _run(one, 1, 100_000_000, u)
    _run(ten, 10, 100_000_000, u)
    np.testing.assert_allclose(ten.x, one.x, atol=1e-12)
    np.testing.assert_allclose(ten.P, one.P, atol=1e-12)
    x0[4], P0[4, 4] = 1.0, 0.05  # turning, uncertain yaw rate: v, ω and their covariance still exact
    one.set_state(x0, P0)
    ten.set_state(x0, P0)
    u = np.array([0.8, -1.0])
    _run(one, 1, 100_000_000, u)
    _run(ten, 10, 100_000_000, u)
    idx = np.ix_([2, 4], [2, 4])
    np.testing.assert_allclose(ten.x[[2, 4]], one.x[[2, 4]], atol=1e-12)
    np.testing.assert_allclose(ten.P[idx], one.P[idx], atol=1e-12)


def test_tank_fused_kernel_equals_the_python_path() -> None:
    from ekf_localization.models.differential import DifferentialModel, tank_kinematics

    inv, fwd = tank_kinematics(0.048, 0.2)
    lag = DriveResponse(time_constant_s=[0.03, 0.0, 0.02], velocity_variance=[1e-3, 0.0, 1e-2])
    wheels = DriveResponse(wheels_from_twist=inv, wheel_acceleration_limit=60.0)
    for model in (DifferentialModel(drive=lag),
                  DifferentialModel(drive=wheels, control="wheels", wheels_to_twist=fwd)):
        Q = _assert_fused_predict_equals_python(model, 5, 2, 11, 10.0)
        assert np.all(np.linalg.eigvalsh(Q) >= -1e-18)


def test_tank_wheel_mode_reproduces_the_simulated_tank_drive() -> None:
    """The simulator's tank (speed limit, straight-line wheel ramp), noise off: predicted over
    10 ms from the true velocity, the model lands on the true v and ω; wheel commands too."""
    from ekf_localization.models.differential import DifferentialModel, tank_kinematics
    from sim_robot.world.drives import DriveLimits
    from sim_robot.world.world import World, WorldConfig

    cfg = WorldConfig(drive="tank", limits=DriveLimits(32.67, 60.0), pose_variance_rate=(0.0, 0.0, 0.0),
                      velocity_variance_per_step=(0.0, 0.0, 0.0))
    inv, fwd = tank_kinematics(cfg.tank.wheel_radius, cfg.tank.half_track)
    np.testing.assert_allclose(inv, cfg.tank.inverse_matrix, atol=1e-15)
    drive = DriveResponse(wheels_from_twist=inv, wheel_acceleration_limit=60.0, wheel_speed_limit=32.67)
    twist_model = DifferentialModel(drive=drive)
    wheel_model = DifferentialModel(drive=drive, control="wheels", wheels_to_twist=fwd)
    world = World(cfg, 1, 0)
    rng = np.random.default_rng(5)
    worst = 0.0
    for i in range(40):
        c = rng.uniform([-1.5, -4.0], [1.5, 4.0])  # often beyond the speed limit
        if i % 2:
            world.set_command([c[0], 0.0, c[1]])
            model, u = twist_model, c
        else:
            u = inv[:, [0, 2]] @ c
            world.set_wheel_command(u)
            model = wheel_model
        for _ in range(rng.integers(1, 30)):
            t = world.truth[0]
            x0 = np.array([[t[0], t[1], t[3], t[2], t[5]]])
            world.advance(10_000_000)
            pred = model.f(x0, u[None], 0.01)
            t = world.truth[0]
            worst = max(worst, abs(pred[0, 2] - t[3]), abs(pred[0, 4] - t[5]))
    assert worst < 1e-9
