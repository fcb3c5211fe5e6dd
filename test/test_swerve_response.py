"""The swerve drive response (models/swerve_response.py): its Jacobian against finite differences,
the reversed module, standing modules, and the parameters that select it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ekf_localization.core.config import EkfConfig
from ekf_localization.models.drive_response import DriveResponse, planar_f_and_jacobian
from ekf_localization.models.mecanum import from_config
from ekf_localization.models.swerve_response import swerve_modules

SQUARE = np.array([[0.26, 0.26], [0.26, -0.26], [-0.26, 0.26], [-0.26, -0.26]])


def _drive(rate: float = 12.0, acc: float = 5.08, tau: float = 0.0) -> DriveResponse:
    return DriveResponse(time_constant_s=np.full(3, tau), acceleration_limit=np.array([acc, acc, 13.8]),
                         deceleration_limit=np.array([acc, acc, 13.8]), velocity_variance=np.full(3, 1e-4),
                         steer_rate_limit=rate, module_positions=SQUARE)


def _respond(drive: DriveResponse, v, c, T: float) -> np.ndarray:
    r = [[0.0] * 8 for _ in range(3)]
    swerve_modules(list(v), list(c), T, drive.params, r)
    return np.array(r)


@pytest.mark.parametrize("tau", [0.0, 0.05])
@pytest.mark.parametrize("T", [0.01, 0.1])
def test_jacobian_matches_finite_differences(tau, T):
    rng = np.random.default_rng(3)
    drive = _drive(tau=tau)
    checked = 0
    for _ in range(200):
        X = np.concatenate([rng.normal(0.0, 1.0, 3), rng.normal(0.0, 1.5, 2), rng.normal(0.0, 3.0, 1)])
        V = np.concatenate([rng.normal(0.0, 1.5, 2), rng.normal(0.0, 3.0, 1)])
        f, F = planar_f_and_jacobian(X[None], V[None], T, drive.params)
        num = np.zeros((6, 6))
        h = 1e-7
        for j in range(6):
            d = np.zeros(6)
            d[j] = h
            num[:, j] = (planar_f_and_jacobian((X + d)[None], V[None], T, drive.params)[0][0]
                         - planar_f_and_jacobian((X - d)[None], V[None], T, drive.params)[0][0]) / (2 * h)
        err = np.abs(num - F[0])
        if np.max(err) > 1e-4:  # a kink (a clip or a limit switching) within h: rare, never most
            continue
        assert np.all(np.isfinite(f))
        checked += 1
    assert checked >= 190


def test_command_reached_holds_it():
    c = [1.0, -0.5, 2.0]
    r = _respond(_drive(), c, c, 0.01)
    assert np.allclose(r[:, 0], c)
    assert np.allclose(r[:, 1], 0.01 * np.array(c))


def test_module_steers_at_the_rate_limit():
    # forward at 1 m/s, commanded sideways: every module must turn 90°; at 12 rad/s over 10 ms
    # they turn 0.12 rad and push only with the command's component along the wheel
    r = _respond(_drive(acc=math.inf), [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], 0.01)
    e = 0.5 * math.pi - 0.12
    s = math.cos(e)  # the speed command s* cos(rest), reached at once without a limit
    assert r[0, 0] == pytest.approx(s * math.cos(0.12), abs=1e-12)
    assert r[1, 0] == pytest.approx(s * math.sin(0.12), abs=1e-12)
    assert r[2, 0] == pytest.approx(0.0, abs=1e-12)


def test_reversed_module_turns_the_short_way():
    # forward at 1 m/s, commanded backward: the modules run reversed without turning
    r = _respond(_drive(acc=100.0), [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], 0.01)
    assert r[0, 0] == pytest.approx(0.0, abs=1e-12)  # ramped down from 1 at 100 m/s² for 10 ms
    assert r[1, 0] == pytest.approx(0.0, abs=1e-12)
    r = _respond(_drive(acc=100.0), [1.0, 0.0, 0.0], [-1.0, 0.01, 0.0], 0.01)
    assert abs(r[1, 0]) < 1e-3  # a 0.6° turn, not 179.4°


def test_standing_modules_point_at_the_target():
    r = _respond(_drive(acc=5.0), [0.0, 0.0, 0.0], [0.0, 2.0, 0.0], 0.01)
    assert r[1, 0] == pytest.approx(0.05)
    assert r[0, 0] == pytest.approx(0.0, abs=1e-12)
    r = _respond(_drive(acc=5.0), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], 0.01)
    assert np.allclose(r[:, :2], 0.0)


def test_without_a_rate_limit_modules_do_not_lag():
    r = _respond(_drive(rate=math.inf, acc=math.inf), [1.0, 0.0, 0.0], [0.3, 0.8, -1.0], 0.01)
    assert np.allclose(r[:, 0], [0.3, 0.8, -1.0])


def test_parameters_select_the_swerve_response():
    base = dict(use_control=True, acceleration_limits=(5.08, 5.08, 0.0, 0.0, 0.0, 13.8),
                deceleration_limits=(5.08, 5.08, 0.0, 0.0, 0.0, 13.8))
    model = from_config(EkfConfig(control_steer_rate_limit=12.0,
                                  control_module_positions=tuple(SQUARE.ravel()), **base))
    assert model.drive.module_positions is not None
    assert len(model.drive.params) > 15
    assert from_config(EkfConfig(**base)).drive.module_positions is None
    with pytest.raises(ValueError, match="at least two modules"):
        from_config(EkfConfig(control_steer_rate_limit=12.0, control_module_positions=(0.1, 0.1), **base))


def _track(drive: DriveResponse, start, command, steps: int) -> np.ndarray:
    """The model's body twist at 10 ms steps from ``start`` toward ``command``."""
    X = np.array([[0.0, 0.0, 0.0, *start]])
    out = []
    for _ in range(steps):
        X = planar_f_and_jacobian(X, np.array([command]), 0.01, drive.params)[0]
        out.append(X[0, 3:].copy())
    return np.array(out)


