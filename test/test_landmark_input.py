"""The landmark input kind (ekf_localization/inputs/landmark.py): range and bearing to a known
landmark, a kind added as one module and one registry line.

Checked: h and its analytic Jacobian against central differences; the bearing residual wraps
across ±π; bad observations are rejected with their reason; the parameters (required position,
variances) fail at start naming the parameter; the Localizer fuses two landmarks into the
pose; and over DDS, ekf_node subscribes landmark0/landmark1 as geometry_msgs/PointStamped and
converges to the pose the observations imply.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.ros_helpers import node_command, running_process, spin_until, wait_for_subscribers

from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.measurements import REJECT_FRAME, REJECT_IMPLAUSIBLE, REJECT_NONFINITE
from ekf_localization.inputs import KINDS
from ekf_localization.inputs.landmark import LandmarkObservation, RangeBearing, RangeBearingMeasurement
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config, parse_ekf_settings
from ekf_localization.ros.parameters import ParameterError

LANDMARKS = ((3.0, 1.0), (-1.0, 2.5))
TRUE_POSE = (1.0, 0.5, 0.3)  # x m, y m, yaw rad
MS = 1_000_000


def _observed(landmark, pose=TRUE_POSE) -> np.ndarray:
    """The landmark in the robot's frame (what a detector on the robot reports)."""
    x, y, th = pose
    dx, dy = landmark[0] - x, landmark[1] - y
    c, s = math.cos(th), math.sin(th)
    return np.array([c * dx + s * dy, -s * dx + c * dy])


def test_jacobian_matches_central_differences() -> None:
    rng = np.random.default_rng(3)
    model = RangeBearingMeasurement(np.array([2.0, -1.0]), (0, 1, 2), 6)
    for _ in range(50):
        x = rng.normal(size=6)
        H = model.jacobian(x[None])[0]
        num = np.zeros_like(H)
        for j in range(6):
            e = np.zeros(6)
            e[j] = 1e-6
            d = model.h((x + e)[None])[0] - model.h((x - e)[None])[0]
            d[1] = wrap_angle(d[1])
            num[:, j] = d / 2e-6
        np.testing.assert_allclose(H, num, rtol=1e-6, atol=1e-7)  # central differences: O(h²) + eps/h


