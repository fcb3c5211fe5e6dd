"""Two cameras: sim_node's second camera (config/sim.yaml ``camera1``), config/ekf_two_cameras.yaml
(pose0 and pose1), sim.launch.py's ``cameras:=2``, and over DDS two tag_localizers in their own
namespaces feeding one ekf_node, which fuses both."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.ros_helpers import REPO, Diagnostics, node_command, running_process

from ekf_localization.ros.launch_description import SECOND_CAMERA_TOPICS, sim_nodes
from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml
from sim_robot.ros.sim_params import parse_parameters
from sim_robot.world.camera_image_sensor import CameraImageSensor
from sim_robot.world.camera_sensor import CameraConfig
from sim_robot.world.world import World, WorldConfig

CONFIG = REPO / "config"
LAYOUT = CONFIG / "tags" / "ftc_seed000.yaml"
# facing the top wall's left tags (ids 1-3) from 1.5 m; the backward camera sees ids 7-9 from 2.2 m
STAND = (-0.9144, 0.3, math.pi / 2)


def _camera_readings(world: World, seconds: float) -> list:
    return [r for r in world.advance(int(seconds * 1e9)) if type(r).__name__ == "CameraReading"]


def test_the_world_carries_a_second_camera_with_its_own_mount_and_noise() -> None:
    """Off by default; on, its readings say camera 1, it sees the wall behind, and the first
    camera's readings are those of a world without it (its own random stream)."""
    base = WorldConfig(camera=CameraConfig(period_ns=50_000_000, max_range=3.0))
    one = World(base, seed=3)
    two = World(WorldConfig(camera=base.camera, camera1=CameraConfig(
        period_ns=50_000_000, max_range=3.0, mount_pose=(-0.1, 0.0, math.pi))), seed=3)
    for w in (one, two):
        w.reset(np.array(STAND))
    first = _camera_readings(one, 0.5)
    both = _camera_readings(two, 0.5)
    assert {r.camera for r in first} == {0} and len(first) == 10
    assert [r.camera for r in both] == [0, 1] * 10  # same stamps, the first camera first
    for a, b in zip(first, [r for r in both if r.camera == 0], strict=True):
        np.testing.assert_array_equal(a.pose, b.pose)
    behind = [r for r in both if r.camera == 1]
    assert all(r.visible[0] for r in behind)
    walls = {int(r.image_index[0]) for r in behind} | {int(r.image_index[0]) for r in first}
    assert len(walls) == 2  # one image ahead (top wall), another behind (bottom wall)
    for r in behind:  # the robot's pose (it stands still), measured through the other mount
        err = r.pose[0, :2] - STAND[:2]
        assert np.all(np.abs(err) < 4.0 * np.sqrt(np.diag(r.cov[0])[:2])), (err, r.cov[0])


def test_sim_parameters_of_the_second_camera() -> None:
    world, node = parse_parameters({})
    assert not world.camera1.enabled and node.camera1_images is None
    mount = [-0.2, 0.05, 0.2, 1.5707963267948966, 0.1]
    world, node = parse_parameters({"camera1.enabled": True, "camera1.mount": mount,
                                    "camera_images.enabled": True, "camera_images.tag_layout": str(LAYOUT)})
    assert world.camera1.enabled and world.camera1.mount_pose == (-0.2, 0.05, mount[3])
    assert world.camera1.period_ns == world.camera.period_ns  # the camera.* model at another mount
    assert node.camera1_images.mount == tuple(mount) and node.camera1_frame == "camera1_optical"
    assert node.camera1_images.camera == node.camera_images.camera
    # free-running: its captures half a period after the first camera's (20 Hz: 25 ms)
    assert (node.camera_images.phase_ns, node.camera1_images.phase_ns) == (0, 25_000_000)
    first, second = (CameraImageSensor(c) for c in (node.camera_images, node.camera1_images))
    assert [second.next_capture_ns(t) for t in (0, 24_999_999, 25_000_000, 70_000_000)] == \
        [25_000_000, 25_000_000, 75_000_000, 75_000_000]
    assert first.next_capture_ns(0) == 50_000_000 and second.due(125_000_000) and not second.due(100_000_000)
    _, off = parse_parameters({"camera1.enabled": True, "camera.enabled": False})
    assert off.camera1_images is None
    with pytest.raises(ParameterError, match="camera1.frame_id"):
        parse_parameters({"camera1.enabled": True, "camera1.frame_id": "camera_optical"})
    with pytest.raises(ParameterError, match="camera1.mount"):
        parse_parameters({"camera1.mount": [0.0, 0.0, 0.1]})
    shipped = parameters_from_yaml(CONFIG / "sim.yaml", "sim_node")
    assert shipped["camera1.enabled"] is False and shipped["camera1.mount"][3] == pytest.approx(math.pi)


