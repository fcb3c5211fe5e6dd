"""Messages <-> measurements: the same readers on rclpy and on rosbags-deserialized messages."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ekf_localization.core.angles import quaternion_to_rpy
from ekf_localization.core.localizer import Estimate
from ekf_localization.core.units import ns_to_sec_nanosec, stamp_to_ns
from ekf_localization.inputs import imu as imu_kind
from ekf_localization.inputs import odom as odom_kind
from ekf_localization.inputs import pose as pose_kind
from ekf_localization.inputs import twist as twist_kind
from ekf_localization.ros.conversions import (
    PLANAR_FIXED_VARIANCE,
    estimate_to_odometry,
    map_to_odom,
    message_to_measurement,
    odometry_arrays,
    transform_stamped,
    transform_to_planar,
    twist_to_control,
)

pytest.importorskip("rclpy")
from geometry_msgs.msg import PoseWithCovarianceStamped, Twist, TwistWithCovarianceStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402

BIG_SEC = 1_763_000_000  # a 2025 wall-clock stamp: float seconds would lose the nanoseconds
RNG = np.random.default_rng(11)


def _rosbags(msg, type_name: str):
    """What a bag reader gives for ``msg``: CDR bytes deserialized by rosbags."""
    return get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(serialize_message(msg), type_name)


def _quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def _sym(n: int) -> np.ndarray:
    A = RNG.normal(size=(n, n))
    return A @ A.T + n * np.eye(n)


def test_stamps_are_exact_integer_nanoseconds() -> None:
    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = BIG_SEC, 999_999_999
    assert stamp_to_ns(msg.header.stamp) == BIG_SEC * 1_000_000_000 + 999_999_999
    assert ns_to_sec_nanosec(BIG_SEC * 1_000_000_000 + 1) == (BIG_SEC, 1)
    assert ns_to_sec_nanosec(-1) == (-1, 999_999_999)


def test_quaternion_to_rpy_inverts_rpy_to_quaternion() -> None:
    for _ in range(200):
        r, p, y = RNG.uniform(-math.pi, math.pi), RNG.uniform(-1.5, 1.5), RNG.uniform(-math.pi, math.pi)
        q = np.array(_quat(r, p, y)) * RNG.uniform(0.5, 2.0)  # need not be normalised
        np.testing.assert_allclose(quaternion_to_rpy(*q), (r, p, y), atol=1e-9)
    assert all(math.isnan(v) for v in quaternion_to_rpy(0.0, 0.0, 0.0, 0.0))


def _odometry() -> Odometry:
    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = BIG_SEC, 123_456_789
    msg.header.frame_id = "odom"
    msg.child_frame_id = "base_link"
    p = msg.pose.pose
    p.position.x, p.position.y, p.position.z = 1.5, -2.25, 0.1
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = _quat(0.01, -0.02, 2.5)
    msg.pose.covariance = _sym(6).ravel().tolist()
    t = msg.twist.twist
    t.linear.x, t.linear.y, t.linear.z = 0.7, -0.1, 0.0
    t.angular.x, t.angular.y, t.angular.z = 0.0, 0.0, -0.4
    msg.twist.covariance = _sym(6).ravel().tolist()
    return msg


def test_odometry_from_rclpy_and_from_a_bag_are_identical() -> None:
    msg = _odometry()
    a = odom_kind.read(msg)
    b = message_to_measurement("odom", _rosbags(msg, "nav_msgs/msg/Odometry"))
    assert a.stamp_ns == b.stamp_ns == BIG_SEC * 1_000_000_000 + 123_456_789
    assert (a.frame_id, a.child_frame_id) == (b.frame_id, b.child_frame_id) == ("odom", "base_link")
    for f in ("pose", "pose_covariance", "twist", "twist_covariance"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    np.testing.assert_allclose(a.pose, [1.5, -2.25, 0.1, 0.01, -0.02, 2.5], atol=1e-12)
    np.testing.assert_array_equal(a.twist, [0.7, -0.1, 0.0, 0.0, 0.0, -0.4])
    np.testing.assert_array_equal(a.pose_covariance.ravel(), msg.pose.covariance)


def test_pose_twist_imu_from_rclpy_and_from_a_bag_are_identical() -> None:
    pose = PoseWithCovarianceStamped()
    pose.header.stamp.sec, pose.header.stamp.nanosec = 12, 5
    pose.header.frame_id = "map"
    pose.pose.pose.position.x = 3.0
    pose.pose.pose.orientation.z, pose.pose.pose.orientation.w = math.sin(0.3), math.cos(0.3)
    pose.pose.covariance = _sym(6).ravel().tolist()
    twist = TwistWithCovarianceStamped()
    twist.header.stamp.sec = 13
    twist.header.frame_id = "base_link"
    twist.twist.twist.linear.x = 0.25
    twist.twist.covariance = _sym(6).ravel().tolist()
    imu = Imu()
    imu.header.stamp.nanosec = 77
    imu.header.frame_id = "base_link"
    imu.orientation.x, imu.orientation.y, imu.orientation.z, imu.orientation.w = _quat(0.1, 0.2, -1.0)
    imu.orientation_covariance = _sym(3).ravel().tolist()
    imu.angular_velocity.z = 0.5
    imu.angular_velocity_covariance = _sym(3).ravel().tolist()
    imu.linear_acceleration.x, imu.linear_acceleration.z = 0.3, 9.80665
    imu.linear_acceleration_covariance = [-1.0] + [0.0] * 8
    for msg, kind, type_name, read in [
            (pose, "pose", "geometry_msgs/msg/PoseWithCovarianceStamped", pose_kind.read),
            (twist, "twist", "geometry_msgs/msg/TwistWithCovarianceStamped", twist_kind.read),
            (imu, "imu", "sensor_msgs/msg/Imu", imu_kind.read)]:
        a, b = read(msg), message_to_measurement(kind, _rosbags(msg, type_name))
        assert a.stamp_ns == b.stamp_ns and a.frame_id == b.frame_id
        for pa, pb in zip(a.parts(), b.parts(), strict=True):
            np.testing.assert_array_equal(pa.values, pb.values)
            np.testing.assert_array_equal(pa.covariance, pb.covariance)
            assert pa.provided == pb.provided
    m = imu_kind.read(imu)
    np.testing.assert_allclose(m.orientation, [0.1, 0.2, -1.0], atol=1e-12)
    assert [p.provided for p in m.parts()] == [True, True, False]
    assert pose_kind.read(pose).stamp_ns == 12_000_000_005
    np.testing.assert_allclose(pose_kind.read(pose).pose[5], 0.6)


def test_cmd_vel_is_stamped_on_receipt() -> None:
    t = Twist()
    t.linear.x, t.linear.y, t.angular.z = 0.5, 0.2, -0.3
    c = twist_to_control(t, 42)
    assert c.stamp_ns == 42
    np.testing.assert_array_equal(c.twist, [0.5, 0.2, 0, 0, 0, -0.3])


def test_estimate_to_odometry_fills_both_6x6_covariances() -> None:
    fields = (0, 1, 5, 6, 7, 11)
    P = _sym(6) * 1e-3
    est = Estimate(BIG_SEC * 1_000_000_000 + 1, np.array([1.0, 2.0, -2.0, 0.3, -0.2, 0.1]), P, fields)
    msg = estimate_to_odometry(est, "map", "base_link")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (BIG_SEC, 1)
    assert (msg.header.frame_id, msg.child_frame_id) == ("map", "base_link")
    back = odom_kind.read(msg)
    np.testing.assert_allclose(back.pose[[0, 1, 5]], [1.0, 2.0, -2.0], atol=1e-12)
    np.testing.assert_array_equal(back.twist[[0, 1, 5]], [0.3, -0.2, 0.1])
    pc, tc = back.pose_covariance, back.twist_covariance
    np.testing.assert_array_equal(pc[np.ix_([0, 1, 5], [0, 1, 5])], P[:3, :3])
    np.testing.assert_array_equal(tc[np.ix_([0, 1, 5], [0, 1, 5])], P[3:, 3:])
    for c in (pc, tc):
        np.testing.assert_array_equal(np.diag(c)[[2, 3, 4]], PLANAR_FIXED_VARIANCE)
        np.linalg.cholesky(c)
    # differential state [x y v yaw vyaw]: vy is not estimated
    est5 = Estimate(0, np.array([1.0, 2.0, 0.5, 0.3, 0.1]), np.eye(5) * 0.01, (0, 1, 6, 5, 11))
    back5 = odom_kind.read(estimate_to_odometry(est5, "odom", "base_link"))
    np.testing.assert_array_equal(back5.twist, [0.5, 0.0, 0.0, 0.0, 0.0, 0.1])
    assert back5.twist_covariance[1, 1] == PLANAR_FIXED_VARIANCE


def test_extras_outside_the_state_fill_their_fields_with_a_floored_variance() -> None:
    """A tilt input's z, roll and pitch (``est.extra``) take their fields, with their variance
    (never below PLANAR_FIXED_VARIANCE) and no correlation; the state's fields keep theirs."""
    fields = (0, 1, 5, 6, 7, 11)
    P = _sym(6) * 1e-3
    extra = ((2, 0.05, 0.01), (3, 0.02, 1e-4), (4, -0.01, 0.0))
    est = Estimate(0, np.array([1.0, 2.0, -2.0, 0.3, -0.2, 0.1]), P, fields, extra)
    pose, pc, twist, tc = odometry_arrays(est)
    np.testing.assert_array_equal(pose, [1.0, 2.0, 0.05, 0.02, -0.01, -2.0])
    np.testing.assert_array_equal(twist, [0.3, -0.2, 0.0, 0.0, 0.0, 0.1])
    np.testing.assert_array_equal(np.diag(pc)[2:5], [0.01, 1e-4, PLANAR_FIXED_VARIANCE])
    np.testing.assert_array_equal(pc[np.ix_([0, 1, 5], [0, 1, 5])], P[:3, :3])
    np.testing.assert_array_equal(tc[np.ix_([0, 1, 5], [0, 1, 5])], P[3:, 3:])
    off = ~np.eye(6, dtype=bool)
    assert not pc[2:5][off[2:5]].any() and not pc[:, 2:5][off[:, 2:5]].any()
    np.linalg.cholesky(pc)