def test_bearing_of_the_observation_matches_h_and_wraps() -> None:
    fusion = RangeBearing(LANDMARKS[0], 0.01, 0.001)
    model, angles = fusion.measurement_model({0: 0, 1: 1, 5: 2, 6: 3, 7: 4, 11: 5}, 6)
    assert angles == (1,)
    z, R = fusion.fuse(LandmarkObservation(0, "base_link", _observed(LANDMARKS[0])), "base_link")
    x = np.array([*TRUE_POSE, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(model.h(x[None])[0], z, atol=1e-12)
    np.testing.assert_allclose(R, np.diag([0.01, 0.001]))
    behind = RangeBearingMeasurement(np.array([-1.0, 1e-9]), (0, 1, 2), 3)  # bearing ≈ π from heading 0
    assert behind.h(np.zeros((1, 3)))[0, 1] == pytest.approx(math.pi)


@pytest.mark.parametrize(("point", "frame", "reason"), [
    ((math.nan, 1.0), "base_link", REJECT_NONFINITE),
    ((1.0, 1.0), "camera_link", REJECT_FRAME),
    ((0.01, 0.0), "base_link", REJECT_IMPLAUSIBLE),
])
def test_bad_observations_are_rejected_with_their_reason(point, frame, reason) -> None:
    fusion = RangeBearing(LANDMARKS[0], 0.01, 0.001)
    assert fusion.fuse(LandmarkObservation(0, frame, np.array(point)), "base_link") == reason


def _diagonal15(values: dict[int, float]) -> list[float]:
    """A 15x15 diagonal matrix (RL field order) with ``values`` on its diagonal, row-major."""
    m = np.zeros((15, 15))
    for f, v in values.items():
        m[f, f] = v
    return m.ravel().tolist()


def _config(**extra):
    """Two landmarks, no other input; the pose starts at the origin, 2 m off (σ) in x and y."""
    p0 = _diagonal15({0: 4.0, 1: 4.0, 5: 1.0, 6: 1e-6, 7: 1e-6, 11: 1e-6})
    q = _diagonal15({0: 1e-6, 1: 1e-6, 5: 1e-6, 6: 1e-4, 7: 1e-4, 11: 1e-4})
    params = {"model": "mecanum", "world_frame": "map", "initial_estimate_covariance": p0,
              "process_noise_covariance": q,
              "landmark0": "landmark0/point", "landmark0_position": list(LANDMARKS[0]),
              "landmark1": "landmark1/point", "landmark1_position": list(LANDMARKS[1])}
    params.update(extra)
    return params


def test_parameters_need_the_position_and_positive_variances() -> None:
    params = _config()
    del params["landmark1_position"]
    with pytest.raises(ParameterError) as err:
        parse_ekf_config(params, MODELS)
    assert "landmark1_position" in str(err.value)
    with pytest.raises(ParameterError) as err:
        parse_ekf_config(_config(landmark0_range_variance=-1.0), MODELS)
    assert "landmark0_range_variance" in str(err.value)
    cfg = parse_ekf_config(_config(landmark0_rejection_threshold=4.0), MODELS)
    assert [i.kind for i in cfg.inputs] == ["landmark", "landmark"]
    assert cfg.inputs[0].threshold("range_bearing") == 4.0
    assert KINDS["landmark"].message_type == "geometry_msgs/msg/PointStamped"


def test_the_localizer_fuses_two_landmarks_into_the_pose() -> None:
    loc = make_localizer(parse_ekf_config(_config(), MODELS))
    rng = np.random.default_rng(0)
    sd_r, sd_b = 0.1, math.sqrt(0.001)
    for k in range(200):
        for name, lm in zip(("landmark0", "landmark1"), LANDMARKS, strict=True):
            p = _observed(lm)
            r, b = np.hypot(*p) + rng.normal(0.0, sd_r), math.atan2(p[1], p[0]) + rng.normal(0.0, sd_b)
            res = loc.add_measurement(name, LandmarkObservation((10 * k + 1) * MS, "base_link",
                                                                np.array([r * math.cos(b), r * math.sin(b)])))
            assert res.applied == ("range_bearing",), res
    est = loc.estimate_at(2000 * MS)
    x, y, th = est.state[:3]
    P = est.covariance[:3, :3]
    err = np.array([x - TRUE_POSE[0], y - TRUE_POSE[1], wrap_angle(th - TRUE_POSE[2])])
    assert float(err @ np.linalg.solve(P, err)) < 16.27  # χ²(3) at 0.999
    assert np.hypot(*err[:2]) < 0.05  # 400 fixes of 0.1 m each: a few cm at most
    assert loc.nis["landmark0/range_bearing"][1] == 200


@pytest.mark.ros
def test_ekf_node_fuses_landmarks_over_dds(ros_context, tmp_path: Path) -> None:
    """ekf_node takes landmark0/landmark1 (geometry_msgs/PointStamped) with no edit but the
    registry line, and its estimate converges to the pose the observations imply."""
    from geometry_msgs.msg import PointStamped
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data

    params = _config(frequency=50.0, publish_tf=False)
    path = tmp_path / "ekf.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    node = Node("landmark_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    outputs: list[Odometry] = []
    node.create_subscription(Odometry, "odometry/filtered", outputs.append, 100)
    pubs = [node.create_publisher(PointStamped, f"landmark{i}/point", qos_profile_sensor_data)
            for i in (0, 1)]
    log = tmp_path / "ekf.log"
    try:
        cmd = node_command("ekf_node") + ["--ros-args", "--params-file", str(path)]
        with running_process(cmd, log) as proc:
            for pub in pubs:
                assert wait_for_subscribers(ex, pub, timeout=60.0), log.read_text()
            msg = PointStamped()
            msg.header.frame_id = "base_link"

            def publish_all() -> bool:
                for pub, lm in zip(pubs, LANDMARKS, strict=True):
                    msg.header.stamp = node.get_clock().now().to_msg()
                    msg.point.x, msg.point.y = (float(v) for v in _observed(lm))
                    pub.publish(msg)
                spin_until(ex, lambda: False, 0.02)
                return False

            for _ in range(100):
                publish_all()
            assert spin_until(ex, lambda: len(outputs) > 5 or publish_all(), 20.0), log.read_text()
            last = outputs[-1].pose.pose
            yaw = 2.0 * math.atan2(last.orientation.z, last.orientation.w)
            assert last.position.x == pytest.approx(TRUE_POSE[0], abs=0.02), log.read_text()
            assert last.position.y == pytest.approx(TRUE_POSE[1], abs=0.02)
            assert wrap_angle(yaw - TRUE_POSE[2]) == pytest.approx(0.0, abs=0.02)
            assert proc.poll() is None and "Traceback" not in log.read_text()
    finally:
        ex.shutdown()
        node.destroy_node()


def test_bag_replay_reads_and_fuses_landmarks(tmp_path: Path) -> None:
    """bag_replay takes the new kind from its registry line too: a rosbag2 (MCAP) file of
    PointStamped observations replays into the pose they imply."""
    pytest.importorskip("rosbags")
    from geometry_msgs.msg import PointStamped
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from ekf_localization.tools.replay import replay

    bag = tmp_path / "landmarks"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = [w.add_connection(f"/landmark{i}/point", "geometry_msgs/msg/PointStamped",
                                  typestore=get_typestore(Stores.ROS2_JAZZY)) for i in (0, 1)]
        for k in range(1, 101):
            for conn, lm in zip(conns, LANDMARKS, strict=True):
                msg = PointStamped()
                msg.header.frame_id = "base_link"
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(20 * k * MS, 1_000_000_000)
                msg.point.x, msg.point.y = (float(v) for v in _observed(lm))
                w.write(conn, 20 * k * MS + 1 * MS, serialize_message(msg))
    result = replay(bag, parse_ekf_settings(_config(), MODELS), output_stamps="grid")
    x, y, th = result.estimates[-1].state[:3]
    assert (x, y) == (pytest.approx(TRUE_POSE[0], abs=0.01), pytest.approx(TRUE_POSE[1], abs=0.01))
    assert wrap_angle(th - TRUE_POSE[2]) == pytest.approx(0.0, abs=0.01)
