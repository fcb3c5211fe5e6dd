"""A camera mount's offset fitted with the pods or the driven wheels (tools/mount_calibration.py
through tools/pod_calibration.py) on synthetic drives (docs/models.md, "Camera mount")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_driven_calibration import MEC_TRUE
from test_driven_calibration import problem as driven_problem
from test_pod_calibration import NOMINAL, assert_jacobian_is_the_difference, problem, synthetic, twist

from ekf_localization.models.sensors.dead_wheels import PodGeometry
from ekf_localization.tools import mount_calibration as mc
from ekf_localization.tools import pod_calibration as pc

PODS = PodGeometry((0.19, -0.15, 0.12), (0.02, -0.02, 1.55), (1.03, 0.97, 1.02))  # parallel mean 0


def mounted_fixes(data, delta):
    """The synthetic drive's fixes as a camera whose mount is off by Δ gives them: F = B ∘ Δ."""
    fixes, enc = data
    pose = pc.at_mount(fixes.pose, np.asarray(delta, float))
    pose[:, 2] = np.remainder(pose[:, 2] + np.pi, 2 * np.pi) - np.pi
    return dataclasses.replace(fixes, pose=pose), enc


def test_the_jacobian_with_a_mount_and_a_gauge_is_the_finite_difference() -> None:
    p = problem(mounted_fixes(synthetic(20.0, PODS, fix_sd=0.01, seed=2), (0.0, 0.0, 0.035)))
    start = mc.Mounted(NOMINAL, (0.01, -0.02, 0.01), mc.pod_gauge(NOMINAL))
    assert start.tie == mc.Tie(4, (3,), 0.0)  # the right pod's angle follows the left's: their mean 0
    free = np.ones(12, bool)
    free[4] = False
    f = pc._Fit(p, start, free)
    x = np.r_[pc.initial_poses(p, start).ravel(), start.vector[free]]
    x += 1e-3 * np.random.default_rng(1).standard_normal(len(x))
    assert_jacobian_is_the_difference(f, x, [*range(6), *range(3 * p.n - 3, 3 * p.n + 11)], 1e-7, 1e-5)


def test_a_mount_yaw_is_recovered_with_the_pods_and_the_gauge_held() -> None:
    """A 2° mount yaw with every pod angle free: the parallel pods' mean angle stays at the file's
    (0), and Δθ and every pod come out exactly from noise-free data."""
    p = problem(mounted_fixes(synthetic(30.0, PODS), (0.0, 0.0, np.radians(2.0))))
    start = mc.Mounted(NOMINAL, tie=mc.pod_gauge(NOMINAL))
    free = np.r_[np.ones(9, bool), False, False, True]  # the mount's x, y: held (a base_link shift)
    free[4] = False  # tied
    r = pc.fit(p, start, free)
    np.testing.assert_allclose(r.pods.vector, np.r_[PODS.vector, 0.0, 0.0, np.radians(2.0)], atol=1e-7)
    ok, std = pc.observable(p, start, free, mc.limits(pc.limits(3)))
    assert ok[free].all() and std[11] < mc.MOUNT_MAX_STD[2]


def test_without_the_gauge_a_common_pod_rotation_trades_with_the_mount_yaw() -> None:
    p = problem(mounted_fixes(synthetic(30.0, PODS, fix_sd=0.005, seed=4), (0.0, 0.0, 0.03)))
    free = np.r_[np.ones(9, bool), False, False, True]
    ok, std = pc.observable(p, mc.Mounted(NOMINAL), free, mc.limits(pc.limits(3)))
    assert not ok[free].all()  # one of the angles or the yaw is held: the drive cannot tell them apart


def test_the_wheels_give_the_whole_mount_and_turning_alone_its_translation() -> None:
    delta = (0.03, -0.02, np.radians(2.0))
    data = mounted_fixes(synthetic(30.0, MEC_TRUE, drive=twist), delta)
    start = mc.Mounted(MEC_TRUE)
    free = np.r_[np.zeros(len(MEC_TRUE.vector), bool), True, True, True]  # the mount only
    r = pc.fit(driven_problem(data), start, free)
    np.testing.assert_allclose(r.pods.mount, delta, atol=1e-7)
    turning = mounted_fixes(synthetic(30.0, MEC_TRUE, drive=_turning), delta)
    ok, _ = pc.observable(driven_problem(turning), start, free, mc.limits(MEC_TRUE.limits()))
    assert ok[-3] and ok[-2] and not ok[-1]  # a turn in place: the circle gives x, y but not the yaw