@pytest.mark.parametrize("command", [[0.0, 1.0, 0.0], [-0.5, 0.8, 0.0], [1.0, 0.0, 2.0]])
def test_the_swerve_response_follows_the_simulated_modules_closer_than_per_axis(command):
    from sim_robot.world.swerve_drive import SwerveDrive, SwerveDriveConfig

    sim = SwerveDrive(SwerveDriveConfig(traction_limit=math.inf), 1)
    start = np.array([1.0, 0.0, 0.0])  # driving forward, modules along x
    for _ in range(300):
        sim.step(start[None], 0.001)
    truth = []
    for k in range(300):
        sim.step(np.array([command], dtype=float), 0.001)
        if k % 10 == 9:
            truth.append(sim.twist[0].copy())
    truth = np.array(truth)
    swerve = _track(_drive(), start, command, 30)
    axes = DriveResponse(acceleration_limit=np.array([5.08, 5.08, 13.8]),
                         deceleration_limit=np.array([5.08, 5.08, 13.8]))
    per_axis = _track(axes, start, command, 30)
    err_swerve = np.sqrt(np.mean((swerve - truth) ** 2))
    err_axes = np.sqrt(np.mean((per_axis - truth) ** 2))
    assert err_swerve < 0.5 * err_axes, (err_swerve, err_axes)


@pytest.mark.parametrize(("overrides", "name", "expected"), [
    ({"control_steer_rate_limit": 12.0}, "control_module_positions", "at least two modules"),
    ({"control_steer_rate_limit": 12.0, "control_module_positions": [0.1, 0.1, 0.1, 0.1]},
     "control_module_positions", "two or more distinct points"),
    ({"control_steer_rate_limit": 12.0, "control_module_positions": [0.1, 0.1, -0.1]},
     "control_module_positions", "[x, y] pairs"),
    ({"control_steer_rate_limit": -1.0}, "control_steer_rate_limit", ">= 0"),
])
def test_ekf_node_refuses_a_swerve_response_without_a_layout(overrides, name, expected):
    from ekf_localization.models.registry import MODELS
    from ekf_localization.ros.ekf_parameters import parse_ekf_config
    from ekf_localization.ros.parameters import ParameterError

    values = {"pose0": "camera/pose", "pose0_config": [True, True] + [False] * 13, "world_frame": "map",
              "use_control": True, **overrides}
    with pytest.raises(ParameterError) as info:
        parse_ekf_config(values, MODELS)
    assert info.value.name == name
    assert expected in str(info.value)


def test_ekf_node_builds_the_swerve_response_from_its_parameters():
    from ekf_localization.models.registry import MODELS
    from ekf_localization.ros.ekf_parameters import parse_ekf_config

    values = {"pose0": "camera/pose", "pose0_config": [True, True] + [False] * 13, "world_frame": "map",
              "use_control": True, "control_steer_rate_limit": 12.0,
              "control_module_positions": SQUARE.ravel().tolist()}
    drive = from_config(parse_ekf_config(values, MODELS)).drive
    assert drive.steer_rate_limit == 12.0
    assert np.array_equal(drive.module_positions, SQUARE)


def test_extreme_states_commands_and_steps_stay_finite():
    rng = np.random.default_rng(0)
    for drive in (_drive(), _drive(tau=0.1), _drive(rate=math.inf, acc=math.inf)):
        for _ in range(500):
            scale = 10.0 ** rng.uniform(-9.0, 6.0)
            X = rng.normal(0.0, 1.0, 6) * np.r_[1.0, 1.0, 1.0, scale, scale, scale]
            V = rng.normal(0.0, 1.0, 3) * 10.0 ** rng.uniform(-9.0, 6.0)
            f, F = planar_f_and_jacobian(X[None], V[None], 10.0 ** rng.uniform(-6.0, 1.0), drive.params)
            assert np.all(np.isfinite(f)) and np.all(np.isfinite(F))
