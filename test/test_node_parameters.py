"""The parameter schema bound to the three nodes, as processes over real DDS.

A bad parameter file: exit code 2, every bad parameter named, no traceback. A running node
refuses ``ros2 param set`` with a reason (its parameters are read at start-up) and keeps its
value; ekf_node's deprecated ``stamped_control`` works with one warning.
"""

from __future__ import annotations

import subprocess
import time

import pytest
import yaml
from helpers.ros_helpers import REPO, node_command, running_process, spin_until

from ekf_localization.ros.params_match import section_for

pytestmark = pytest.mark.ros

# node -> (its YAML, two bad parameters, what each message must say)
BAD = {
    "ekf_node": ("ekf.yaml", {"frequency": 0.0, "odom0_queue_size": 0},
                 ["parameter 'frequency': expected a rate in Hz from 0.001 to 10000, got 0.0",
                  "parameter 'odom0_queue_size': expected an integer >= 1 (messages), got 0"]),
    "pure_pursuit_node": ("pure_pursuit.yaml", {"frequency": 50, "lookahed_distance": 0.2},
                          ["parameter 'frequency': expected a float from 0.001 to 10000 (Hz), written with a "
                           "decimal point",
                           "parameter 'lookahed_distance': expected a known pure_pursuit_node parameter"]),
    "sim_node": ("sim.yaml", {"imu.yaw_variance": -1.0, "drive": "hovercraft"},
                 ["parameter 'imu.yaw_variance': expected a float > 0 (rad²), got -1.0",
                  "parameter 'drive': expected one of 'mecanum', 'tank', 'swerve', got 'hovercraft'"]),
}


def _bad_file(tmp_path, node: str) -> str:
    shipped, bad, _ = BAD[node]
    doc = yaml.safe_load((REPO / "config" / shipped).read_text())
    section_for(doc, node).update(bad)
    path = tmp_path / f"bad_{node}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


@pytest.mark.parametrize("node", sorted(BAD))
def test_bad_parameter_file_exits_2_naming_every_bad_parameter(ros_domain, tmp_path, node):
    cmd = [*node_command(node), "--ros-args", "--params-file", _bad_file(tmp_path, node)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=str(REPO))
    out = res.stdout + res.stderr
    assert res.returncode == 2, out
    assert "Traceback" not in out, out
    assert f"{node}: 2 bad parameters" in res.stderr, res.stderr
    for needle in BAD[node][2]:
        assert needle in res.stderr, res.stderr


@pytest.fixture
def client_node(ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    node = Node("parameter_test_client", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    yield node, ex
    ex.shutdown()
    node.destroy_node()


def _call(ex, future, timeout: float = 20.0):
    assert spin_until(ex, future.done, timeout=timeout), "no answer from the node's parameter service"
    return future.result()


def _parameter_client(node, ex, remote: str):
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(node, remote)
    assert spin_until(ex, client.services_are_ready, timeout=60.0), f"{remote}: no parameter services"
    # A request can be answered before the reply's reader is matched (DDS discovery: the reply
    # is lost); ask until one round trip completes, then both directions are matched.
    deadline = time.monotonic() + 60.0
    while not spin_until(ex, client.get_parameters(["use_sim_time"]).done, timeout=3.0):
        assert time.monotonic() < deadline, f"{remote}: its parameter service never answered"
    return client


def _value(ex, client, name: str, timeout: float = 20.0):
    from rclpy.parameter import parameter_value_to_python

    return parameter_value_to_python(_call(ex, client.get_parameters([name]), timeout).values[0])


def test_param_set_is_refused_with_a_reason_and_changes_nothing(client_node, tmp_path):
    from rclpy.parameter import Parameter

    node, ex = client_node
    cmd = [*node_command("pure_pursuit_node"), "--ros-args", "--params-file", "config/pure_pursuit.yaml"]
    with running_process(cmd, tmp_path / "pure_pursuit_node.log") as proc:
        client = _parameter_client(node, ex, "pure_pursuit_node")
        assert _value(ex, client, "frequency") == 50.0
        assert _value(ex, client, "goal_heading_tolerance") == 0.05  # not in the file: declared default
        for p in (Parameter("frequency", value=20.0), Parameter("pid_x.kp", value=1.0)):
            result = _call(ex, client.set_parameters([p])).results[0]
            assert not result.successful
            assert f"pure_pursuit_node reads '{p.name}' only at start-up" in result.reason, result.reason
        assert _value(ex, client, "frequency") == 50.0
        assert _value(ex, client, "pid_x.kp") == 5.0
        # ROS's own parameters stay settable
        sim_time = _call(ex, client.set_parameters([Parameter("use_sim_time", value=False)]))
        assert sim_time.results[0].successful
        assert proc.poll() is None


def test_ekf_node_accepts_the_deprecated_name_with_one_warning(client_node, tmp_path):
    from rclpy.parameter import Parameter

    node, ex = client_node
    log = tmp_path / "ekf_node.log"
    # config/ekf.yaml says stamped_cmd_vel: true; the old name with another value is an error
    conflict = [*node_command("ekf_node"), "--ros-args", "--params-file", "config/ekf.yaml",
                "-p", "stamped_control:=false"]
    bad = subprocess.run(conflict, capture_output=True, text=True, timeout=120, cwd=str(REPO))
    assert bad.returncode == 2, bad.stderr
    assert "parameter 'stamped_control': expected only one of" in bad.stderr, bad.stderr
    cmd = [*node_command("ekf_node"), "--ros-args", "--params-file", str(_without_stamped(tmp_path)),
           "-p", "stamped_control:=true"]
    with running_process(cmd, log) as proc:
        client = _parameter_client(node, ex, "ekf_node")
        # the first answer comes after the kernels' warm-up (a compile when the cache is cold)
        assert _value(ex, client, "stamped_cmd_vel", timeout=240.0) is True
        result = _call(ex, client.set_parameters([Parameter("stamped_cmd_vel", value=False)])).results[0]
        assert not result.successful and "only at start-up" in result.reason
        assert _value(ex, client, "stamped_cmd_vel") is True
        assert proc.poll() is None
    lines = [ln for ln in log.read_text().splitlines() if "deprecated" in ln]
    assert len(lines) == 1 and "'stamped_control' is deprecated: use 'stamped_cmd_vel'" in lines[0], lines


def _without_stamped(tmp_path):
    doc = yaml.safe_load((REPO / "config" / "ekf.yaml").read_text())
    del section_for(doc, "ekf_node")["stamped_cmd_vel"]
    path = tmp_path / "ekf_unstamped.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path