def test_two_cameras_config_is_ekf_yaml_plus_pose1() -> None:
    from ekf_localization.models.registry import MODELS
    from ekf_localization.ros.ekf_parameters import load_ekf_settings

    two = parameters_from_yaml(CONFIG / "ekf_two_cameras.yaml")
    one = parameters_from_yaml(CONFIG / "ekf.yaml")
    assert {k: v for k, v in two.items() if not k.startswith("pose1")} == one
    assert two["pose1"] == "camera1/pose"
    assert {k.replace("pose1", "pose0"): v for k, v in two.items() if k.startswith("pose1")
            and k != "pose1"} == {k: v for k, v in one.items() if k.startswith("pose0_")}
    settings = load_ekf_settings(CONFIG / "ekf_two_cameras.yaml", MODELS)
    assert settings.warnings == ()
    assert [i.topic for i in settings.config.inputs if i.name.startswith("pose")] == ["camera/pose",
                                                                                     "camera1/pose"]


def test_sim_launch_with_two_cameras_starts_a_tag_localizer_per_camera() -> None:
    specs = sim_nodes(str(REPO), camera="images", cameras="2", namespace="r1", frame_prefix="r1/")
    by = {(s.namespace, s.name): s for s in specs}
    assert set(by) == {("r1", "sim_node"), ("r1", "ekf_node"), ("r1", "pure_pursuit_node"),
                       ("r1", "tag_localizer"), ("r1/camera1", "tag_localizer")}
    sim = by[("r1", "sim_node")].overrides
    assert sim["camera1.enabled"] is True and sim["camera_images.enabled"] is True
    assert sim["camera.enabled"] is False
    frames = (sim["camera_images.frame_id"], sim["camera1.frame_id"])
    assert frames == ("r1/camera_optical", "r1/camera1_optical")
    assert by[("r1", "ekf_node")].param_files == (str(CONFIG / "ekf_two_cameras.yaml"),)
    second = by[("r1/camera1", "tag_localizer")].overrides
    assert {k: second[k] for k in SECOND_CAMERA_TOPICS} == SECOND_CAMERA_TOPICS
    assert second["base_link_frame"] == "r1/base_link" and second["layout_file"] == str(LAYOUT)
    assert not set(SECOND_CAMERA_TOPICS) & set(by[("r1", "tag_localizer")].overrides)
    poses = {(s.namespace, s.name) for s in sim_nodes(str(REPO), cameras="2")}
    assert ("", "tag_localizer") not in poses  # camera:=poses: sim_node's camera1/pose, no images
    given = {s.name: s for s in sim_nodes(str(REPO), cameras="2", ekf_params="/x.yaml")}
    assert given["ekf_node"].param_files == ("/x.yaml",)
    one = {s.name: s for s in sim_nodes(str(REPO))}
    assert one["ekf_node"].param_files == (str(CONFIG / "ekf.yaml"),)
    assert "camera1.enabled" not in one["sim_node"].overrides
    with pytest.raises(ValueError, match="cameras"):
        sim_nodes(str(REPO), cameras="3")
    with pytest.raises(ValueError, match="camera"):
        sim_nodes(str(REPO), camera="video")


