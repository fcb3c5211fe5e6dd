"""Bad parameter files and bad bags: one line naming the problem and the expected form, exit 2.

Never a traceback: rcl's own parse errors (raised inside rclpy.init) are found before it,
rates that overflow a timer are refused by the parsers, and bag_replay names a broken bag.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from helpers.ros_helpers import REPO, node_command
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from ekf_localization.core.units import ns_to_sec_nanosec
from ekf_localization.ros.params_file import params_file_problem, ros_args_problem
from ekf_localization.tools.bag_replay import main as bag_replay

F15 = "[false, false, false, false, false, false, true, true, false, false, false, true, false, false, false]"

BAD_FILES = {
    "mixed_list": ("ekf_node:\n  ros__parameters:\n    control_velocity_variance: [1.0, 2, 0.0, 0.0]\n",
                   "parameter 'control_velocity_variance': expected a list whose elements are all of "
                   "one type"),
    "int_in_bool_list": ("ekf_node:\n  ros__parameters:\n    odom0: odometry/dead_wheels\n"
                         f"    odom0_config: {F15.replace('true, true', 'true, 1', 1)}\n",
                         "parameter 'odom0_config': expected a list whose elements are all of one type"),
    "yaml_syntax": ("ekf_node:\n  ros__parameters:\n    frequency: [1.0\n",
                    "expected valid YAML; syntax error at line 4"),
    "not_a_mapping": ("- 1.0\n- 2.0\n", "expected a mapping of node names"),
}


def one_line_exit_2(res: subprocess.CompletedProcess, needle: str) -> None:
    assert res.returncode == 2, res.stdout + res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, res.stderr
    assert "Traceback" not in res.stderr + res.stdout
    assert needle in lines[0], lines[0]


def run(cmd: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=str(REPO))


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_params_file_rcl_cannot_parse_is_named(tmp_path: Path, case: str) -> None:
    text, needle = BAD_FILES[case]
    path = tmp_path / f"{case}.yaml"
    path.write_text(text)
    problem = params_file_problem(path)
    assert problem is not None and needle in problem and str(path) in problem


def test_shipped_parameter_files_pass_the_check() -> None:
    for path in sorted((REPO / "config").glob("*.yaml")):
        if "ros__parameters" in path.read_text():  # pure_pursuit_node declares its own (a [] is fine)
            assert params_file_problem(path, empty_lists=path.stem == "pure_pursuit") is None, path


def test_command_line_values_are_checked_too() -> None:
    assert "element 1 is an integer" in ros_args_problem(["x", "--ros-args", "-p", "v:=[1.0, 2]"])
    assert "non-empty list" in ros_args_problem(["x", "--ros-args", "-p", "v:=[]"])
    assert ros_args_problem(["x", "--ros-args", "-p", "v:=[]"], empty_lists=True) is None
    assert ros_args_problem(["x", "-p", "v:=[1.0, 2]"]) is None  # not a ROS argument
    assert ros_args_problem(["x", "--ros-args", "-p", "name:=text: with colon"]) is None


@pytest.mark.ros
@pytest.mark.parametrize("case", ["mixed_list", "int_in_bool_list", "yaml_syntax", "missing"])
def test_ekf_node_exits_2_with_one_line(ros_domain, tmp_path: Path, case: str) -> None:
    path = tmp_path / f"{case}.yaml"
    if case != "missing":
        path.write_text(BAD_FILES[case][0])
    needle = BAD_FILES[case][1] if case != "missing" else "expected a readable YAML file"
    one_line_exit_2(run([*node_command("ekf_node"), "--ros-args", "--params-file", str(path)]), needle)


@pytest.mark.parametrize("executable", ["sim_node", "pure_pursuit_node"])
@pytest.mark.parametrize("case", ["mixed_list", "missing"])
def test_the_other_nodes_name_a_file_rcl_cannot_read(ros_domain, tmp_path: Path, executable: str,
                                                      case: str) -> None:
    """The same check runs before rclpy.init in every node (node_runner), not only ekf_node."""
    path = tmp_path / f"{case}.yaml"
    if case == "mixed_list":
        path.write_text(f"{executable}:\n  ros__parameters:\n    some_list: [1.0, 2, 0.0]\n")
    needle = ("parameter 'some_list': expected a list whose elements are all of one type"
              if case == "mixed_list" else "expected a readable YAML file")
    one_line_exit_2(run([*node_command(executable), "--ros-args", "--params-file", str(path)]), needle)


@pytest.mark.ros
def test_ekf_node_refuses_a_rate_its_timer_cannot_have(ros_domain) -> None:
    res = run([*node_command("ekf_node"), "--ros-args", "--params-file", str(REPO / "config" / "ekf.yaml"),
               "-p", "frequency:=1.0e-12"])
    one_line_exit_2(res, "parameter 'frequency': expected a rate in Hz from 0.001 to 10000, got 1e-12")


@pytest.mark.ros
def test_sim_node_empty_list_is_named(ros_domain, tmp_path: Path) -> None:
    path = tmp_path / "sim_extra.yaml"
    path.write_text("sim_node:\n  ros__parameters:\n    field.custom_images: []\n")
    res = run([*node_command("sim_node"), "--ros-args", "--params-file", str(REPO / "config" / "sim.yaml"),
               "--params-file", str(path)])
    one_line_exit_2(res, "parameter 'field.custom_images': expected a non-empty list")


# --- bag_replay ---------------------------------------------------------------------------------

def _odometry_bag(path: Path, n: int = 400) -> None:
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message

    ts = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/odometry/dead_wheels", "nav_msgs/msg/Odometry", typestore=ts)
        for k in range(n):
            t = 1_000_000_000 + k * 10_000_000
            msg = Odometry()
            msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(t)
            msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
            w.write(conn, t, serialize_message(msg))


def _chatter_bag(path: Path) -> None:
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        for k in range(5):
            msg = ts.types["std_msgs/msg/String"](data="hi")
            w.write(conn, k, ts.serialize_cdr(msg, "std_msgs/msg/String"))


def _truncated(path: Path) -> None:
    _odometry_bag(path)
    mcap = next(path.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])


def _metadata_only(path: Path) -> None:
    _odometry_bag(path)
    for f in path.glob("*.mcap"):
        f.unlink()


BAD_BAGS = {
    "truncated_mcap": (_truncated, "cannot read bag"),
    "empty_directory": (lambda p: p.mkdir(), "cannot read bag"),
    "metadata_only": (_metadata_only, "cannot read bag"),
    "text_file": (lambda p: p.write_text("not a bag\n"), "cannot read bag"),
    "no_input_topics": (_chatter_bag, "has none of the input topics"),
    "missing": (lambda p: None, "no bag at"),
}


@pytest.mark.parametrize("case", sorted(BAD_BAGS))
def test_bag_replay_names_a_bad_bag(tmp_path: Path, capsys, case: str) -> None:
    make, needle = BAD_BAGS[case]
    bag = tmp_path / case
    make(bag)
    code = bag_replay([str(bag), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0] and "expected" in lines[0], err


def test_unknown_executor_is_refused_in_one_line(tmp_path: Path) -> None:
    """EKF_LOCALIZATION_EXECUTOR other than single/events: exit 2, naming the variable and the choices."""
    import os

    from ekf_localization.ros.node_runner import EXECUTOR_ENV

    env = dict(os.environ, **{EXECUTOR_ENV: "multi"})
    params = str(REPO / "config" / "ekf.yaml")
    res = subprocess.run([*node_command("ekf_node"), "--ros-args", "--params-file", params],
                         capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    one_line_exit_2(res, f"{EXECUTOR_ENV} must be one of single, events, got 'multi'")
