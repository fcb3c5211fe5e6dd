"""tag_localizer's ``single_tag: corners``: a lone tag's corner pixels go to ekf_node's tag_cornersN.

The generated inputs (tools/tag_corner_inputs.py) project the layout as the simulator's camera
sees it; over DDS, single-tag frames give no pose but corners that ekf_node fuses, and a
multi-tag frame still gives the PnP pose.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import tag_images
from helpers.ros_helpers import node_command, running_process, spin_until, wait_for_subscribers

from ekf_localization.inputs.tag_corners import TagCornerMeasurement
from ekf_localization.ros.parameters import ParameterError
from ekf_localization.ros.tag_localizer_parameters import parse_settings
from ekf_localization.tools import demo_images
from ekf_localization.tools.tag_corner_inputs import tag_corner_inputs
from ekf_localization.vision import tag_pnp
from ekf_localization.vision.camera_geometry import mount_rotation_translation
from ekf_localization.vision.corner_noise import CornerNoise

pytest.importorskip("cv2")
REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config"


def _model(values: dict, k: int) -> TagCornerMeasurement:
    R_bc, t_bc = mount_rotation_translation(values[f"tag_corners{k}_camera_mount"])
    return TagCornerMeasurement(np.array(values[f"tag_corners{k}_corners"]), values[f"tag_corners{k}_camera"],
                                R_bc, t_bc, (0, 1, 2), 3)


def test_demo_inputs_project_the_layout_as_the_simulated_camera_does(tmp_path: Path) -> None:
    """The images demo's tag_cornersN (both cameras, the first one yawed and pitched): each tag's
    h(x) from a robot pose equals the projection through the simulator's own camera mount
    (sim_robot's base_to_optical)."""
    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.ros.params_match import section_for
    from sim_robot.ros.sim_params import parse_parameters
    from sim_robot.world.camera_image_sensor import CameraImageSensor

    doc = yaml.safe_load((CONFIG / "sim.yaml").read_text())
    section_for(doc, "sim_node")["camera_images"]["mount"] = [0.12, 0.04, 0.2, 0.3, 0.15]
    sim_yaml = tmp_path / "sim.yaml"
    sim_yaml.write_text(yaml.safe_dump(doc))
    values = demo_images.ekf_overrides(CONFIG, sim_yaml, 2, "corners")
    assert demo_images.ekf_overrides(CONFIG, sim_yaml, 2, "ambiguity") == {}
    sim_values = parameters_from_yaml(sim_yaml, "sim_node")
    sim_values.update({"camera_images.enabled": True, "camera1.enabled": True})
    sim = parse_parameters(sim_values)[1]
    layout = sim.camera_images.layout
    n = len(layout.tags)
    assert sum(1 for k in values if k.removeprefix("tag_corners").isdigit()) == 2 * n
    pose = np.array([0.3, -0.2, 0.0, 0.0, 0.0, 2.0])
    for camera, images in enumerate((sim.camera_images, sim.camera1_images)):
        sensor = CameraImageSensor(images)
        in_front = 0
        for k, tag_id in enumerate(sorted(layout.tags)):
            i = camera * n + k
            assert values[f"tag_corners{i}"] == ("camera1/" if camera else "") + f"tag_corners/tag_{tag_id}"
            problem = tag_pnp.PnPProblem(layout.tags[tag_id].corners_map(), np.zeros((4, 2)), images.camera,
                                         sensor.base_to_optical(), (tag_id,))
            if np.any(tag_pnp.camera_points(problem, pose)[:, 2] < 0.1):
                continue                      # behind this camera: h holds the depth, PnP does not
            in_front += 1
            uv, _ = tag_pnp.residuals_and_jacobian(problem, pose)
            h = _model(values, i).h(pose[[0, 1, 5]][None])[0]
            np.testing.assert_allclose(h, uv, atol=1e-9)
        assert in_front >= 3
    noise = demo_images.tag_localizer_settings(CONFIG).corner_noise
    assert values["tag_corners0_pixel_std"] == noise.pixel_std
    assert values["tag_corners0_camera_frame"] == sim.camera_frame


def test_corners_in_mode_tf_are_the_ambiguity_gate(tmp_path: Path) -> None:
    """apriltag_ros's tag frames carry no pixels: the shipped corners default works in mode tf
    as the gate; an unknown method is still refused."""
    layout = tmp_path / "tags.yaml"
    layout.write_text(yaml.safe_dump(tag_images.LAYOUT_DICT))
    settings = parse_settings({"layout_file": str(layout), "mode": "tf", "single_tag": "corners"})
    assert settings.single_tag == "ambiguity"
    assert parse_settings({"layout_file": str(layout), "single_tag": "corners"}).single_tag == "corners"
    with pytest.raises(ParameterError, match="single_tag"):
        parse_settings({"layout_file": str(layout), "mode": "tf", "single_tag": "corner"})


def _diagonal15(values: dict[int, float]) -> list[float]:
    m = np.zeros((15, 15))
    for i, v in values.items():
        m[i, i] = v
    return m.ravel().tolist()


class _Camera:
    """A probe node that plays the camera: the mount on /tf_static, then images and CameraInfo."""

    def __init__(self, ros_context, name: str) -> None:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import CameraInfo, Image
        from test_tag_localizer import _static_mount_tf
        from tf2_msgs.msg import TFMessage

        from ekf_localization.ros.tf_io import TF_STATIC_QOS

        self.node = Node(name, context=ros_context)
        self.ex = SingleThreadedExecutor(context=ros_context)
        self.ex.add_node(self.node)
        self.node.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS).publish(_static_mount_tf())
        self.img = self.node.create_publisher(Image, "camera/image_raw", qos_profile_sensor_data)
        self.info = self.node.create_publisher(CameraInfo, "camera/camera_info", qos_profile_sensor_data)

    def play(self, pixels: np.ndarray, done, frames: int) -> None:
        """A 10 Hz camera of ``pixels`` until ``done()`` or ``frames`` frames."""
        from test_tag_localizer import _camera_info_msg, _image_msg

        for _ in range(frames):
            now = self.node.get_clock().now().nanoseconds
            self.info.publish(_camera_info_msg(now))
            self.img.publish(_image_msg(pixels, now))
            if spin_until(self.ex, done, 0.1):
                return

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()


