"""message_to_measurement, the one conversion of an input message (ekf_node's and the bag tools').

Checked for each input kind: the record's values, covariances (row-major), frames and stamp
(integer ns, exact for a 2025 wall-clock stamp); the same record from the rclpy message and
from the rosbags message a bag reader gives; and the messages that cannot be fused: fields
that do not read as the kind's raise one of UNREADABLE_ERRORS (counted as unreadable), and
non-finite values and covariances of the wrong size or shape are rejected by the Localizer
with their reasons.
"""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("rclpy")
from geometry_msgs.msg import PoseWithCovarianceStamped, Twist, TwistStamped, TwistWithCovarianceStamped  # noqa: E402
from helpers.localizer_scenario import ekf_config  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402

from ekf_localization.core.angles import rpy_to_quaternion  # noqa: E402
from ekf_localization.core.measurements import (  # noqa: E402
    REJECT_COVARIANCE,
    REJECT_NONFINITE,
    REJECT_UNREADABLE,
    ImuMeasurement,
    JointStateMeasurement,
    OdometryMeasurement,
    PoseMeasurement,
    TwistMeasurement,
)
from ekf_localization.models.registry import make_localizer  # noqa: E402
from ekf_localization.ros.conversions import (  # noqa: E402
    MESSAGE_TYPES,
    UNREADABLE_ERRORS,
    control_from_message,
    message_class,
    message_to_measurement,
)

SEC = 1_000_000_000
BIG_SEC = 1_763_000_000  # float seconds would lose the nanoseconds of such a stamp
STAMP_NS = BIG_SEC * SEC + 123_456_789


def _stamp(msg) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = BIG_SEC, 123_456_789


def _spd(n: int, seed: int) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


def _orient(q, rpy: tuple[float, float, float]) -> None:
    q.x, q.y, q.z, q.w = rpy_to_quaternion(*rpy)


def _odometry() -> Odometry:
    m = Odometry()
    _stamp(m)
    m.header.frame_id, m.child_frame_id = "odom", "base_link"
    p = m.pose.pose
    p.position.x, p.position.y, p.position.z = 1.5, -2.25, 0.1
    _orient(p.orientation, (0.01, -0.02, 2.5))
    m.pose.covariance = _spd(6, 1).ravel()
    t = m.twist.twist
    t.linear.x, t.linear.y, t.angular.z = 0.7, -0.1, -0.4
    m.twist.covariance = _spd(6, 2).ravel()
    return m


def _pose() -> PoseWithCovarianceStamped:
    m = PoseWithCovarianceStamped()
    _stamp(m)
    m.header.frame_id = "map"
    m.pose.pose.position.x, m.pose.pose.position.y = 3.0, 0.5
    _orient(m.pose.pose.orientation, (0.0, 0.0, -1.2))
    m.pose.covariance = _spd(6, 3).ravel()
    return m


def _twist() -> TwistWithCovarianceStamped:
    m = TwistWithCovarianceStamped()
    _stamp(m)
    m.header.frame_id = "base_link"
    m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.angular.z = 0.25, 0.05, 0.3
    m.twist.covariance = _spd(6, 4).ravel()
    return m


def _imu() -> Imu:
    m = Imu()
    _stamp(m)
    m.header.frame_id = "imu_link"
    _orient(m.orientation, (0.1, 0.2, -1.0))
    m.orientation_covariance = _spd(3, 5).ravel()
    m.angular_velocity.x, m.angular_velocity.z = 0.01, 0.5
    m.angular_velocity_covariance = _spd(3, 6).ravel()
    m.linear_acceleration.x, m.linear_acceleration.z = 0.3, 9.80665
    m.linear_acceleration_covariance = [-1.0] + [0.0] * 8  # "not provided"
    return m


def _joint() -> JointState:
    m = JointState()
    _stamp(m)
    m.name = ["left", "right", "strafe"]
    m.position = [0.5, -1.25, 3.0]
    m.velocity = [0.1, 0.2, -0.3]
    return m


MESSAGES = {"odom": _odometry, "pose": _pose, "twist": _twist, "imu": _imu, "joint": _joint}


