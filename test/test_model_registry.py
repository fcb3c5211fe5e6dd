"""The model registry: the shipped models' specs, and a new model added as docs/models.md says."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest

from ekf_localization.core.localizer import Localizer
from ekf_localization.core.measurements import FIELD_NAMES, ControlCommand, PoseMeasurement
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.models import registry
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError

REPO = Path(__file__).resolve().parents[1]


def _doc_model(tmp_path: Path):
    """The example module of docs/models.md "Writing a model", imported from a file."""
    text = (REPO / "docs" / "models.md").read_text()
    section = text[text.index("## Writing a model"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    path = tmp_path / "constant_position.py"
    path.write_text(code)
    spec = importlib.util.spec_from_file_location("constant_position_doc_example", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def constant_position(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> MotionModelSpec:
    """The doc's toy model, registered for this test only (the one registry line)."""
    spec = _doc_model(tmp_path).SPEC
    monkeypatch.setitem(MODELS, spec.name, spec)
    return spec


def _pose(t_ns: int, xyyaw, variance: float) -> PoseMeasurement:
    pose = np.zeros(6)
    pose[[0, 1, 5]] = xyyaw
    return PoseMeasurement(t_ns, "map", pose, np.eye(6) * variance)


def test_shipped_models_are_registered_by_name() -> None:
    assert set(MODELS) == {"mecanum", "differential", "tank"}
    assert all(name == spec.name for name, spec in MODELS.items())
    assert registry.get("mecanum").state_fields == (0, 1, 5, 6, 7, 11)
    assert registry.get("differential").input_fields == (12,)
    with pytest.raises(ValueError, match="'mecanum', 'differential'"):
        registry.get("swerve")


@pytest.mark.parametrize("name", ["mecanum", "differential", "tank"])
def test_each_spec_builds_a_model_of_its_state_size(name: str) -> None:
    spec = MODELS[name]
    config = parse_ekf_config({"model": name}, MODELS)
    model = spec.build(config)
    assert model.n == len(spec.state_fields)
    # the angle components are the yaw field(s)
    assert [FIELD_NAMES[f] for f, a in zip(spec.state_fields, model.x_is_angle, strict=True) if a] == ["yaw"]
    loc = make_localizer(config)
    assert loc.spec is spec and loc.state_fields == spec.state_fields


def test_mecanum_takes_the_planar_twist_of_cmd_vel() -> None:
    u = MODELS["mecanum"].control_from_twist(np.array([0.5, -0.2, 9.0, 9.0, 9.0, 0.7]))
    np.testing.assert_array_equal(u, [0.5, -0.2, 0.7])
    assert MODELS["differential"].control_from_twist is None


def test_a_spec_is_checked_when_declared() -> None:
    build = MODELS["mecanum"].build
    with pytest.raises(ValueError, match="distinct fields"):
        MotionModelSpec("bad", (0, 0, 5), build, "none")
    with pytest.raises(ValueError, match="distinct fields"):
        MotionModelSpec("bad", (0, 1, 15), build, "none")
    with pytest.raises(ValueError, match="not both"):
        MotionModelSpec("bad", (0, 1, 5), build, "none", control_from_twist=lambda t: t, input_fields=(12,))
    with pytest.raises(ValueError, match="one state name"):
        MotionModelSpec("bad", (0, 1, 5), build, "none", state_names=("x",))


def test_localizer_refuses_a_spec_the_config_does_not_name() -> None:
    with pytest.raises(ValueError, match="'differential'"):
        Localizer(parse_ekf_config({}, MODELS), MODELS["differential"])