@pytest.mark.ros
def test_single_tag_corners_are_fused_by_ekf_node_over_dds(ros_context, tmp_path: Path) -> None:
    """Images of one tag: tag_localizer publishes no pose but tag 2's corners, ekf_node's
    tag_corners1 applies them (its /diagnostics) and its estimate ends nearer the truth; an image
    of three tags still gives a PnP pose on camera/pose."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PolygonStamped, PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data


    layout = tmp_path / "tags.yaml"
    layout.write_text(yaml.safe_dump(tag_images.LAYOUT_DICT))
    noise = CornerNoise(0.5)
    tag_params = tmp_path / "tag.yaml"
    tag_params.write_text(yaml.safe_dump({"tag_localizer": {"ros__parameters": {
        "layout_file": str(layout), "single_tag": "corners", "pixel_std": noise.pixel_std}}}))
    truth = np.array([1.7, 1.9, 0.0, 0.0, 0.0, math.pi + 0.05])
    start = [float(truth[0]) + 0.04, float(truth[1]) - 0.03, 0.0, 0.0, 0.0, float(truth[5])] + [0.0] * 9
    cam = tag_images.CAMERA
    ekf = {"model": "mecanum", "world_frame": "map", "frequency": 50.0, "publish_tf": False,
           "initial_state": start,
           "initial_estimate_covariance": _diagonal15({0: 0.05**2, 1: 0.05**2, 5: 0.005**2,
                                                       6: 1e-6, 7: 1e-6, 11: 1e-6}),
           "process_noise_covariance": _diagonal15({0: 1e-8, 1: 1e-8, 5: 1e-8, 6: 1e-6, 7: 1e-6, 11: 1e-6}),
           "pose0": "camera/pose", "pose0_config": [True, True, False, False, False, True] + [False] * 9,
           **tag_corner_inputs(tag_images.LAYOUT, (cam.fx, cam.fy, cam.cx, cam.cy), tag_images.MOUNT_XYZ_RPY,
                               noise, camera_frame="camera_optical")}
    ekf_params = tmp_path / "ekf.yaml"
    ekf_params.write_text(yaml.safe_dump({"ekf_node": {"ros__parameters": ekf}}))

    camera = _Camera(ros_context, "corners_test")
    node, ex = camera.node, camera.ex
    poses: list = []
    corners: list = []
    outputs: list = []
    status: dict[str, dict[str, str]] = {}
    node.create_subscription(PoseWithCovarianceStamped, "camera/pose", poses.append, 10)
    node.create_subscription(PolygonStamped, "tag_corners/tag_2", corners.append, qos_profile_sensor_data)
    node.create_subscription(Odometry, "odometry/filtered", outputs.append, 100)
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: status.update(
        {s.name: {kv.key: kv.value for kv in s.values} for s in m.status}), 50)

    def count(name: str, key: str) -> int:
        return int(status.get(name, {}).get(key, "0") or 0)

    one_tag = tag_images.render(truth, (2,), noise_std=2.0, rng=np.random.default_rng(3))
    three_tags = tag_images.render(truth, (1, 2, 3), noise_std=2.0, rng=np.random.default_rng(4))
    tag_log, ekf_log = tmp_path / "tag_localizer.log", tmp_path / "ekf.log"
    try:
        with running_process([*node_command("tag_localizer"), "--ros-args", "--params-file", str(tag_params)],
                             tag_log), \
             running_process([*node_command("ekf_node"), "--ros-args", "--params-file", str(ekf_params)],
                             ekf_log) as ekf_proc:
            assert wait_for_subscribers(ex, camera.img, timeout=60.0), tag_log.read_text()

            def applied() -> int:
                return count("ekf_node: tag_corners1", "applied")

            camera.play(one_tag, lambda: applied() >= 5, 100)      # up to 10 s
            assert applied() >= 5, (status.get("ekf_node: tag_corners1"), ekf_log.read_text()[-2000:])
            spin_until(ex, lambda: count("tag_localizer: tag fixes", "corner_frames") >= 5, 3.0)
            assert not poses and corners
            assert count("tag_localizer: tag fixes", "corner_frames") >= 5
            assert count("tag_localizer: tag fixes", "fixes_accepted") == 0
            assert corners[0].header.frame_id == "camera_optical"
            uv = np.array([[p.x, p.y] for p in corners[0].polygon.points])
            assert np.abs(uv - tag_images.project_tag(truth, 2)).max() < 1.5
            assert outputs, ekf_log.read_text()
            p = outputs[-1].pose.pose.position
            # a heading known to 0.3°: one tag 1.6 m away must pull both x and y in
            assert math.hypot(p.x - truth[0], p.y - truth[1]) < 0.3 * math.hypot(start[0] - truth[0],
                                                                                  start[1] - truth[1])
            camera.play(three_tags, lambda: bool(poses), 50)       # several tags: the PnP pose as before
            assert poses, tag_log.read_text()
            assert ekf_proc.poll() is None and "Traceback" not in ekf_log.read_text() + tag_log.read_text()
    finally:
        camera.close()


@pytest.mark.ros
def test_corners_nobody_subscribes_to_are_a_warning_naming_the_fix(ros_context, tmp_path: Path) -> None:
    """single_tag: corners with no tag_cornersN in the filter: the lone tag's frames are lost, so
    /diagnostics warns and names tag_corner_inputs (and counts them)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus


    layout = tmp_path / "tags.yaml"
    layout.write_text(yaml.safe_dump(tag_images.LAYOUT_DICT))
    tag_params = tmp_path / "tag.yaml"
    tag_params.write_text(yaml.safe_dump({"tag_localizer": {"ros__parameters": {
        "layout_file": str(layout), "single_tag": "corners"}}}))
    camera = _Camera(ros_context, "corners_unheard_test")
    node, ex = camera.node, camera.ex
    status: dict[str, DiagnosticStatus] = {}
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: status.update({s.name: s for s in m.status}), 50)

    def values() -> dict[str, str]:
        st = status.get("tag_localizer: tag fixes")
        return {kv.key: kv.value for kv in st.values} if st else {}

    truth = np.array([1.7, 1.9, 0.0, 0.0, 0.0, math.pi + 0.05])
    one_tag = tag_images.render(truth, (2,), noise_std=2.0, rng=np.random.default_rng(3))
    log = tmp_path / "tag_localizer.log"
    try:
        with running_process([*node_command("tag_localizer"), "--ros-args", "--params-file", str(tag_params)],
                             log):
            assert wait_for_subscribers(ex, camera.img, timeout=60.0), log.read_text()
            camera.play(one_tag, lambda: int(values().get("corner_frames", "0")) >= 3, 100)  # up to 10 s
            frames = int(values().get("corner_frames", "0"))
            assert frames >= 3, log.read_text()[-2000:]
            st = status["tag_localizer: tag fixes"]
            assert st.level == DiagnosticStatus.WARN and "tag_corner_inputs" in st.message, st.message
            assert int(values()["corner_frames_unsubscribed"]) == frames
    finally:
        camera.close()


