"""robot_localization configurations: its template loads unchanged; diagonal covariances,
``_differential`` and ``_relative`` inputs (core.pose_modes)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from ekf_localization.core.angles import matrix_to_rpy
from ekf_localization.core.frames import RigidTransform
from ekf_localization.core.measurements import ImuMeasurement, OdometryMeasurement, PoseMeasurement
from ekf_localization.core.pose_modes import PoseDifferentiator, PoseRelative
from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config, parse_ekf_settings
from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml

# robot_localization's parameter template (ekf.yaml) with its licence, kept in the repository
RL = Path(__file__).parent / "data" / "robot_localization"
F15 = [False] * 15


def fuse(*fields: int) -> list[bool]:
    return [i in fields for i in range(15)]


def _template() -> Path:
    return RL / "ekf.yaml"


def test_rl_template_loads_unchanged() -> None:
    settings = parse_ekf_settings(parameters_from_yaml(_template(), "ekf_filter_node"), MODELS)
    cfg = settings.config
    modes = {i.name: (i.settings.differential, i.settings.relative) for i in cfg.inputs}
    assert modes == {"odom0": (False, False), "odom1": (False, True), "pose0": (True, False),
                     "twist0": (False, False), "imu0": (False, True)}
    assert np.allclose(np.diag(cfg.initial_estimate_covariance), 1e-9)  # its 15-value diagonal form
    warned = " ".join(settings.warnings)
    for name in ("two_d_mode", "debug", "transform_timeout", "control_config"):
        assert f"'{name}'" in warned
    assert make_localizer(cfg).stats.keys() >= {"odom0", "odom1", "pose0", "twist0", "imu0"}


def test_rl_parameters_that_do_not_apply_warn_once_each() -> None:
    values = {"clear_params": True, "filter_type": "ukf", "two_d_mode": True, "tf_prefix": "robot1",
              "base_link_frame_output": "base_link_out", "debug": False,
              "odom0": "odom", "odom0_config": fuse(6, 7, 11)}
    warnings = parse_ekf_settings(values, MODELS).warnings
    for name in ("clear_params", "filter_type", "two_d_mode", "tf_prefix", "base_link_frame_output", "debug"):
        assert sum(f"'{name}'" in w for w in warnings) == 1, name


def test_covariances_in_both_forms() -> None:
    diag = [1e-3 * (k + 1) for k in range(15)]
    a = parse_ekf_config({"process_noise_covariance": diag, "initial_estimate_covariance": diag}, MODELS)
    full = np.diag(diag).ravel().tolist()
    b = parse_ekf_config({"process_noise_covariance": full, "initial_estimate_covariance": full}, MODELS)
    assert np.array_equal(a.process_noise_covariance, b.process_noise_covariance)
    assert np.array_equal(a.initial_estimate_covariance, np.diag(diag))
    with pytest.raises(ParameterError, match="225 numbers .* or 15"):
        parse_ekf_config({"process_noise_covariance": diag[:14]}, MODELS)


def _pose6(T: RigidTransform) -> np.ndarray:
    return np.concatenate([T.translation, matrix_to_rpy(T.rotation)])


def test_differential_poses_give_the_body_velocity_whatever_the_frame_origin() -> None:
    """A circle driven at v = 0.5 m/s, ω = 0.4 rad/s, seen in a frame shifted and turned by 1 rad."""
    offset = RigidTransform.from_xyz_ypr(3.0, -2.0, 0.0, 1.0, 0.0, 0.0)
    diff = PoseDifferentiator()
    v, w, dt = 0.5, 0.4, 0.01
    out = []
    for k in range(5):
        t = k * dt
        pose = RigidTransform.from_xyz_ypr(v / w * math.sin(w * t), v / w * (1 - math.cos(w * t)), 0.0,
                                           w * t, 0.0, 0.0)
        out.append(diff.update(int(t * SEC), _pose6(offset.compose(pose)), np.eye(6) * 1e-6))
    assert out[0] is None
    for rates, cov in out[1:]:
        # the chord of the arc: speed v·sinc(ω·dt/2) along the mean heading; ω exact
        half = w * dt / 2
        assert np.allclose(rates, [v * math.cos(half) * math.sin(half) / half,
                                   v * math.sin(half) ** 2 / half, 0, 0, 0, w], atol=1e-9)
        assert np.allclose(np.diag(cov), 2e-6 / dt**2)
    assert diff.update(int(2 * dt * SEC), np.zeros(6), np.eye(6)) == "not_increasing"


def test_relative_poses_start_at_the_origin() -> None:
    rel = PoseRelative()
    first = _pose6(RigidTransform.from_xyz_ypr(1.0, 2.0, 0.0, 0.5, 0.0, 0.0))
    out, _ = rel.update(first, np.eye(6))
    assert np.allclose(out, 0.0)
    moved = RigidTransform.from_xyz_ypr(1.0, 2.0, 0.0, 0.5, 0.0, 0.0).compose(
        RigidTransform.from_xyz_ypr(0.3, 0.0, 0.0, 0.2, 0.0, 0.0))
    out, _ = rel.update(_pose6(moved), np.eye(6))
    assert np.allclose(out, [0.3, 0, 0, 0, 0, 0.2])


def _imu(stamp: int, yaw: float) -> ImuMeasurement:
    return ImuMeasurement(stamp, "base_link", np.array([0.0, 0.0, yaw]), np.eye(3) * 1e-4, np.zeros(3),
                          np.full((3, 3), -1.0), np.zeros(3), np.full((3, 3), -1.0))


def test_imu_yaw_zeroed_at_power_on_as_relative_and_as_differential() -> None:
    """An IMU whose heading reads 2.0 rad at power-on while the robot heads 0.0."""
    for mode, fields in (("relative", fuse(5)), ("differential", fuse(5))):
        q = (np.eye(15) * 1e-3).ravel().tolist()
        loc = make_localizer(parse_ekf_config({"imu0": "imu", "imu0_config": fields, f"imu0_{mode}": True,
                                               "process_noise_covariance": q}, MODELS))
        for k in range(50):
            t = SEC + k * 20_000_000
            loc.add_measurement("imu0", _imu(t, 2.0 + 0.3 * k * 0.02), t)
        x = loc.committed().state  # mecanum [x y yaw vx vy vyaw]
        if mode == "relative":
            assert x[2] == pytest.approx(0.3 * 49 * 0.02, abs=0.01)
        else:
            assert x[5] == pytest.approx(0.3, abs=0.02)  # yaw -> yaw rate


def test_pinpoint_style_pose_source_differential_needs_no_world_transform() -> None:
    """A pose sensor (Pinpoint/OTOS) in its own frame, unknown to TF: differential mode fuses its velocity."""
    loc = make_localizer(parse_ekf_config({"pose0": "otos", "pose0_config": fuse(0, 1, 5),
                                           "pose0_differential": True, "world_frame": "map"}, MODELS))
    for k in range(30):
        t = SEC + k * 10_000_000
        pose = np.array([0.4 * k * 0.01, 0.0, 0.0, 0.0, 0.0, 0.0])
        res = loc.add_measurement("pose0", PoseMeasurement(t, "otos_origin", pose, np.eye(6) * 1e-8), t)
        assert not res.rejected, res
    x = loc.committed().state
    assert x[3] == pytest.approx(0.4, abs=0.01) and abs(x[4]) < 0.01


def test_odometry_pose_in_odom_differential_with_the_world_in_map() -> None:
    loc = make_localizer(parse_ekf_config({"odom0": "odom", "odom0_config": fuse(0, 1, 5),
                                           "odom0_differential": True, "world_frame": "map"}, MODELS))
    for k in range(30):
        t = SEC + k * 10_000_000
        m = OdometryMeasurement(t, "odom", "base_link", np.array([5.0, 0.2 * k * 0.01, 0, 0, 0, math.pi / 2]),
                                np.eye(6) * 1e-8, np.zeros(6), np.eye(6))
        assert not loc.add_measurement("odom0", m, t).rejected
    x = loc.committed().state
    assert x[3] == pytest.approx(0.2, abs=0.01)  # heading +y in odom: forward in the body frame


def test_rl_template_runs_in_ekf_node_yaml_form(tmp_path) -> None:
    """The same file, renamed for ekf_node, reads the same (the node name is the only difference)."""
    doc = yaml.safe_load(_template().read_text())
    (tmp_path / "rl.yaml").write_text(yaml.safe_dump({"ekf_node": doc["ekf_filter_node"]}))
    a = parse_ekf_config(parameters_from_yaml(tmp_path / "rl.yaml"), MODELS)
    b = parse_ekf_config(parameters_from_yaml(_template(), "ekf_filter_node"), MODELS)
    assert [i.name for i in a.inputs] == [i.name for i in b.inputs]
