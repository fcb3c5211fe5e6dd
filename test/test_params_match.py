"""Params-file sections match nodes as rcl matches them; a node warns about a file with no section
for it; the shipped YAMLs apply in any namespace."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from helpers.ros_helpers import REPO, node_command

from ekf_localization.ros.parameters import read_parameter_yaml
from ekf_localization.ros.params_match import (
    node_fqn,
    params_files,
    section_applies,
    section_for,
    unmatched_params_files,
)

SHIPPED = {"ekf.yaml": "ekf_node", "ekf_differential.yaml": "ekf_node", "ekf_joint_states.yaml": "ekf_node",
           "ekf_mecanum_drive_controller.yaml": "ekf_node", "ekf_diff_drive_controller.yaml": "ekf_node",
           "ekf_driven_wheels.yaml": "ekf_node", "ekf_swerve.yaml": "ekf_node", "ekf_tank.yaml": "ekf_node",
           "pure_pursuit.yaml": "pure_pursuit_node", "sim.yaml": "sim_node", "sim_tank.yaml": "sim_node",
           "sim_swerve.yaml": "sim_node"}


@pytest.mark.parametrize(("key", "fqn", "applies"), [
    # what rclpy 7.1 gave /ekf_node and /r1/ekf_node from one file (params_match's docstring)
    ("ekf_node", "/ekf_node", True), ("ekf_node", "/r1/ekf_node", False),
    ("/**/ekf_node", "/ekf_node", True), ("/**/ekf_node", "/r1/ekf_node", True),
    ("/**/ekf_node", "/r1/sub/ekf_node", True), ("/*/ekf_node", "/ekf_node", False),
    ("/*/ekf_node", "/r1/ekf_node", True), ("/*/ekf_node", "/r1/sub/ekf_node", False),
    ("/**", "/r1/sub/ekf_node", True), ("/r1/ekf_node", "/r1/ekf_node", True),
    ("/r1/ekf_node", "/r2/ekf_node", False), ("/**/ekf_node", "/r1/ekf_node_2", False),
    ("/**/sim_node", "/r1/ekf_node", False),
])
def test_section_keys_match_like_rcl(key: str, fqn: str, applies: bool) -> None:
    assert section_applies(key, fqn) is applies


def test_node_fqn_follows_the_remaps() -> None:
    assert node_fqn("ekf_node", ["ekf_node"]) == "/ekf_node"
    assert node_fqn("ekf_node", ["x", "--ros-args", "-r", "__ns:=/r1"]) == "/r1/ekf_node"
    assert node_fqn("ekf_node", ["x", "--ros-args", "-r", "__ns:=r1/a", "-r", "__node:=ekf"]) == "/r1/a/ekf"
    assert node_fqn("ekf_node", ["x", "--ros-args", "-r", "other:__ns:=/r1", "-r", "a:=b"]) == "/ekf_node"
    assert node_fqn("ekf_node", ["x", "--ros-args", "--remap", "ekf_node:__ns:=/r2"]) == "/r2/ekf_node"
    assert node_fqn("ekf_node", ["x", "-r", "__ns:=/r1"]) == "/ekf_node"  # not a ROS argument


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_yamls_apply_in_any_namespace(name: str) -> None:
    path = REPO / "config" / name
    node = SHIPPED[name]
    doc = read_parameter_yaml(path)
    assert list(doc) == [f"/**/{node}"]
    for ns in ("", "/r1", "/team/r2"):
        args = ["x", "--ros-args", "-r", f"__ns:={ns or '/'}", "--params-file", str(path)]
        assert unmatched_params_files(node_fqn(node, args), args) == []
        assert section_for(doc, f"{ns}/{node}")


def test_a_file_for_another_node_or_namespace_is_named(tmp_path: Path) -> None:
    plain = tmp_path / "plain.yaml"
    plain.write_text("ekf_node:\n  ros__parameters:\n    frequency: 20.0\n")
    args = ["x", "--ros-args", "--params-file", str(plain), "-r", "__ns:=/r1",
            "--params-file", str(REPO / "config" / "ekf.yaml")]
    assert params_files(args) == [str(plain), str(REPO / "config" / "ekf.yaml")]
    (msg,) = unmatched_params_files("/r1/ekf_node", args)
    assert str(plain) in msg and "/r1/ekf_node" in msg and "'ekf_node'" in msg and "'/**/ekf_node:'" in msg
    assert unmatched_params_files("/ekf_node", args) == []
    with pytest.raises(KeyError, match="/r1/ekf_node"):
        section_for(read_parameter_yaml(plain), "/r1/ekf_node")


@pytest.mark.ros
def test_a_node_says_at_start_that_a_file_has_nothing_for_it(ros_domain, tmp_path: Path) -> None:
    """sim_node given a file keyed 'sim_node:' under /r1 warns, names the file, and runs on."""
    plain = tmp_path / "sim_plain.yaml"
    plain.write_text("sim_node:\n  ros__parameters:\n    seed: 3\n")
    cmd = [*node_command("sim_node"), "--ros-args", "-r", "__ns:=/r1", "--params-file", str(plain),
           "-p", "real_time_factor:=-1.0"]  # a bad value stops it right after start-up
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=str(REPO))
    out = res.stdout + res.stderr
    warn = [ln for ln in out.splitlines() if "has no section for this node" in ln]
    assert len(warn) == 1 and "WARN" in warn[0] and "[r1.sim_node]" in warn[0] and str(plain) in warn[0], out


def test_a_launch_files_list_parameters_read_as_lists(tmp_path: Path) -> None:
    """launch_ros dumps a launch file's dict parameters with PyYAML, lists as !!python/tuple
    (its evaluated parameters are tuples): read as rcl reads them, arrays."""
    import yaml

    path = tmp_path / "launch_params_x"
    path.write_text(yaml.dump({"/**": {"ros__parameters": {"mount": (0.1, 0.0, 0.15), "name": "a"}}},
                              default_flow_style=False))
    assert "!!python/tuple" in path.read_text()  # what launch_ros writes
    assert read_parameter_yaml(path) == {"/**": {"ros__parameters": {"mount": [0.1, 0.0, 0.15], "name": "a"}}}
