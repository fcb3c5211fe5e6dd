"""ekf_node parameters: every bad value names the parameter; the shipped YAMLs load."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from helpers.fusion_scenario import F15, fuse
from helpers.ros_helpers import REPO

from ekf_localization.models.registry import MODELS
from ekf_localization.ros.ekf_parameters import (
    EKF_PARAMETERS,
    effective_values,
    load_ekf_config,
    load_ekf_settings,
    parse_ekf_config,
    parse_ekf_settings,
)
from ekf_localization.ros.input_parameters import THRESHOLD_SUFFIXES
from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml


def base(**overrides) -> dict:
    v = {"odom0": "odometry/dead_wheels", "odom0_config": fuse(6, 7, 11),
         "pose0": "camera/pose", "pose0_config": fuse(0, 1, 5), "world_frame": "map"}
    v.update(overrides)
    return v


def test_minimal_config_and_defaults() -> None:
    settings = parse_ekf_settings(base(), MODELS)
    cfg = settings.config
    assert cfg.model == "mecanum" and settings.frequency == 30.0
    assert cfg.sensor_timeout == pytest.approx(1 / 30)
    assert cfg.world_frame == "map" and cfg.base_link_frame == "base_link"
    assert [i.name for i in cfg.inputs] == ["odom0", "pose0"]
    assert cfg.inputs[0].threshold("twist") == math.inf
    assert cfg.history_length_ns == 1_000_000_000
    assert settings.warnings == ()


def test_integers_are_accepted_for_floats_and_thresholds_parsed() -> None:
    settings = parse_ekf_settings(base(frequency=50, history_length=1, pose0_rejection_threshold=3,
                                       odom0_twist_rejection_threshold=float("inf")), MODELS)
    cfg = settings.config
    assert settings.frequency == 50.0 and isinstance(settings.frequency, float)
    assert cfg.inputs[1].threshold("pose") == 3.0
    assert cfg.inputs[0].threshold("twist") == math.inf


BAD = [
    ({"model": "holonomic"}, "model", "'mecanum', 'differential'"),
    ({"frequency": 0.0}, "frequency", "from 0.001 to 10000"),
    ({"frequency": 1.0e-12}, "frequency", "Hz from 0.001"),
    ({"frequency": 1.0e12}, "frequency", "Hz from 0.001"),
    ({"frequency": "fast"}, "frequency", "Hz"),
    ({"frequency": float("nan")}, "frequency", "Hz"),
    ({"sensor_timeout": -1.0}, "sensor_timeout", "> 0"),
    ({"world_frame": "earth"}, "world_frame", "map_frame"),
    ({"odom_frame": "map"}, "odom_frame", "different from map_frame"),
    ({"base_link_frame": "odom"}, "base_link_frame", "different"),
    ({"map_frame": ""}, "map_frame", "non-empty"),
    ({"history_length": 0.0}, "history_length", "> 0 (smooth_lagged_data is true)"),
    ({"history_length": 3.0, "max_measurement_age": 1.0}, "max_measurement_age", ">= history_length"),
    ({"future_stamp_tolerance": -0.1}, "future_stamp_tolerance", ">= 0"),
    ({"max_prediction_step": 0.0}, "max_prediction_step", ">= 1e-6"),
    ({"use_control": "yes"}, "use_control", "true or false"),
    ({"control_timeout": 0.0}, "control_timeout", "> 0"),
    ({"model": "differential", "use_control": True}, "use_control", "IMU's forward acceleration"),
    ({"control_velocity_variance": [0.1, 0.1, 0.1]}, "control_velocity_variance", "6 non-negative"),
    ({"control_velocity_variance": [0.1, -0.1, 0, 0, 0, 0.1]}, "control_velocity_variance", "non-negative"),
    ({"process_noise_covariance": [0.1] * 14}, "process_noise_covariance", "225 numbers"),
    ({"initial_state": [0.0] * 14}, "initial_state", "15 finite numbers"),
    ({"initial_state": [math.nan] * 15}, "initial_state", "15 finite numbers"),
    ({"odom0_config": [True] * 14}, "odom0_config", "15 booleans"),
    ({"odom0_config": [1] * 15}, "odom0_config", "15 booleans"),
    ({"odom0_queue_size": 0}, "odom0_queue_size", "integer >= 1"),
    ({"odom0_queue_size": 2.5}, "odom0_queue_size", "integer >= 1"),
    ({"pose0_rejection_threshold": -2.0}, "pose0_rejection_threshold", "Mahalanobis"),
    ({"pose0_rejection_threshold": "big"}, "pose0_rejection_threshold", "Mahalanobis"),
    ({"pose0_relative": "yes"}, "pose0_relative", "true or false"),
    ({"odom0_differential": 1}, "odom0_differential", "true or false"),
    ({"odom2": "x", "odom2_config": F15}, "odom2", "odom1 is missing"),
    ({"pose0": ""}, "pose0", "topic name"),
    ({"odom0_confg": F15}, "odom0_confg", "known ekf_node parameter"),
    ({"frequncy": 30.0}, "frequncy", "known ekf_node parameter"),
    ({"twist3_config": F15}, "twist3_config", "has no topic"),
    ({"imu0": "imu/data", "imu0_config": fuse(11), "imu0_twist_rejection_threshold": 1.0,
      "imu0_angular_velocity_rejection_threshold": 1.0}, "imu0_", "only one of"),
]


@pytest.mark.parametrize(("overrides", "name", "expected"), BAD, ids=[b[1] for b in BAD])
def test_bad_parameter_names_the_parameter(overrides: dict, name: str, expected: str) -> None:
    with pytest.raises(ParameterError) as info:
        parse_ekf_config(base(**overrides), MODELS)
    assert info.value.name.startswith(name)
    assert f"parameter '{info.value.name}'" in str(info.value)
    assert expected in str(info.value)


def test_missing_config_is_required() -> None:
    v = base()
    del v["pose0_config"]
    with pytest.raises(ParameterError, match=r"parameter 'pose0_config'.*\(required\)"):
        parse_ekf_config(v, MODELS)


def _matrix(diag: list[float], off: tuple[int, int, float] | None = None) -> list[float]:
    M = np.diag(diag)
    if off is not None:
        i, j, v = off
        M[i, j] = M[j, i] = v
    return [float(x) for x in M.ravel()]


def test_matrix_parameters_are_checked_on_the_model_fields() -> None:
    d = [0.01] * 15
    with pytest.raises(ParameterError, match="process_noise_covariance.*not symmetric"):
        parse_ekf_config(base(process_noise_covariance=np.triu(np.ones((15, 15))).ravel().tolist()), MODELS)
    with pytest.raises(ParameterError, match="process_noise_covariance.*off-diagonal.*x, y, yaw, vx, vy"):
        parse_ekf_config(base(process_noise_covariance=_matrix(d, (0, 1, 0.001))), MODELS)
    # an off-diagonal entry among fields the model does not estimate is irrelevant
    parse_ekf_config(base(process_noise_covariance=_matrix(d, (2, 3, 0.001))), MODELS)
    with pytest.raises(ParameterError, match="process_noise_covariance.*non-negative variances"):
        parse_ekf_config(base(process_noise_covariance=_matrix([-0.1] + d[1:])), MODELS)
    bad_p0 = [1.0] * 15
    bad_p0[5] = 0.0
    with pytest.raises(ParameterError, match="initial_estimate_covariance.*positive definite"):
        parse_ekf_config(base(initial_estimate_covariance=_matrix(bad_p0)), MODELS)
    # zero variance on z (not estimated) is fine; a correlated x-y block is fine when PD
    ok = [1.0] * 15
    ok[2] = 0.0
    parse_ekf_config(base(initial_estimate_covariance=_matrix(ok, (0, 1, 0.5))), MODELS)


def test_warnings_for_fields_the_model_or_message_lacks_and_rl_extras() -> None:
    settings = parse_ekf_settings(base(odom0_config=fuse(2, 6, 7, 11, 12), twist0="t",
                                       twist0_config=fuse(0, 6), two_d_mode=True, odom0_nodelay=False,
                                       odom0_relative=False), MODELS)
    text = "\n".join(settings.warnings)
    assert "odom0_config: model 'mecanum' does not estimate z" in text
    assert "odom0_config: a odom message has no az" not in text
    assert "odom0_config: a odom message has no ax" in text
    assert "twist0_config: a twist message has no x" in text
    assert "'two_d_mode' (robot_localization) is not supported" in text
    assert "'odom0_nodelay'" in text


def test_inputs_are_numbered_and_sorted_by_kind() -> None:
    cfg = parse_ekf_config(base(odom1="b", odom1_config=fuse(6), imu0="i", imu0_config=fuse(11),
                                imu0_linear_acceleration_rejection_threshold=2.0), MODELS)
    assert [(i.name, i.kind, i.topic) for i in cfg.inputs] == [
        ("odom0", "odom", "odometry/dead_wheels"), ("odom1", "odom", "b"), ("pose0", "pose", "camera/pose"),
        ("imu0", "imu", "i")]
    assert cfg.inputs[3].threshold("linear_acceleration") == 2.0


def test_ros_builtin_parameters_are_ignored() -> None:
    cfg = parse_ekf_settings(base(use_sim_time=True, start_type_description_service=True,
                                  **{"qos_overrides./parameter_events.publisher.depth": 1000}), MODELS)
    ref = parse_ekf_settings(base(), MODELS)
    assert effective_values(cfg) == effective_values(ref) and cfg.config.inputs == ref.config.inputs
    assert cfg.warnings == ()


@pytest.mark.parametrize("name", ["ekf.yaml", "ekf_differential.yaml", "ekf_mecanum_drive_controller.yaml",
                                  "ekf_diff_drive_controller.yaml"])
def test_shipped_config_files_load_without_warnings(name: str) -> None:
    settings = load_ekf_settings(REPO / "config" / name, MODELS)
    assert settings.warnings == ()
    assert settings.config.inputs


def test_mecanum_config_matches_the_simulator_contract() -> None:
    settings = load_ekf_settings(REPO / "config" / "ekf.yaml", MODELS)
    cfg = settings.config
    assert cfg.model == "mecanum" and cfg.world_frame == "map" and settings.stamped_cmd_vel
    by_topic = {i.topic: i for i in cfg.inputs}
    odom = by_topic["odometry/dead_wheels"]
    assert [f for f, on in enumerate(odom.settings.config) if on] == [6, 7, 11]
    cam = by_topic["camera/pose"]
    assert [f for f, on in enumerate(cam.settings.config) if on] == [0, 1, 5]
    assert math.isfinite(cam.threshold("pose"))
    imu = by_topic["imu/data"]
    assert imu.settings.config[5] and imu.settings.config[11]  # yaw and yaw rate


def test_yaml_sections_wildcard_and_namespaced(tmp_path: Path) -> None:
    p = tmp_path / "p.yaml"
    p.write_text("/**:\n  ros__parameters:\n    frequency: 10.0\n    use_sim_time: true\n"
                 "/robot/ekf_node:\n  ros__parameters:\n    frequency: 20.0\n    odom0: a\n"
                 "    odom0_config: [false, false, false, false, false, false, true, false, false,\n"
                 "                   false, false, false, false, false, false]\n"
                 "other_node:\n  ros__parameters:\n    frequency: 99.0\n")
    values = parameters_from_yaml(p, "ekf_node")
    assert values["frequency"] == 20.0 and values["use_sim_time"] is True
    assert load_ekf_settings(p, MODELS).frequency == 20.0
    assert parameters_from_yaml(p, "other_node")["frequency"] == 99.0
    q = tmp_path / "q.yaml"
    q.write_text("other_node:\n  ros__parameters:\n    frequency: 99.0\n")
    with pytest.raises(ParameterError, match="file .*q.yaml.*a section for node 'ekf_node'"):
        parameters_from_yaml(q, "ekf_node")


def test_unreadable_yaml_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("ekf_node: [unclosed\n")
    with pytest.raises(ParameterError, match="bad.yaml"):
        load_ekf_config(p, MODELS)


def test_docs_list_every_parameter_and_input_setting() -> None:
    text = (REPO / "docs" / "ekf_node.md").read_text()
    documented = set(re.findall(r"`([<>a-zN_]+)`", text))
    for name in EKF_PARAMETERS:
        assert name in documented, name
    suffixes = {s for kind in THRESHOLD_SUFFIXES.values() for s in kind} | {"_config", "_queue_size"}
    for s in suffixes:
        assert any(d.endswith(s) for d in documented), s


def test_all_bad_parameters_are_reported_together() -> None:
    with pytest.raises(ParameterError) as info:
        parse_ekf_config(base(frequency=0.0, odom0_queue_size=0, frequncy=30.0, world_frame="earth"), MODELS)
    assert info.value.names == ("frequency", "world_frame", "odom0_queue_size", "frequncy")
    text = str(info.value)
    assert text.startswith("4 bad parameters (unknown parameter(s) 'frequncy'):")
    for name in info.value.names:
        assert f"parameter '{name}': expected" in text


def test_stamped_control_is_the_deprecated_name_of_stamped_cmd_vel() -> None:
    settings = parse_ekf_settings(base(stamped_control=True), MODELS)
    assert settings.stamped_cmd_vel is True
    assert settings.warnings == ("parameter 'stamped_control' is deprecated: use 'stamped_cmd_vel' (same "
                                 "meaning; see docs/ekf_node.md)",)
    both = parse_ekf_settings(base(stamped_control=True, stamped_cmd_vel=True), MODELS)
    assert both.stamped_cmd_vel is True
    with pytest.raises(ParameterError, match="parameter 'stamped_control': expected only one of"):
        parse_ekf_settings(base(stamped_control=True, stamped_cmd_vel=False), MODELS)
    assert parse_ekf_settings(base(), MODELS).stamped_cmd_vel is False