def test_the_corrected_mount_composes_the_offset_with_the_believed_one() -> None:
    believed = np.array([0.1, 0.05, 0.2])
    true = np.array([0.12, 0.03, 0.25])
    delta = pc.at_mount(true[None, :], mc.inverse(believed))[0]  # Δ = M ∘ M₀⁻¹
    np.testing.assert_allclose(mc.corrected_mount(delta, believed), true, atol=1e-12)


def _turning(t: np.ndarray, pushes: bool = True) -> np.ndarray:
    return twist(t, False)


def test_the_simulated_camera_reports_its_own_pose_at_its_true_mount() -> None:
    """``pose_of_camera``: the fix is the camera frame's pose (B ∘ M), for the filter to turn into
    base_link's through the mount it believes; without it, base_link's pose."""
    from sim_robot.world.camera_sensor import CameraConfig, CameraNoise, CameraSensor
    from sim_robot.world.field import Field, FieldImage

    quiet = CameraNoise(0.0, 1e-30)
    mount = (0.1, -0.05, 0.035)
    pose = np.array([[0.5, -0.2, 0.3]])
    field = Field(10.0, (FieldImage(3.0, 0.5, np.pi, 0.3),))  # an image 2.5 m ahead, facing the robot
    for of_camera, expected in ((True, pc.at_mount(pose, np.array(mount))), (False, pose)):
        cfg = CameraConfig(mount_pose=mount, position_noise=quiet, yaw_noise=quiet, pose_of_camera=of_camera)
        r = CameraSensor(cfg, field, 1, np.random.default_rng(0)).capture(0, pose)
        assert r.visible[0]
        np.testing.assert_allclose(r.pose, expected, atol=1e-9)


def test_report_writes_the_static_transforms_entry_and_warns_for_tf_static(capsys) -> None:
    from ekf_localization.tools.ekf_calibrate_mount import TF_STATIC, CameraMount, report

    values = {"static_transforms": ["1 2 3 0 0 0 map other", "0.1 0 0.2 0 0.1 0 base_link camera_link"]}
    mount = CameraMount("pose0", "/camera/pose", "base_link", "camera_link", (0.1, 0.0, 0.2, 0.0, 0.1, 0.0),
                        "static_transforms")
    delta = np.array([0.0, 0.0, 0.035])
    only_yaw = np.array([False, False, True])
    assert report(mount, delta, np.full(3, 1e-3), only_yaw, values) == ["static_transforms"]
    assert values["static_transforms"][0] == "1 2 3 0 0 0 map other"
    words = values["static_transforms"][1].split()
    assert words[6:] == ["base_link", "camera_link"] and float(words[3]) == pytest.approx(0.035)
    assert float(words[2]) == 0.2 and float(words[4]) == 0.1  # z and pitch as the file has them
    out = capsys.readouterr().out
    assert "static_transforms[base_link camera_link].yaw 0.035 ± 0.001 (was 0)" in out
    assert "warning" not in out
    report(dataclasses.replace(mount, source=TF_STATIC), delta, np.full(3, 1e-3), np.ones(3, bool), {})
    assert "warning: base_link -> camera_link came from /tf_static in the bag" in capsys.readouterr().out
    with pytest.raises(ValueError, match="fixes not of this robot"):
        report(mount, np.array([0.0, 0.0, 1.0]), np.ones(3), np.ones(3, bool), {})


def mount_params(tmp_path, static: bool = True):
    """config/ekf_joint_states.yaml with pose0 the camera frame's pose, the mount believed 0."""
    from test_pod_calibration import JOINT_YAML

    text = JOINT_YAML.read_text().replace("    pose0: camera/pose\n",
                                          "    pose0: camera/pose\n    pose0_pose_frame: camera_link\n")
    if static:
        text = text.replace("    base_link_frame: base_link\n", "    base_link_frame: base_link\n"
                            '    static_transforms: ["0 0 0 0 0 0 base_link camera_link"]\n')
    path = tmp_path / "params.yaml"
    path.write_text(text)
    return path


