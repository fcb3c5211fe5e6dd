"""Frames in the ROS-free core: the transform buffer and measurements turned into base_link / world."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ekf_localization.core.angles import matrix_to_rpy, rpy_to_matrix
from ekf_localization.core.frames import (
    RigidTransform,
    TransformBuffer,
    pose_transform_jacobian,
    to_filter_frames,
    transform_orientation,
    transform_pose,
    transform_twist,
    twist_jacobian,
)
from ekf_localization.core.measurements import (
    REJECT_NO_TRANSFORM,
    ImuMeasurement,
    MeasurementPart,
    OdometryMeasurement,
    PoseMeasurement,
)
from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config

RNG = np.random.default_rng(12)


def _random_transform() -> RigidTransform:
    return RigidTransform(Rotation.random(random_state=RNG).as_matrix(), RNG.normal(size=3))


def _close(a: RigidTransform, b: RigidTransform) -> bool:
    return np.allclose(a.rotation, b.rotation, atol=1e-12) and np.allclose(a.translation, b.translation,
                                                                           atol=1e-12)


def test_static_transform_publisher_argument_order() -> None:
    """x y z yaw pitch roll: yaw 90° turns the child's x axis into the parent's y axis."""
    T = RigidTransform.from_xyz_ypr(1.0, 2.0, 3.0, math.pi / 2, 0.0, 0.0)
    assert np.allclose(T.rotation @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(T.translation, [1, 2, 3])
    T = RigidTransform.from_xyz_ypr(0.0, 0.0, 0.0, 0.3, -0.2, 0.1)
    assert np.allclose(matrix_to_rpy(T.rotation), [0.1, -0.2, 0.3])


def test_buffer_chains_inverts_and_reports_gaps() -> None:
    buf = TransformBuffer()
    T_bp, T_pi, T_bc = _random_transform(), _random_transform(), _random_transform()
    buf.set_static("base_link", "plate", T_bp)
    buf.set_static("/plate", "imu_link", T_pi)  # a leading slash is the same frame (tf2)
    buf.set_static("base_link", "camera", T_bc)
    assert _close(buf.lookup("base_link", "imu_link"), T_bp.compose(T_pi))
    assert _close(buf.lookup("imu_link", "base_link"), T_bp.compose(T_pi).inverse())
    assert _close(buf.lookup("camera", "imu_link"), T_bc.inverse().compose(T_bp).compose(T_pi))
    assert buf.lookup("base_link", "laser") is None
    assert buf.lookup("imu_link", "imu_link").is_identity()
    buf.set_static("plate", "imu_link", RigidTransform())  # a change replaces the cached chain
    assert _close(buf.lookup("base_link", "imu_link"), T_bp)


def test_buffer_interpolates_dynamic_links() -> None:
    buf = TransformBuffer()
    buf.add("odom", "base_link", RigidTransform.from_xyz_ypr(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 1 * SEC)
    buf.add("odom", "base_link", RigidTransform.from_xyz_ypr(2.0, 0.0, 0.0, 1.0, 0.0, 0.0), 2 * SEC)
    mid = buf.lookup("odom", "base_link", 1 * SEC + SEC // 4)
    assert np.allclose(mid.translation, [0.5, 0, 0])
    assert matrix_to_rpy(mid.rotation)[2] == pytest.approx(0.25)
    assert buf.lookup("odom", "base_link", SEC // 2) is None  # before the first sample
    latest = buf.lookup("odom", "base_link", 5 * SEC)  # after the newest: the newest (as RL)
    assert np.allclose(latest.translation, [2, 0, 0])
    assert np.allclose(buf.lookup("odom", "base_link", 0).translation, [2, 0, 0])


def test_buffer_keeps_at_most_max_frames_of_each_kind() -> None:
    """1000 distinct /tf child frames (issue 35, case 6) leave max_frames links, the newest, and
    never push out a static link: the camera mount still resolves."""
    buf = TransformBuffer(max_frames=8)
    mount = _random_transform()
    buf.set_static("base_link", "camera", mount)
    for k in range(1000):
        buf.add("map", f"junk_{k}", RigidTransform(), SEC + k)
    assert len(buf) == 8 + 1 and buf.evictions == 1000 - 8
    assert buf.lookup("map", "junk_0") is None and buf.lookup("map", "junk_999") is not None
    assert _close(buf.lookup("base_link", "camera"), mount)
    buf.add("map", "junk_992", RigidTransform(), 2 * SEC)  # updated: now the newest
    buf.add("map", "fresh", RigidTransform(), 2 * SEC)
    assert buf.lookup("map", "junk_992") is not None and buf.lookup("map", "junk_993") is None


def test_twist_lever_arm_matches_rigid_body_motion() -> None:
    """A sensor at r on a body moving with (v_b, ω) sees v_s = Rᵀ(v_b + ω × r), ω_s = Rᵀω."""
    T_bs = _random_transform()
    R, r = T_bs.rotation, T_bs.translation
    v_b, w_b = RNG.normal(size=3), RNG.normal(size=3)
    twist_s = np.concatenate([R.T @ (v_b + np.cross(w_b, r)), R.T @ w_b])
    out, cov = transform_twist(twist_s, np.eye(6) * 1e-4, T_bs)
    assert np.allclose(out, np.concatenate([v_b, w_b]))
    # the form v_base = R·(v_s − ω_s × r_s), r_s the lever arm in the sensor's axes
    v_s, w_s = twist_s[:3], twist_s[3:]
    assert np.allclose(out[:3], R @ (v_s - np.cross(w_s, R.T @ r)))
    J = twist_jacobian(T_bs)
    assert np.allclose(cov, J @ (np.eye(6) * 1e-4) @ J.T)
    eps = 1e-6  # J is the exact derivative of the (linear) map
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        fd = (transform_twist(twist_s + d, np.eye(6), T_bs)[0] - out) / eps
        assert np.allclose(fd, J[:, k], atol=1e-6)


def _pose6(T: RigidTransform) -> np.ndarray:
    return np.concatenate([T.translation, matrix_to_rpy(T.rotation)])


def test_sensor_pose_becomes_base_pose() -> None:
    T_wb, T_bs, T_wf = _random_transform(), _random_transform(), _random_transform()
    T_fs = T_wf.inverse().compose(T_wb).compose(T_bs)  # the sensor's pose in frame f
    out, _ = transform_pose(_pose6(T_fs), np.eye(6), T_wf, T_bs)
    assert np.allclose(out[:3], T_wb.translation)
    assert np.allclose(rpy_to_matrix(*out[3:]), T_wb.rotation)


def test_pose_transform_jacobian_matches_finite_differences() -> None:
    """Perturb T_fs by (δp, exp([δθ]×)) on the left; T_wb moves by J·δ in (position, fixed-axis rotation)."""
    T_wf, T_fs, T_bs = _random_transform(), _random_transform(), _random_transform()
    J = pose_transform_jacobian(T_wf, T_fs, T_bs)
    base = T_wf.compose(T_fs).compose(T_bs.inverse())
    eps = 1e-7
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        Tk = RigidTransform(Rotation.from_rotvec(d[3:]).as_matrix() @ T_fs.rotation, T_fs.translation + d[:3])
        moved = T_wf.compose(Tk).compose(T_bs.inverse())
        dp = (moved.translation - base.translation) / eps
        dth = Rotation.from_matrix(moved.rotation @ base.rotation.T).as_rotvec() / eps
        assert np.allclose(np.concatenate([dp, dth]), J[:, k], atol=1e-5), k
    C = np.diag([1e-4, 2e-4, 3e-4, 1e-3, 2e-3, 3e-3])
    _, cov = transform_pose(_pose6(T_fs), C, T_wf, T_bs)
    assert np.allclose(cov, J @ C @ J.T) and np.allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_imu_mounted_rotated() -> None:
    """An IMU turned 90° about z (and lifted): heading, yaw rate and acceleration of base_link."""
    T_bs = RigidTransform.from_xyz_ypr(0.1, 0.0, 0.05, math.pi / 2, 0.0, 0.0)
    # base_link heads 0.4 rad: the IMU (turned +90° on it) reports 0.4 + π/2
    assert transform_orientation(np.array([0.0, 0.0, 0.4 + math.pi / 2]), T_bs)[2] == pytest.approx(0.4)
    part = MeasurementPart("angular_velocity", 9, "imu_link", np.array([0.0, 0.0, 0.7]), np.eye(3) * 1e-4)
    out, _ = to_filter_frames(part, 0, lambda a, b, t: T_bs, "map", "base_link", "")
    assert np.allclose(out.values, [0, 0, 0.7]) and out.frame_id == "base_link"
    acc = MeasurementPart("linear_acceleration", 12, "imu_link", np.array([1.0, 0.0, 9.8]),
                          np.diag([1e-2, 2e-2, 3e-2]))
    out, _ = to_filter_frames(acc, 0, lambda a, b, t: T_bs, "map", "base_link", "")
    assert np.allclose(out.values, [0, 1, 9.8]) and np.allclose(np.diag(out.covariance), [2e-2, 1e-2, 3e-2])


def test_nan_in_a_field_the_transform_does_not_mix_in_stays_out() -> None:
    T_bs = RigidTransform.from_xyz_ypr(0.2, 0.1, 0.0, 0.5, 0.0, 0.0)  # yaw-only mount, planar offset
    twist = np.array([0.5, 0.1, math.nan, math.nan, math.nan, 0.3])  # vz, wx, wy unknown
    out, cov = transform_twist(twist, np.diag([1e-4, 1e-4, math.nan, math.nan, math.nan, 1e-4]), T_bs)
    assert np.all(np.isfinite(out[[0, 1, 5]])) and np.all(np.isfinite(cov[np.ix_([0, 1, 5], [0, 1, 5])]))


def _config(**overrides):
    v = {"odom0": "odom", "odom0_config": [False] * 6 + [True, True, False, False, False, True] + [False] * 3,
         "imu0": "imu", "imu0_config": [False] * 5 + [True] + [False] * 5 + [True] + [False] * 3,
         "pose0": "camera/pose", "pose0_config": [True, True, False, False, False, True] + [False] * 9,
         "world_frame": "map"}
    v.update(overrides)
    return parse_ekf_config(v, MODELS)


def _imu(stamp: int, yaw: float, rate: float, frame: str) -> ImuMeasurement:
    return ImuMeasurement(stamp, frame, np.array([0.0, 0.0, yaw]), np.eye(3) * 1e-4,
                          np.array([0.0, 0.0, rate]), np.eye(3) * 1e-4, np.zeros(3), np.eye(3))


def test_a_pinned_link_is_kept_over_messages_for_its_frame() -> None:
    """The static_transforms parameter's links are pinned: a /tf_static or /tf message for the
    same child (a recorded copy of an older value, another node's) neither replaces nor evicts it."""
    buf = TransformBuffer(max_frames=2)
    mount = _random_transform()
    buf.set_static("base_link", "camera", mount, pinned=True)
    buf.set_static("base_link", "camera", _random_transform())
    buf.set_static("odom", "camera", RigidTransform())
    buf.add("map", "camera", RigidTransform(), SEC)
    for k in range(5):
        buf.set_static("base_link", f"static_{k}", RigidTransform())
    assert _close(buf.lookup("base_link", "camera"), mount) and buf.lookup("map", "camera") is None
    other = _random_transform()  # the parameter itself may set it again (a new params file)
    buf.set_static("base_link", "camera", other, pinned=True)
    assert _close(buf.lookup("base_link", "camera"), other)


def test_localizer_uses_static_transforms_and_rejects_missing_ones_once() -> None:
    warnings: list[str] = []  # the parameter in static_transform_publisher's order
    loc = make_localizer(_config(static_transforms=[f"0.1 0 0 {math.pi / 2} 0 0 base_link imu_link"]),
                         warn=warnings.append)
    ref = make_localizer(_config())
    for k in range(5):
        t = SEC + k * 10_000_000
        assert loc.add_measurement("imu0", _imu(t, 0.3 + math.pi / 2, 0.2, "imu_link"), t).applied
        ref.add_measurement("imu0", _imu(t, 0.3, 0.2, "base_link"), t)
    assert np.allclose(loc.committed().state, ref.committed().state, atol=1e-12)
    # a frame with no transform: rejected, counted, logged once naming the transform
    for k in range(3):
        t = 2 * SEC + k * 10_000_000
        res = loc.add_measurement("imu0", _imu(t, 0.0, 0.0, "imu_other"), t)
        assert res.rejected and all(r == REJECT_NO_TRANSFORM for _, r in res.rejected)
    assert loc.stats["imu0"].rejected[REJECT_NO_TRANSFORM] == 6  # orientation and angular velocity
    named = [w for w in warnings if "imu_other" in w]
    assert len(named) == 1 and "base_link <- imu_other" in named[0]


def test_camera_pose_measured_at_the_camera() -> None:
    """A pose of camera_link in map: the filter gets base_link's pose."""
    cam = (0.2, -0.1, 0.3, 0.5, 0.0, 0.0)
    loc = make_localizer(_config(static_transforms=[" ".join(map(str, cam)) + " base_link camera_link"],
                                 pose0_pose_frame="camera_link"))
    T_wb = RigidTransform.from_xyz_ypr(1.0, 2.0, 0.0, 0.7, 0.0, 0.0)
    T_ws = T_wb.compose(RigidTransform.from_xyz_ypr(*cam))
    res = loc.add_measurement("pose0", PoseMeasurement(SEC, "map", _pose6(T_ws), np.eye(6) * 1e-6), SEC)
    assert res.applied == ("pose",)
    x = loc.committed().state
    assert x[0] == pytest.approx(1.0, abs=1e-4) and x[1] == pytest.approx(2.0, abs=1e-4)
    assert x[2] == pytest.approx(0.7, abs=1e-4)


def test_zero_variance_is_floored_counted_and_warned_once() -> None:
    """diff_drive_controller's all-zero covariances: fused with the floor, not dropped."""
    warnings: list[str] = []
    loc = make_localizer(_config(zero_variance_floor=1e-6), warn=warnings.append)
    for k in range(3):
        t = SEC + k * 10_000_000
        m = OdometryMeasurement(t, "odom", "base_link", np.zeros(6), np.zeros((6, 6)),
                                np.array([0.5, 0, 0, 0, 0, 0.1]), np.zeros((6, 6)))
        assert loc.add_measurement("odom0", m, t).applied == ("twist",)
    assert loc.stats["odom0"].zero_variances_floored == 3
    assert len([w for w in warnings if "zero variance" in w and "1e-06" in w]) == 1
    assert loc.committed().state[3] == pytest.approx(0.5, abs=1e-6)


def test_odometry_pose_of_its_child_frame() -> None:
    """odomN_pose_use_child_frame (RL): the pose is of child_frame_id (here base_footprint, 5 cm below)."""
    odom_config = [True, True, False, False, False, True] + [False] * 9
    loc = make_localizer(_config(odom0_config=odom_config, odom0_pose_use_child_frame=True,
                                 world_frame="odom",
                                 static_transforms=["0.1 0 -0.05 0 0 0 base_link base_footprint"]))
    m = OdometryMeasurement(SEC, "odom", "base_footprint", np.array([1.1, 0.0, 0.0, 0.0, 0.0, 0.0]),
                            np.eye(6) * 1e-6, np.zeros(6), np.eye(6))
    assert loc.add_measurement("odom0", m, SEC).applied == ("pose",)
    assert loc.committed().state[0] == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize("bad", [["1 2 3 base_link imu_link"], ["0 0 0 0 0 0 a a"], "base_link",
                                 ["0 0 0 x 0 0 a b"]])
def test_bad_static_transforms_name_the_parameter(bad) -> None:
    from ekf_localization.ros.parameters import ParameterError

    with pytest.raises(ParameterError, match="static_transforms.*x y z yaw pitch roll parent child"):
        _config(static_transforms=bad)