def test_cli_prints_inputs_that_ekf_node_parses(capsys) -> None:
    """tag_corner_inputs' YAML, added to config/ekf.yaml, parses as ekf_node's: one tag_cornersN per
    layout tag; a missing file is a clear error (exit 2)."""
    from ekf_localization.ros.ekf_parameters import parse_ekf_settings
    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.tools import tag_corner_inputs as cli

    args = ["--tag-localizer", str(CONFIG / "tag_localizer.yaml"), "--camera", "457", "457", "319.5", "239.5",
            "--mount", "0.1", "0", "0.15", "0", "0.1", "0", "--camera-frame", "camera_optical"]
    assert cli.main(args) == 0
    printed = yaml.safe_load(capsys.readouterr().out)["ekf_node"]["ros__parameters"]
    values = parameters_from_yaml(CONFIG / "ekf.yaml", "ekf_node") | printed
    settings = parse_ekf_settings(values)
    names = {i.name for i in settings.config.inputs}
    layout = demo_images.tag_localizer_settings(CONFIG).layout
    assert {f"tag_corners{k}" for k in range(len(layout.tags))} <= names
    assert printed["tag_corners0_camera_mount"] == [0.1, 0.0, 0.15, 0.0, 0.1, 0.0]
    assert cli.main(["--tag-localizer", "/no/such/file.yaml", "--camera", "1", "1", "0", "0",
                     "--mount", "0", "0", "0", "0", "0", "0"]) == 2
    assert "tag_corner_inputs:" in capsys.readouterr().err