def test_a_drive_that_only_turns_names_the_mount_yaw_and_leaves_it(tmp_path, capsys) -> None:
    """The first 6 s of the calibration drive turn in place: the mount's yaw is named, not fitted,
    and the written file keeps the believed mount; a file without the transform exits 2."""
    pytest.importorskip("rosbags")
    from test_pod_calibration import tags_camera

    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.tools import ekf_calibrate
    from sim_robot.ros.sim_bag import JOINT_STATES, demo_world_config, write_sim_bag

    world = tags_camera(demo_world_config())
    world = dataclasses.replace(world, camera=dataclasses.replace(world.camera, pose_of_camera=True,
                                                                  mount_pose=(0.0, 0.0, 0.035)))
    bag = write_sim_bag(tmp_path / "bag", 6.0, seed=1, world_config=world, drive="calibration",
                        topics=("/imu/data", "/camera/pose", JOINT_STATES))
    out = tmp_path / "cal.yaml"
    argv = [str(bag), "--params", str(mount_params(tmp_path)), "--out", str(out), "--bootstrap", "0"]
    assert ekf_calibrate.main(argv) == 0
    text = capsys.readouterr().out
    assert "static_transforms[base_link camera_link].yaw: not observable from these drives" in text
    assert "static_transforms[base_link camera_link] (the camera mount of pose0): not fitted" in text
    assert parameters_from_yaml(out)["static_transforms"] == ["0 0 0 0 0 0 base_link camera_link"]
    argv[2] = str(mount_params(tmp_path, static=False))
    assert ekf_calibrate.main(argv) == 2
    err = capsys.readouterr().err
    assert "pose0_pose_frame is camera_link, but neither static_transforms nor" in err
    assert "Traceback" not in err


def test_static_transforms_wins_over_a_mount_on_tf_static(tmp_path) -> None:
    """ekf_node keeps its static_transforms over /tf_static (the buffer pins them; a bag recorded
    while ekf_node ran holds its own old value there): so does the calibration. Without the
    entry, the bag's /tf_static gives the mount (and the report warns, above)."""
    pytest.importorskip("rosbags")
    tf2_msgs = pytest.importorskip("tf2_msgs.msg")
    from geometry_msgs.msg import TransformStamped
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from ekf_localization.core.angles import rpy_to_quaternion
    from ekf_localization.models.registry import MODELS
    from ekf_localization.ros.ekf_parameters import load_ekf_config
    from ekf_localization.tools.ekf_calibrate_mount import TF_STATIC, camera_mount

    tf = TransformStamped()
    tf.header.frame_id, tf.child_frame_id = "base_link", "camera_link"
    tf.transform.translation.x, tf.transform.translation.z = 0.1, 0.2
    q = rpy_to_quaternion(0.0, 0.0, 0.05)
    tf.transform.rotation.x, tf.transform.rotation.y, tf.transform.rotation.z, tf.transform.rotation.w = q
    bag = tmp_path / "tf_bag"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        store = get_typestore(Stores.ROS2_JAZZY)
        conn = w.add_connection(TF_STATIC, "tf2_msgs/msg/TFMessage", typestore=store)
        w.write(conn, 1, serialize_message(tf2_msgs.TFMessage(transforms=[tf])))
    config = load_ekf_config(mount_params(tmp_path), MODELS)
    mount = camera_mount(config, [bag], ["/camera/pose"])
    assert mount.source == "static_transforms" and mount.xyz_ypr == (0.0,) * 6
    config = load_ekf_config(mount_params(tmp_path, static=False), MODELS)
    mount = camera_mount(config, [bag], ["/camera/pose"])
    assert mount.source == TF_STATIC and mount.input_name == "pose0"
    np.testing.assert_allclose(mount.xyz_ypr, (0.1, 0.0, 0.2, 0.05, 0.0, 0.0), atol=1e-12)