@pytest.mark.ros
def test_sim_node_publishes_the_second_cameras_poses(ros_context, tmp_path) -> None:
    """Pose mode: camera1/pose beside camera/pose, each the robot's pose from its own view."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from helpers.ros_helpers import spin_until
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    probe = Node("camera_pose_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(probe)
    got: dict[str, list] = {"camera": [], "camera1": []}
    for name, out in got.items():
        probe.create_subscription(PoseWithCovarianceStamped, f"{name}/pose", out.append, 50)
    cmd = [*node_command("sim_node"), "--ros-args", "--params-file", str(CONFIG / "sim.yaml"),
           "-p", "publish_clock:=true", "-p", "camera1.enabled:=true", "-p", f"initial_pose:={list(STAND)}"]
    try:
        with running_process(cmd, tmp_path / "sim.log") as proc:
            ok = spin_until(ex, lambda: min(len(v) for v in got.values()) >= 5, timeout=60.0)
            assert ok and proc.poll() is None, (tmp_path / "sim.log").read_text()[-2000:]
    finally:
        ex.shutdown()
        probe.destroy_node()
    for msgs in got.values():
        for m in msgs:
            p = m.pose.pose.position
            assert m.header.frame_id == "map"
            assert math.hypot(p.x - STAND[0], p.y - STAND[1]) < 4.0 * math.sqrt(m.pose.covariance[0]) + 0.05


def two_camera_commands() -> dict[str, list[str]]:
    """sim_node rendering both cameras (standing at ``STAND``), a tag_localizer per camera (the
    second in namespace camera1), ekf_node on config/ekf_two_cameras.yaml; all on sim time."""
    sim_time = ["-p", "use_sim_time:=true"]
    tags = ["--params-file", str(CONFIG / "tag_localizer.yaml"), *sim_time, "-p", f"layout_file:={LAYOUT}"]
    second = [a for k, v in SECOND_CAMERA_TOPICS.items() for a in ("-p", f"{k}:={v}")]
    return {
        "sim": [*node_command("sim_node"), "--ros-args", "--params-file", str(CONFIG / "sim.yaml"),
                "-p", "publish_clock:=true", "-p", "camera.enabled:=false",
                "-p", "camera_images.enabled:=true", "-p", f"camera_images.tag_layout:={LAYOUT}",
                "-p", "camera1.enabled:=true", "-p", f"initial_pose:={list(STAND)}"],
        "tags0": [*node_command("tag_localizer"), "--ros-args", *tags],
        "tags1": [*node_command("tag_localizer"), "--ros-args", "-r", "__ns:=/camera1", *tags, *second],
        "ekf": [*node_command("ekf_node"), "--ros-args", "--params-file",
                str(CONFIG / "ekf_two_cameras.yaml"), *sim_time, "-p", "thread_priority:=0",
                "-p", f"initial_state:={[STAND[0], STAND[1], 0.0, 0.0, 0.0, STAND[2]] + [0.0] * 9}"],
    }


@pytest.mark.ros
def test_two_tag_localizers_feed_one_ekf_node_over_dds(ros_context, tmp_path) -> None:
    """Both cameras' fixes reach ekf_node and are applied: its /diagnostics counts pose0 and pose1."""
    pytest.importorskip("cv2")
    pytest.importorskip("dt_apriltags")
    from contextlib import ExitStack

    diags = Diagnostics(ros_context)
    cmds = two_camera_commands()

    def applied(name: str) -> int:
        return int(diags.get(f"ekf_node: {name}", "applied", "0") or 0)

    def fixes(status: str) -> int:  # a tag_localizer's accepted fixes (its /diagnostics, 1 Hz)
        return int(diags.get(f"{status}: tag fixes", "fixes_accepted", "0") or 0)

    try:
        with ExitStack() as stack:
            procs = {k: stack.enter_context(running_process(cmd, tmp_path / f"{k}.log"))
                     for k, cmd in cmds.items()}
            ok = diags.spin_until(lambda: applied("pose0") >= 10 and applied("pose1") >= 10
                                  and fixes("tag_localizer") > 0 and fixes("camera1/tag_localizer") > 0
                                  or any(p.poll() is not None for p in procs.values()), timeout=120.0)
            logs = {k: (tmp_path / f"{k}.log").read_text()[-1500:] for k in cmds}
            assert ok and all(p.poll() is None for p in procs.values()), (diags.latest, logs)
            assert int(diags.get("ekf_node: pose1", "rejected", "0") or 0) <= applied("pose1") // 10
    finally:
        diags.close()