def _rosbags(kind: str, msg):
    """The message as a bag reader (rosbags) gives it."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    raw = bytes(serialize_message(msg))
    name = MESSAGE_TYPES[kind]
    try:
        return store.deserialize_cdr(raw, name)
    except Exception:  # rosbags refuses rclpy's trailing padding of some types (JointState)
        return store.deserialize_cdr(raw[:-4], name)


def test_odometry_record() -> None:
    m = _odometry()
    r = message_to_measurement("odom", m)
    assert isinstance(r, OdometryMeasurement)
    assert type(r.stamp_ns) is int and r.stamp_ns == STAMP_NS
    assert (r.frame_id, r.child_frame_id) == ("odom", "base_link")
    np.testing.assert_allclose(r.pose, [1.5, -2.25, 0.1, 0.01, -0.02, 2.5], atol=1e-12)
    np.testing.assert_array_equal(r.twist, [0.7, -0.1, 0.0, 0.0, 0.0, -0.4])
    np.testing.assert_array_equal(r.pose_covariance, _spd(6, 1))
    np.testing.assert_array_equal(r.twist_covariance, _spd(6, 2))
    assert [(p.name, p.frame_id) for p in r.parts()] == [("pose", "odom"), ("twist", "base_link")]


def test_pose_and_twist_records() -> None:
    p = message_to_measurement("pose", _pose())
    assert isinstance(p, PoseMeasurement)
    assert p.stamp_ns == STAMP_NS and p.frame_id == "map"
    np.testing.assert_allclose(p.pose, [3.0, 0.5, 0.0, 0.0, 0.0, -1.2], atol=1e-12)
    np.testing.assert_array_equal(p.covariance, _spd(6, 3))
    t = message_to_measurement("twist", _twist())
    assert isinstance(t, TwistMeasurement)
    assert t.stamp_ns == STAMP_NS and t.frame_id == "base_link"
    np.testing.assert_array_equal(t.twist, [0.25, 0.05, 0.0, 0.0, 0.0, 0.3])
    np.testing.assert_array_equal(t.covariance, _spd(6, 4))


def test_imu_record_flags_a_part_not_provided() -> None:
    r = message_to_measurement("imu", _imu())
    assert isinstance(r, ImuMeasurement)
    assert r.stamp_ns == STAMP_NS and r.frame_id == "imu_link"
    np.testing.assert_allclose(r.orientation, [0.1, 0.2, -1.0], atol=1e-12)
    np.testing.assert_array_equal(r.angular_velocity, [0.01, 0.0, 0.5])
    np.testing.assert_array_equal(r.linear_acceleration, [0.3, 0.0, 9.80665])
    np.testing.assert_array_equal(r.orientation_covariance, _spd(3, 5))
    np.testing.assert_array_equal(r.angular_velocity_covariance, _spd(3, 6))
    assert [(p.name, p.provided) for p in r.parts()] == [
        ("orientation", True), ("angular_velocity", True), ("linear_acceleration", False)]


def test_joint_state_record() -> None:
    r = message_to_measurement("joint", _joint())
    assert isinstance(r, JointStateMeasurement)
    assert r.stamp_ns == STAMP_NS and r.names == ("left", "right", "strafe")
    np.testing.assert_array_equal(r.positions, [0.5, -1.25, 3.0])
    np.testing.assert_array_equal(r.velocities, [0.1, 0.2, -0.3])
    assert r.efforts.shape == (0,)
    bare = _joint()
    bare.velocity = []
    assert message_to_measurement("joint", bare).velocities.shape == (0,)


def test_cmd_vel_twist_at_receipt_and_twist_stamped_at_its_stamp() -> None:
    t = Twist()
    t.linear.x, t.linear.y, t.angular.z = 0.5, 0.2, -0.3
    c = control_from_message(t, 42)
    assert c.stamp_ns == 42
    np.testing.assert_array_equal(c.twist, [0.5, 0.2, 0.0, 0.0, 0.0, -0.3])
    s = TwistStamped()
    _stamp(s)
    s.twist = t
    c = control_from_message(s, 42)
    assert c.stamp_ns == STAMP_NS
    np.testing.assert_array_equal(c.twist, [0.5, 0.2, 0.0, 0.0, 0.0, -0.3])


@pytest.mark.parametrize("kind", sorted(MESSAGES))
def test_a_bag_message_gives_the_same_record(kind: str) -> None:
    """bag_replay's path (rosbags' message) and ekf_node's (rclpy's) give equal records: the
    same types, every array float64, writable and bit for bit equal."""
    msg = MESSAGES[kind]()
    a, b = message_to_measurement(kind, msg), message_to_measurement(kind, _rosbags(kind, msg))
    assert type(a) is type(b)
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype == np.float64 and x.flags.writeable and y.flags.writeable, f.name
            assert x.shape == y.shape and np.array_equal(x, y), f.name
        else:
            assert x == y and type(x) is type(y), f.name


@pytest.mark.parametrize("kind", sorted(MESSAGES))
def test_a_message_of_another_type_is_unreadable(kind: str) -> None:
    """Fields that do not read as the kind's (a Twist, a header without a stamp) raise one of
    UNREADABLE_ERRORS, which ekf_node and bag_replay count as unreadable_message."""
    with pytest.raises(UNREADABLE_ERRORS):
        message_to_measurement(kind, Twist())
    broken = MESSAGES[kind]()
    broken.header = SimpleNamespace(stamp=SimpleNamespace(sec="soon", nanosec=0), frame_id="odom")
    with pytest.raises(UNREADABLE_ERRORS):
        message_to_measurement(kind, broken)
    loc = make_localizer(ekf_config())
    loc.note_unreadable("odom0")
    assert loc.stats["odom0"].received == 1 and loc.stats["odom0"].rejected[REJECT_UNREADABLE] == 1


def _rejected(source: str, kind: str, msg) -> tuple:
    """(part, reason) of each part a fresh Localizer of config/ekf.yaml rejects."""
    loc = make_localizer(ekf_config())
    return loc.add_measurement(source, message_to_measurement(kind, msg), STAMP_NS).rejected


def test_good_messages_are_fused() -> None:
    for source, kind, msg in (("odom0", "odom", _odometry()), ("pose0", "pose", _pose())):
        assert _rejected(source, kind, msg) == (), source


def test_non_finite_values_are_rejected() -> None:
    m = _odometry()
    m.twist.twist.linear.x = math.nan
    assert ("twist", REJECT_NONFINITE) in _rejected("odom0", "odom", m)
    m = _odometry()
    cov = _spd(6, 2).ravel()
    cov[7] = math.inf
    m.twist.covariance = cov
    assert ("twist", REJECT_NONFINITE) in _rejected("odom0", "odom", m)
    p = _pose()
    p.pose.pose.orientation.x = p.pose.pose.orientation.y = 0.0
    p.pose.pose.orientation.z = p.pose.pose.orientation.w = 0.0  # no orientation: NaN yaw
    assert ("pose", REJECT_NONFINITE) in _rejected("pose0", "pose", p)


def test_covariances_of_the_wrong_size_or_shape_are_rejected() -> None:
    """A covariance of the wrong size (rclpy refuses one, a duck-typed or old bag message may
    carry one) reads as NaNs: nonfinite; a non-symmetric one: bad_covariance."""
    m = _rosbags("odom", _odometry())
    short = SimpleNamespace(header=m.header, child_frame_id=m.child_frame_id, pose=m.pose,
                            twist=SimpleNamespace(twist=m.twist.twist, covariance=np.ones(35)))
    r = message_to_measurement("odom", short)
    assert r.twist_covariance.shape == (6, 6) and np.isnan(r.twist_covariance).all()
    assert ("twist", REJECT_NONFINITE) in _rejected("odom0", "odom", short)
    m = _odometry()
    cov = _spd(6, 2)
    cov[0, 1] += 1.0
    m.twist.covariance = cov.ravel()
    assert ("twist", REJECT_COVARIANCE) in _rejected("odom0", "odom", m)


def test_message_class_of_each_kind() -> None:
    assert {k: message_class(k) for k in MESSAGES} == {
        "odom": Odometry, "pose": PoseWithCovarianceStamped, "twist": TwistWithCovarianceStamped,
        "imu": Imu, "joint": JointState}