def test_the_output_message_reads_back_from_a_bag_as_published() -> None:
    """What ekf_node publishes (estimate_to_odometry), as a bag records it and the bag tools read
    it (rosbags): the same numbers and frames, for a negative and a 2025 stamp."""
    from ekf_localization.tools.bag_io import odometry_state

    for stamp in (-1, BIG_SEC * 1_000_000_000 + 7):
        est = Estimate(stamp, RNG.normal(size=5), _sym(5) * 1e-3, (0, 1, 6, 5, 11))
        msg = estimate_to_odometry(est, "odom", "base_link")
        back = _rosbags(msg, "nav_msgs/msg/Odometry")
        assert (back.header.frame_id, back.child_frame_id) == ("odom", "base_link")
        assert stamp_to_ns(back.header.stamp) == stamp
        np.testing.assert_array_equal(back.pose.covariance, msg.pose.covariance)
        np.testing.assert_array_equal(back.twist.covariance, msg.twist.covariance)
        a, b = odom_kind.read(msg), odom_kind.read(back)
        np.testing.assert_array_equal(a.pose, b.pose)
        np.testing.assert_array_equal(a.twist, b.twist)
        assert odometry_state(back)[0] == stamp


def test_map_to_odom_composes_back_to_map_to_base() -> None:
    for _ in range(50):
        mb = (RNG.uniform(-3, 3), RNG.uniform(-3, 3), RNG.uniform(-math.pi, math.pi))
        ob = (RNG.uniform(-3, 3), RNG.uniform(-3, 3), RNG.uniform(-math.pi, math.pi))
        mo = map_to_odom(mb, ob)
        c, s = math.cos(mo[2]), math.sin(mo[2])
        composed = (mo[0] + c * ob[0] - s * ob[1], mo[1] + s * ob[0] + c * ob[1], mo[2] + ob[2])
        np.testing.assert_allclose(composed[:2], mb[:2], atol=1e-12)
        assert math.remainder(composed[2] - mb[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
        tf = transform_stamped(5, "map", "odom", mo)
        np.testing.assert_allclose(transform_to_planar(tf), mo, atol=1e-12)


@pytest.mark.parametrize("scale", [1e200, 1e-200])
def test_a_scaled_quaternion_in_a_message_is_fused_not_rejected(scale: float) -> None:
    """Issue 15, defect 7: an IMU or camera quaternion scaled by 1e200 or 1e-200 (its norm
    squared over- or underflows) gives the orientation, and the Localizer fuses it."""
    from helpers.localizer_scenario import SEC, ekf_config

    from ekf_localization.core.angles import yaw_to_quaternion
    from ekf_localization.models.registry import make_localizer

    yaw = 0.7
    q = [v * scale for v in yaw_to_quaternion(yaw)]
    imu = Imu()
    imu.header.stamp.sec, imu.header.frame_id = 5, "base_link"
    imu.orientation.x, imu.orientation.y, imu.orientation.z, imu.orientation.w = q
    imu.orientation_covariance = [1e-3, 0.0, 0.0, 0.0, 1e-3, 0.0, 0.0, 0.0, 1e-3]
    imu.angular_velocity_covariance = [1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-4]
    imu.linear_acceleration_covariance = [-1.0] + [0.0] * 8
    m = imu_kind.read(imu)
    assert m.orientation[2] == pytest.approx(yaw, abs=1e-12)
    pose = PoseWithCovarianceStamped()
    pose.header.stamp.sec, pose.header.frame_id = 5, "map"
    o = pose.pose.pose.orientation
    o.x, o.y, o.z, o.w = q
    pose.pose.covariance = list(np.diag([4e-4, 4e-4, 1e-6, 1e-6, 1e-6, 1e-3]).ravel())
    pm = pose_kind.read(pose)
    assert pm.pose[5] == pytest.approx(yaw, abs=1e-12)
    loc = make_localizer(ekf_config())
    assert "orientation" in loc.add_measurement("imu0", m, 5 * SEC).applied
    assert loc.add_measurement("pose0", pm, 5 * SEC).applied
    assert sum(loc.stats["imu0"].rejected.values()) == sum(loc.stats["pose0"].rejected.values()) == 0