def test_the_documented_toy_model_runs_through_the_localizer(constant_position: MotionModelSpec) -> None:
    p0, r, n = 0.5, 0.04, 20
    q = np.zeros((15, 15))  # no process noise: the filter is the textbook mean of the poses
    cfg = parse_ekf_config({"model": "constant_position", "world_frame": "map",
                            "process_noise_covariance": q.ravel().tolist(),
                            "initial_estimate_covariance": (np.eye(15) * p0).ravel().tolist(),
                            "pose0": "camera/pose",
                            "pose0_config": [True, True, False, False, False, True] + [False] * 9}, MODELS)
    loc = make_localizer(cfg)
    assert loc.spec is constant_position and loc.model.n == 3
    z = np.array([1.0, -2.0, 2.0])
    rng = np.random.default_rng(7)
    poses = z + rng.normal(0.0, np.sqrt(r), (n, 3))
    for k, p in enumerate(poses):
        result = loc.add_measurement("pose0", _pose(SEC + k * SEC // 10, p, r), SEC + k * SEC // 10)
        assert result.applied == ("pose",), result
    est = loc.advance_to(3 * SEC)
    assert est.state_fields == (0, 1, 5)
    # information form of n fusions of a constant: P = 1/(1/p0 + n/r), x = P·Σz/r (x0 = 0)
    p_n = 1.0 / (1.0 / p0 + n / r)
    np.testing.assert_allclose(np.diag(est.covariance), p_n, rtol=1e-9)
    expected = p_n * poses.sum(axis=0) / r
    np.testing.assert_allclose(est.state, expected, atol=1e-9)
    assert constant_position.state_names == ("x", "y", "yaw")


def test_toy_model_takes_no_command(constant_position: MotionModelSpec) -> None:
    with pytest.raises(ParameterError, match="use_control.*constant_position.*the pose is held"):
        parse_ekf_config({"model": "constant_position", "use_control": True}, MODELS)


def test_a_model_not_registered_is_refused_by_the_parser() -> None:
    with pytest.raises(ParameterError, match="model"):
        parse_ekf_config({"model": "constant_position"}, MODELS)


def test_tank_wheel_commands_and_cmd_vel_drive_the_tank_through_its_drive_response() -> None:
    """model tank: wheel speeds [left right] in wheel_order, or cmd_vel [vx vyaw], are the targets
    its v and ω ramp to at the wheel acceleration limit; a mecanum wheel_order is refused."""
    values = {"model": "tank", "world_frame": "map", "use_control": True, "control_timeout": 5.0,
              "wheel_radius": 0.05, "half_wheelbase": 0.1, "half_track": 0.25,
              "wheel_order": ["right", "left"],
              "wheel_acceleration_limit": 40.0, "wheel_command_topic": "wheel_commands",
              "control_velocity_variance": [1e-6, 0.0, 0.0, 0.0, 0.0, 1e-5],
              "process_noise_covariance": (np.eye(15) * 1e-4).ravel().tolist(),
              "initial_estimate_covariance": (np.eye(15) * 1e-6).ravel().tolist()}
    loc = make_localizer(parse_ekf_config(values, MODELS))
    assert loc.spec is MODELS["tank"] and loc.model.drive is not None
    loc.start(0)
    assert loc.add_wheel_command(0, [12.0, 4.0], 0) is None  # right 12, left 4 rad/s
    est = loc.advance_to(SEC)  # the wheels reach 12 and 4 rad/s after 0.3 s
    v, w = est.state[2], est.state[4]  # [x y v yaw vyaw]
    assert v == pytest.approx(0.05 * (12.0 + 4.0) / 2, abs=1e-9)
    assert w == pytest.approx(0.05 * (12.0 - 4.0) / (2 * 0.25), abs=1e-9)
    assert loc.add_wheel_command(SEC, [1.0, 2.0, 3.0], SEC) == "wrong_wheel_count"
    assert loc.add_control(ControlCommand(SEC, np.array([-0.2, 9.0, 0.0, 0.0, 0.0, 0.0])), SEC) is None
    est = loc.advance_to(2 * SEC)
    assert est.state[2] == pytest.approx(-0.2, abs=1e-9) and est.state[4] == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(ParameterError, match="wheel_order"):
        parse_ekf_config({**values, "wheel_order": ["rear_left", "rear_right", "front_left", "front_right"]},
                         MODELS)
