"""Offline replay over real bag files: MCAP, sqlite3 and ROS 1 give the same estimates."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from helpers.images import assert_plot_png
from helpers.ros_helpers import REPO
from rclpy.serialization import serialize_message
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from ekf_localization.tools import bag_io
from ekf_localization.tools.bag_replay import main
from ekf_localization.tools.evaluation import rmse
from ekf_localization.tools.replay import load_settings, replay
from sim_robot.ros import sim_messages
from sim_robot.world.camera_sensor import CameraReading
from sim_robot.world.dead_wheel_sensor import DeadWheelReading
from sim_robot.world.imu_sensor import ImuReading
from sim_robot.world.world import TruthReading, World

TYPES = {
    "/odometry/dead_wheels": "nav_msgs/msg/Odometry",
    "/camera/pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/imu/data": "sensor_msgs/msg/Imu",
    "/ground_truth/odom": "nav_msgs/msg/Odometry",
    "/cmd_vel": "geometry_msgs/msg/Twist",
}


def simulated_messages(duration_s: float = 6.0) -> list[tuple[str, int, bytes]]:
    """(topic, receive time ns, CDR bytes) of a simulated drive, in receive order."""
    from geometry_msgs.msg import Twist

    from seed_experiments.experiments.shipped_consistency import shipped_configs

    world = World(shipped_configs()[1], n_trials=1, seed=3)  # config/sim.yaml: ekf.yaml's drive
    world.reset(np.array(START))
    out: list[tuple[str, int, bytes]] = []
    step_ns = 20_000_000  # a new command every 20 ms
    for k in range(int(duration_s * 1e9) // step_ns):
        t = k * step_ns * 1e-9
        cmd = np.array([0.4 + 0.2 * math.sin(0.7 * t), 0.15 * math.cos(0.5 * t), 0.5 * math.sin(0.4 * t)])
        world.set_command(cmd)
        tw = Twist()
        tw.linear.x, tw.linear.y, tw.angular.z = (float(v) for v in cmd)
        out.append(("/cmd_vel", world.t_ns, serialize_message(tw)))
        for r in world.advance(step_ns):
            if isinstance(r, TruthReading):
                msg = sim_messages.ground_truth(r, r.stamp_ns, "map", "base_link")
                out.append(("/ground_truth/odom", r.stamp_ns, serialize_message(msg)))
            elif isinstance(r, DeadWheelReading):
                msg = sim_messages.dead_wheel_odometry(r, r.stamp_ns, "odom", "base_link")
                out.append(("/odometry/dead_wheels", r.stamp_ns, serialize_message(msg)))
            elif isinstance(r, ImuReading):
                msg = sim_messages.imu(r, r.stamp_ns, "base_link")
                out.append(("/imu/data", r.stamp_ns, serialize_message(msg)))
            elif isinstance(r, CameraReading) and r.visible[0]:
                msg = sim_messages.camera_pose(r, r.stamp_ns, "map")
                out.append(("/camera/pose", r.arrival_ns, serialize_message(msg)))
    return out


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    msgs = simulated_messages()
    root = tmp_path_factory.mktemp("bags")
    ts2 = get_typestore(Stores.ROS2_JAZZY)
    paths = {}
    for storage, plugin in (("mcap", StoragePlugin.MCAP), ("sqlite3", StoragePlugin.SQLITE3)):
        path = root / storage
        with Writer(path, version=9, storage_plugin=plugin) as w:
            conns = {t: w.add_connection(t, ty, typestore=ts2) for t, ty in TYPES.items()}
            for topic, t, data in msgs:
                w.write(conns[topic], t, data)
        paths[storage] = path
    ts1 = get_typestore(Stores.ROS1_NOETIC)
    path = root / "drive.bag"
    with Writer1(path) as w:
        conns = {t: w.add_connection(t, ty, typestore=ts1) for t, ty in TYPES.items()}
        for topic, t, data in msgs:
            w.write(conns[topic], t, ts2.cdr_to_ros1(data, TYPES[topic]))
    paths["ros1"] = path
    return paths


START = (-0.5, -0.6, 0.3)  # x, y, yaw of the simulated drive


@pytest.fixture(scope="module")
def config():
    """config/ekf.yaml, told where the robot starts (as set_pose would on a real robot)."""
    x0 = [START[0], START[1], 0.0, 0.0, 0.0, START[2]] + [0.0] * 9
    return load_settings(REPO / "config" / "ekf.yaml", overrides=[f"initial_state={x0}"])


def test_all_formats_give_identical_estimates(bags, config):
    results = {name: replay(path, config, "grid") for name, path in bags.items()}
    ref = results["mcap"].trajectory()
    assert len(ref) > 200
    assert np.all(np.isfinite(ref.states)) and np.all(np.isfinite(ref.covariances))
    sq = results["sqlite3"].trajectory()
    np.testing.assert_array_equal(sq.t_ns, ref.t_ns)
    np.testing.assert_array_equal(sq.states, ref.states)
    # A ROS 1 bag may order messages with equal receive times differently (same stamps,
    # other fusion order): equal to rounding.
    r1 = results["ros1"].trajectory()
    np.testing.assert_array_equal(r1.t_ns, ref.t_ns)
    np.testing.assert_allclose(r1.states, ref.states, rtol=0, atol=1e-9)


def test_replay_tracks_truth_better_than_dead_reckoning(bags, config):
    res = replay(bags["mcap"], config, "grid")
    truth = bag_io.read_odometry(bags["mcap"], "/ground_truth/odom")
    dead = bag_io.read_odometry(bags["mcap"], "/odometry/dead_wheels")
    ekf = rmse(res.trajectory(), truth)
    dr = rmse(dead, truth)
    assert ekf["xy"] < 0.05, ekf  # metres, over a 6 s drive with camera fixes
    assert ekf["xy"] < dr["xy"], (ekf, dr)
    assert ekf["theta"] < 0.15 and ekf["vx"] < 0.05, ekf
    assert ekf["vtheta"] < 0.05, ekf  # config/sim.yaml's truth jitter on the yaw rate is small
    assert res.localizer.stats["pose0"].applied > 10


def test_replay_command_line_writes_outputs(bags, tmp_path, capsys):
    out = tmp_path / "replay"
    assert main([str(bags["mcap"]), "--params", str(REPO / "config" / "ekf.yaml"), "--grid",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "RMSE against /ground_truth/odom" in text and "replayed EKF" in text
    lines = (out / "filtered.csv").read_text().splitlines()
    assert lines[0].startswith("stamp_ns,x_m,y_m,yaw_rad")
    assert len(lines) > 200
    assert_plot_png(out / "trajectory.png", 880, 880)  # report.py: 8 x 8 in at 110 dpi
    assert_plot_png(out / "errors.png", 1100, 715)  # 10 x 6.5 in at 110 dpi
    replayed = bag_io.read_odometry(out / "filtered_bag", "/odometry/filtered")
    assert len(replayed) == len(lines) - 1
    assert np.all(np.isfinite(replayed.states))


def test_bad_parameter_override_is_reported(bags, tmp_path, capsys):
    rc = main([str(bags["mcap"]), "--set", "frequency=-3.0", "--out", str(tmp_path)])
    assert rc == 2
    assert "frequency" in capsys.readouterr().err


IMU_MOUNT = (0.05, -0.02, 0.03, math.pi / 2, 0.0, math.pi)  # x y z yaw pitch roll: turned and upside down


def _imu_in_imu_link(data: bytes) -> bytes:
    """The same IMU reading as an IMU mounted at IMU_MOUNT in imu_link would report it."""
    from rclpy.serialization import deserialize_message
    from scipy.spatial.transform import Rotation
    from sensor_msgs.msg import Imu

    m = deserialize_message(data, Imu)
    x, y, z, yaw, pitch, roll = IMU_MOUNT
    R_bs = Rotation.from_euler("ZYX", [yaw, pitch, roll])
    q = m.orientation
    q_s = (Rotation.from_quat([q.x, q.y, q.z, q.w]) * R_bs).as_quat()  # R_ref,s = R_ref,b · R_bs
    m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = (float(v) for v in q_s)
    Rt = R_bs.inv().as_matrix()
    for vec, cov_name in ((m.angular_velocity, "angular_velocity_covariance"),
                          (m.linear_acceleration, "linear_acceleration_covariance")):
        vec.x, vec.y, vec.z = (float(v) for v in Rt @ [vec.x, vec.y, vec.z])
        C = np.asarray(getattr(m, cov_name), dtype=float).reshape(3, 3)
        setattr(m, cov_name, (Rt @ C @ Rt.T).ravel())
    m.header.frame_id = "imu_link"
    return serialize_message(m)


def _tf_static_mount() -> bytes:
    from geometry_msgs.msg import TransformStamped
    from scipy.spatial.transform import Rotation
    from tf2_msgs.msg import TFMessage

    x, y, z, yaw, pitch, roll = IMU_MOUNT
    tf = TransformStamped()
    tf.header.frame_id, tf.child_frame_id = "base_link", "imu_link"
    tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = x, y, z
    qx, qy, qz, qw = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat()
    r = tf.transform.rotation
    r.x, r.y, r.z, r.w = float(qx), float(qy), float(qz), float(qw)
    return serialize_message(TFMessage(transforms=[tf]))


def test_imu_in_its_own_frame_with_the_mount_in_tf_static_gives_the_same_estimate(tmp_path, config):
    """Done-when of issue 12: the IMU in imu_link, its mounting only in the bag's /tf_static
    (recorded last, as a late recorder may): the replay equals the one with the IMU in base_link."""
    msgs = simulated_messages(3.0)
    ts2 = get_typestore(Stores.ROS2_JAZZY)
    paths = {}
    for name in ("base_link", "imu_link"):
        path = tmp_path / name
        types = dict(TYPES, **({"/tf_static": "tf2_msgs/msg/TFMessage"} if name == "imu_link" else {}))
        with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
            conns = {t: w.add_connection(t, ty, typestore=ts2) for t, ty in types.items()}
            for topic, t, data in msgs:
                if name == "imu_link" and topic == "/imu/data":
                    data = _imu_in_imu_link(data)
                w.write(conns[topic], t, data)
            if name == "imu_link":
                w.write(conns["/tf_static"], msgs[-1][1] + 1, _tf_static_mount())
        paths[name] = path
    ref = replay(paths["base_link"], config, "grid")
    mounted = replay(paths["imu_link"], config, "grid")
    assert mounted.localizer.stats["imu0"].rejected_total == ref.localizer.stats["imu0"].rejected_total == 0
    assert mounted.localizer.stats["imu0"].applied == ref.localizer.stats["imu0"].applied > 100
    a, b = ref.trajectory(), mounted.trajectory()
    assert np.array_equal(a.t_ns, b.t_ns) and len(a) > 100
    assert np.allclose(a.states, b.states, atol=1e-9, rtol=0)
    assert np.allclose(a.covariances, b.covariances, atol=1e-12, rtol=1e-9)
    # without the /tf_static message, every IMU message is rejected as no_transform
    path = tmp_path / "no_tf"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {t: w.add_connection(t, ty, typestore=ts2) for t, ty in TYPES.items()}
        for topic, t, data in msgs:
            w.write(conns[topic], t, _imu_in_imu_link(data) if topic == "/imu/data" else data)
    st = replay(path, config, "grid").localizer.stats["imu0"]
    assert st.applied == 0 and st.rejected["no_transform"] == 2 * st.received
