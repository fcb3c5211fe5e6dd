"""The launch files, run for real (Jazzy's ``launch``/``launch_ros``, as ``ros2 launch`` runs them):
which processes start, which topic names appear over DDS, and a clean stop. The node specs they
start (ekf_localization.ros.launch_description) are checked without ROS first."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml
from helpers.launch_runner import alive, launch_problem, launched, layout_prefix, started, started_all
from helpers.ros_helpers import REPO, spin_until

from ekf_localization.ros.launch_description import (
    EKF_ARGUMENTS,
    INPUT_REMAPS,
    SIM_ARGUMENTS,
    ekf_nodes,
    legacy_forward,
    sim_nodes,
)

PATH_FILE = str(REPO / "config" / "paths" / "seed000_test_path.yaml")
# ekf_node's topics with the shipped config/ekf.yaml (inputs, output, set_pose), relative names
EKF_TOPICS = {"odometry/filtered", "odometry/dead_wheels", "camera/pose", "imu/data", "set_pose"}
GLOBAL_TOPICS = {"/tf", "/diagnostics"}


def _by_name(specs):
    return {s.name: s for s in specs}


def test_ekf_launch_starts_ekf_node_alone_unless_a_path_is_given() -> None:
    specs = _by_name(ekf_nodes(str(REPO)))
    assert set(specs) == {"ekf_node"}
    ekf = specs["ekf_node"]
    assert ekf.namespace == "" and ekf.remaps == () and ekf.overrides == {"use_sim_time": False}
    assert ekf.param_files == (str(REPO / "config" / "ekf.yaml"),)
    follow = _by_name(ekf_nodes(str(REPO), path_file=PATH_FILE, cmd_vel_topic="base/cmd_vel"))
    assert set(follow) == {"ekf_node", "pure_pursuit_node"}
    assert follow["pure_pursuit_node"].overrides == {"use_sim_time": False, "path_file": PATH_FILE}
    assert follow["pure_pursuit_node"].remaps == (("cmd_vel", "base/cmd_vel"),)  # follower and filter agree
    for spec in [*specs.values(), *follow.values()]:
        assert all(Path(p).is_file() for p in spec.param_files)
    with pytest.raises(ValueError, match="use_sim_time"):
        ekf_nodes(str(REPO), use_sim_time="maybe")
    with pytest.raises(ValueError, match="unknown launch arguments"):
        ekf_nodes(str(REPO), use_sim="true")


def test_a_params_file_names_the_command_topic_for_the_follower_too() -> None:
    """A config that reads a controller's command topic (cmd_vel_topic) gets the follower's
    cmd_vel remapped to it; the cmd_vel_topic launch argument overrides both."""
    params = str(REPO / "config" / "ekf_diff_drive_controller.yaml")
    specs = _by_name(ekf_nodes(str(REPO), params_file=params, path_file=PATH_FILE))
    assert specs["ekf_node"].remaps == () and "cmd_vel_topic" not in specs["ekf_node"].overrides
    assert specs["pure_pursuit_node"].remaps == (("cmd_vel", "diff_drive_controller/cmd_vel"),)
    given = _by_name(ekf_nodes(str(REPO), params_file=params, path_file=PATH_FILE, cmd_vel_topic="base/cmd"))
    assert given["ekf_node"].overrides["cmd_vel_topic"] == "base/cmd"
    assert given["pure_pursuit_node"].remaps == (("cmd_vel", "base/cmd"),)


def test_namespace_remaps_and_frame_prefix() -> None:
    (ekf,) = ekf_nodes(str(REPO), namespace="/r1/", frame_prefix="r1/", odom_topic="wheels/odom",
                       imu_topic="/robot/imu")
    assert ekf.namespace == "r1"
    assert dict(ekf.remaps) == {"odometry/dead_wheels": "wheels/odom", "imu/data": "/robot/imu"}
    assert ekf.overrides == {"use_sim_time": False, "odom_frame": "r1/odom",
                             "base_link_frame": "r1/base_link"}
    assert set(INPUT_REMAPS) <= set(EKF_ARGUMENTS)
    sim = _by_name(sim_nodes(str(REPO), namespace="r2", frame_prefix="r2/", use_sim_time="false"))
    assert {s.namespace for s in sim.values()} == {"r2"}
    assert sim["sim_node"].overrides == {"publish_clock": False, "odom_frame": "r2/odom",
                                         "base_link_frame": "r2/base_link"}
    assert sim["ekf_node"].overrides["odom_frame"] == "r2/odom"
    assert "odom_frame" not in sim["pure_pursuit_node"].overrides
    assert ekf.command(["ekf_node"])[:6] == ["ekf_node", "--ros-args", "-r", "__node:=ekf_node",
                                             "-r", "__ns:=/r1"]


def test_sim_launch_runs_the_sim_on_its_clock() -> None:
    specs = _by_name(sim_nodes(str(REPO)))
    assert set(specs) == {"sim_node", "ekf_node", "pure_pursuit_node"}
    assert specs["sim_node"].overrides == {"publish_clock": True}  # someone publishes /clock
    assert specs["ekf_node"].overrides == {"use_sim_time": True}
    assert specs["pure_pursuit_node"].overrides == {"use_sim_time": True, "path_file": PATH_FILE}
    assert set(SIM_ARGUMENTS) >= {"namespace", "frame_prefix", "use_sim_time"}


def test_the_old_launch_file_forwards() -> None:
    target, args, message = legacy_forward(use_sim="false")
    assert target == "ekf.launch.py" and args == {"use_sim_time": "false"}  # no path: no follower
    assert "deprecated" in message and "ekf.launch.py" in message
    target, args, _ = legacy_forward(use_sim="false", ekf_params="/x.yaml", path_file="/p.yaml")
    assert args == {"use_sim_time": "false", "params_file": "/x.yaml", "path_file": "/p.yaml"}
    target, args, _ = legacy_forward()
    assert target == "sim.launch.py" and args == {"use_sim_time": "true"}


# --- running them ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def prefix(tmp_path_factory) -> Path:
    problem = launch_problem()
    if problem:
        pytest.skip(problem)
    return layout_prefix(tmp_path_factory.mktemp("install"))


@pytest.fixture
def probe(ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    node = Node("launch_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    yield node, ex
    ex.shutdown()
    node.destroy_node()


def _topics(node) -> set[str]:
    return {name for name, _ in node.get_topic_names_and_types()}


def _wait_for(ex, node, log: Path, processes: set[str], topics: set[str], timeout: float = 120.0) -> set[str]:
    """Wait until launch started ``processes`` (exactly) and every one of ``topics`` is on the graph."""
    ok = spin_until(ex, lambda: set(started(log)) == processes and topics <= _topics(node), timeout=timeout,
                    step=0.1)
    assert ok, (sorted(started(log)), sorted(topics - _topics(node)), log.read_text()[-4000:])
    pids = started(log)
    assert all(alive(p) for p in pids.values()), log.read_text()[-4000:]
    return _topics(node)


def _has_node(ex, node, name: str, namespace: str) -> bool:
    """Whether the graph shows node ``namespace``/``name`` (node names arrive after the topics)."""
    return spin_until(ex, lambda: (name, namespace) in node.get_node_names_and_namespaces(), timeout=30.0)


def _publishers(node, topic: str) -> int:
    return len(node.get_publishers_info_by_topic(topic))


@pytest.mark.ros
def test_ekf_launch_runs_ekf_node_alone(prefix, probe, tmp_path, record_property) -> None:
    """No arguments: ekf_node alone, estimating within 3 s of the first odometry message."""
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data

    node, ex = probe
    out: list[float] = []
    est = node.create_subscription(Odometry, "/odometry/filtered",
                                   lambda _m: out.append(time.monotonic()), 10)
    wheels = node.create_publisher(Odometry, "/odometry/dead_wheels", qos_profile_sensor_data)
    with launched(prefix, tmp_path, "ekf.launch.py") as log:
        topics = _wait_for(ex, node, log, {"ekf_node"}, {"/" + t for t in EKF_TOPICS} | GLOBAL_TOPICS)
        # both directions matched, so neither the first odometry nor the first estimate is lost
        assert spin_until(ex, lambda: wheels.get_subscription_count() >= 1 and est.get_publisher_count() >= 1,
                          timeout=30.0)
        first = time.monotonic()
        msg = Odometry()
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.twist.covariance = [1e-4 if i % 7 == 0 else 0.0 for i in range(36)]
        deadline = first + 10.0
        while not out and time.monotonic() < deadline:  # the robot's odometry at 50 Hz, standing still
            msg.header.stamp = node.get_clock().now().to_msg()
            wheels.publish(msg)
            spin_until(ex, lambda: bool(out), timeout=0.02, step=0.005)
        assert out, log.read_text()[-3000:]
        record_property("first_output_after_first_odometry_s", round(out[0] - first, 3))
        print(f"first /odometry/filtered {out[0] - first:.3f} s after the first odometry message")
        assert out[0] - first <= 3.0, out[0] - first
        assert _publishers(node, "/cmd_vel") == 0 and "/pure_pursuit/path" not in _topics(node), topics
        assert _has_node(ex, node, "ekf_node", "/")
    assert "has no section for this node" not in log.read_text()


@pytest.mark.ros
def test_ekf_launch_with_a_path_file_starts_the_follower(prefix, probe, tmp_path) -> None:
    node, ex = probe
    with launched(prefix, tmp_path, "ekf.launch.py", path_file=PATH_FILE) as log:
        _wait_for(ex, node, log, {"ekf_node", "pure_pursuit_node"},
                  {"/" + t for t in EKF_TOPICS} | {"/cmd_vel", "/pure_pursuit/path"})
        assert spin_until(ex, lambda: _publishers(node, "/cmd_vel") == 1, timeout=30.0)


@pytest.mark.ros
def test_ekf_launch_in_a_namespace_with_remaps(prefix, probe, tmp_path) -> None:
    node, ex = probe
    with launched(prefix, tmp_path, "ekf.launch.py", namespace="r1", odom_topic="wheels/odom",
                  frame_prefix="r1/") as log:
        want = {"/r1/" + t for t in EKF_TOPICS - {"odometry/dead_wheels"}} | {"/r1/wheels/odom"}
        want |= GLOBAL_TOPICS
        topics = _wait_for(ex, node, log, {"ekf_node"}, want)
        assert _has_node(ex, node, "ekf_node", "/r1")
        # nothing of the robot's outside its namespace but the global topics; the remapped name only
        outside = {t for t in topics if not t.startswith("/r1/")} - GLOBAL_TOPICS
        assert outside <= {"/rosout", "/parameter_events", "/tf_static"}, outside
        assert "/r1/odometry/dead_wheels" not in topics
        services = {n for n, _ in node.get_service_names_and_types_by_node("ekf_node", "/r1")}
        assert {"/r1/ekf_node/reset", "/r1/ekf_node/describe_parameters"} <= services, services
        assert all(n.startswith("/r1/") for n in services), services
    text = log.read_text()
    assert "has no section for this node" not in text, text


@pytest.mark.ros
def test_sim_launch_estimates(prefix, probe, tmp_path) -> None:
    from nav_msgs.msg import Odometry

    node, ex = probe
    odom: list[Odometry] = []
    node.create_subscription(Odometry, "/odometry/filtered", odom.append, 10)
    with launched(prefix, tmp_path, "sim.launch.py") as log:
        _wait_for(ex, node, log, {"sim_node", "ekf_node", "pure_pursuit_node"},
                  {"/" + t for t in EKF_TOPICS} | {"/clock", "/cmd_vel", "/ground_truth/odom", "/tf"})
        assert spin_until(ex, lambda: len(odom) >= 10, timeout=120.0), log.read_text()[-4000:]
    assert "has no section for this node" not in log.read_text()
    assert odom[-1].header.frame_id == "map" and odom[-1].child_frame_id == "base_link"


@pytest.mark.ros
def test_sim_launch_with_two_cameras_fuses_both(prefix, probe, tmp_path) -> None:
    """``camera:=images cameras:=2``: sim_node renders two cameras, a tag_localizer per camera (the
    second in namespace camera1) and ekf_node on ekf_two_cameras.yaml applies both (pose0, pose1)."""
    pytest.importorskip("cv2")
    pytest.importorskip("dt_apriltags")
    from diagnostic_msgs.msg import DiagnosticArray

    node, ex = probe
    latest: dict[str, dict[str, str]] = {}
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: latest.update(
        {st.name: {kv.key: kv.value for kv in st.values} for st in m.status}), 50)

    def applied(name: str) -> int:
        return int(latest.get(f"ekf_node: {name}", {}).get("applied", "0") or 0)

    with launched(prefix, tmp_path, "sim.launch.py", camera="images", cameras="2") as log:
        _wait_for(ex, node, log, {"sim_node", "ekf_node", "pure_pursuit_node", "tag_localizer"},
                  {"/camera/image_raw", "/camera1/image_raw", "/camera1/camera_info", "/camera/pose",
                   "/camera1/pose", "/odometry/filtered"})
        assert [n for n, _ in started_all(log)].count("tag_localizer") == 2, log.read_text()[-3000:]
        assert _has_node(ex, node, "tag_localizer", "/camera1") and _has_node(ex, node, "tag_localizer", "/")
        ok = spin_until(ex, lambda: applied("pose0") >= 5 and applied("pose1") >= 5, timeout=180.0, step=0.1)
        assert ok, (latest, log.read_text()[-4000:])
        # config/tag_localizer.yaml's single_tag corners: a tag_cornersN per layout tag and camera
        layout = yaml.safe_load((REPO / "config" / "tags" / "ftc_seed000.yaml").read_text())
        corner_inputs = {n for n in latest if n.startswith("ekf_node: tag_corners")}
        assert len(corner_inputs) == 2 * len(layout["tags"]), sorted(latest)
    assert "has no section for this node" not in log.read_text()


@pytest.mark.ros
def test_the_old_launch_file_warns_and_forwards(prefix, probe, tmp_path) -> None:
    node, ex = probe
    with launched(prefix, tmp_path, "ekf_localization.launch.py", use_sim="false") as log:
        _wait_for(ex, node, log, {"ekf_node"}, {"/odometry/filtered"})
    warning = [ln for ln in log.read_text().splitlines() if "deprecated" in ln]
    assert len(warning) == 1 and "WARNING" in warning[0] and "ekf.launch.py" in warning[0], warning


def test_no_launch_package_gives_a_clear_skip_reason(monkeypatch, tmp_path) -> None:
    import helpers.launch_runner as runner

    monkeypatch.setattr(runner, "_system_launch", lambda: False)
    monkeypatch.setattr(runner, "VENDORED", tmp_path / "shared" / "vendor" / "ros2_launch")
    reason = runner.launch_problem()
    assert reason and "ros2_launch" in reason and "launch_ros" in reason
