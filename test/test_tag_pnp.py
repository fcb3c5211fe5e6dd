"""Multi-tag PnP (vision/tag_pnp.py): Jacobian, noiseless accuracy, NEES of the covariance, rejections."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from ekf_localization.core.angles import wrap_angle
from ekf_localization.vision import tag_pnp
from ekf_localization.vision.corner_noise import CornerNoise
from ekf_localization.vision.detection import TagDetection
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import tag_layout_from_dict

pytest.importorskip("cv2")

SIZE = 0.165
LAYOUT = tag_layout_from_dict({
    "field": {"length": 3.6576, "width": 3.6576},
    "tags": [{"id": 1, "size": SIZE, "position": [0.0, 1.4, 0.30], "yaw": 0.0},
             {"id": 2, "size": SIZE, "position": [0.0, 1.9, 0.35], "yaw": 0.0},
             {"id": 3, "size": SIZE, "position": [0.0, 2.4, 0.25], "yaw": 0.3}]})
CAMERA = PinholeCamera.from_fov(640, 480, math.radians(70.0))
# base_link <- camera optical: 10 cm ahead, 25 cm up, looking along base +x (z_opt = x_base,
# x_opt = -y_base, y_opt = -z_base), pitched up 5 degrees
MOUNT = tag_pnp.pose_matrix([0.10, 0.02, 0.25, 0.0, -math.radians(5.0), 0.0])
MOUNT[:3, :3] = MOUNT[:3, :3] @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _detections(pose: np.ndarray, ids: tuple[int, ...], rng: np.random.Generator | None = None,
                pixel_std: float = 0.0) -> list[TagDetection]:
    """The layout corners of ``ids`` projected from robot pose ``pose``, with pixel noise."""
    T_wc = tag_pnp.pose_matrix(pose) @ MOUNT
    out = []
    for i in ids:
        X = LAYOUT.tags[i].corners_map()
        Xc = (X - T_wc[:3, 3]) @ T_wc[:3, :3]
        uv = CAMERA.project(Xc)
        assert np.all(Xc[:, 2] > 0) and np.all((uv >= 0) & (uv < [640, 480])), "tag out of view"
        if rng is not None:
            uv = uv + rng.normal(0.0, pixel_std, uv.shape)
        out.append(TagDetection(i, uv))
    return out


def _error(fix: tag_pnp.TagFix, truth: np.ndarray) -> np.ndarray:
    e = fix.pose - truth
    e[3:] = (e[3:] + math.pi) % (2 * math.pi) - math.pi
    return e


def test_jacobian_matches_central_differences() -> None:
    pose = np.array([1.3, 1.7, 0.02, 0.03, -0.04, math.pi - 0.2])
    problem, _ = tag_pnp.build_problem(_detections(pose, (1, 2)), LAYOUT, CAMERA, MOUNT)
    guess = pose + np.array([0.05, -0.03, 0.01, 0.02, 0.01, -0.05])
    _, J = tag_pnp.residuals_and_jacobian(problem, guess)
    num = np.empty_like(J)
    for k in range(6):
        d = np.zeros(6)
        d[k] = 1e-6
        rp, _ = tag_pnp.residuals_and_jacobian(problem, guess + d)
        rm, _ = tag_pnp.residuals_and_jacobian(problem, guess - d)
        num[:, k] = (rp - rm) / 2e-6
    np.testing.assert_allclose(J, num, rtol=1e-6, atol=1e-4 * np.abs(num).max())


@pytest.mark.parametrize("yaw_off", [math.radians(20.0), math.radians(-35.0)])
def test_single_tag_at_1_5_m_without_noise(yaw_off: float) -> None:
    # camera 1.5 m from a 16.5 cm tag, seen obliquely
    c = np.array([1.5 * math.cos(yaw_off), 1.4 + 1.5 * math.sin(yaw_off)])
    yaw = math.atan2(1.4 - c[1], -c[0])
    truth = np.array([c[0] - 0.1 * math.cos(yaw), c[1] - 0.1 * math.sin(yaw), 0.0, 0.0, 0.0, yaw])
    fix, unknown = tag_pnp.localize(_detections(truth, (1,)), LAYOUT, CAMERA, MOUNT, CornerNoise(0.5),
                                    max_ambiguity=1.0)
    assert isinstance(fix, tag_pnp.TagFix) and unknown == ()
    e = _error(fix, truth)
    assert np.linalg.norm(e[:3]) < 0.01
    assert np.all(np.abs(e[3:]) < math.radians(0.5))
    assert fix.reprojection_rms < 1e-6


def test_multi_tag_without_noise_is_exact() -> None:
    truth = np.array([1.6, 1.8, 0.0, 0.0, 0.0, math.pi + 0.1])
    fix, _ = tag_pnp.localize(_detections(truth, (1, 2, 3)), LAYOUT, CAMERA, MOUNT, CornerNoise(0.5))
    assert isinstance(fix, tag_pnp.TagFix) and fix.tag_ids == (1, 2, 3) and fix.ambiguity == 0.0
    np.testing.assert_allclose(_error(fix, truth), 0.0, atol=1e-7)


@pytest.mark.parametrize(("ids", "offset", "max_ambiguity"),
                         [((1, 2, 3), 0.0, 0.2), ((1,), 0.6, 0.2)])
def test_nees_of_noisy_fixes_is_in_its_chi2_band(ids: tuple[int, ...], offset: float,
                                                 max_ambiguity: float) -> None:
    """The covariance is honest: mean NEES of the accepted fixes over seeded trials inside
    chi2(6 n)/n's 99 % band (n accepted). One tag 1.5 m away, 22 degrees off its axis: the
    ambiguity gate drops the frames where IPPE's two solutions fit about equally well (with
    the gate off, 15 of 300 fixes take the mirrored tilt and the mean NEES is ~900)."""
    rng = np.random.default_rng(33)
    pixel_std, trials = 0.5, 300
    nees = []
    for _ in range(trials):
        target = LAYOUT.tags[ids[len(ids) // 2]].pose_in_map[1, 3]
        c = np.array([1.5, target + offset]) + rng.normal(0, 0.05, 2)
        yaw = math.atan2(target - c[1], -c[0]) + rng.normal(0, 0.03)
        truth = np.array([c[0] - 0.1 * math.cos(yaw), c[1] - 0.1 * math.sin(yaw), 0.0,
                          rng.normal(0, 0.01), rng.normal(0, 0.01), yaw])
        fix, _ = tag_pnp.localize(_detections(truth, ids, rng, pixel_std), LAYOUT, CAMERA,
                                  MOUNT, CornerNoise(pixel_std), max_ambiguity=max_ambiguity)
        if isinstance(fix, tag_pnp.TagRejection):
            assert len(ids) == 1 and fix.reason == tag_pnp.AMBIGUOUS
            continue
        e = _error(fix, truth)
        nees.append(float(e @ np.linalg.solve(fix.covariance, e)))
    n = len(nees)
    assert n >= (trials if len(ids) > 1 else 50)
    lo, hi = chi2.ppf([0.005, 0.995], 6 * n) / n
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi, n)


def test_rejections_unknown_ambiguous_off_field() -> None:
    truth = np.array([1.6, 1.8, 0.0, 0.0, 0.0, math.pi])
    dets = _detections(truth, (1, 2))
    fix, unknown = tag_pnp.localize([TagDetection(99, dets[0].corners)], LAYOUT, CAMERA, MOUNT,
                                    CornerNoise(0.5))
    assert isinstance(fix, tag_pnp.TagRejection) and fix.reason == tag_pnp.NO_LAYOUT_TAGS
    assert unknown == (99,)
    fix, unknown = tag_pnp.localize(dets + [TagDetection(42, dets[0].corners)], LAYOUT, CAMERA,
                                    MOUNT, CornerNoise(0.5))
    assert isinstance(fix, tag_pnp.TagFix) and unknown == (42,)
    # a single tag seen head-on from far with noise: the two IPPE solutions fit about equally
    far = np.array([3.4, 1.4, 0.0, 0.0, 0.0, math.pi])
    rng = np.random.default_rng(1)
    fix, _ = tag_pnp.localize(_detections(far, (1,), rng, 1.0), LAYOUT, CAMERA, MOUNT, CornerNoise(1.0),
                              max_ambiguity=0.2)
    assert isinstance(fix, tag_pnp.TagRejection) and fix.reason == tag_pnp.AMBIGUOUS
    # a layout whose tags the robot sees from behind the wall: the fix lies off the field
    moved = tag_layout_from_dict({"field": {"length": 1.0, "width": 3.6576},
                                  "tags": [{"id": 1, "size": SIZE, "position": [0.0, 1.4, 0.3],
                                            "yaw": 0.0},
                                           {"id": 2, "size": SIZE, "position": [0.0, 1.9, 0.35],
                                            "yaw": 0.0}]})
    fix, _ = tag_pnp.localize(dets, moved, CAMERA, MOUNT, CornerNoise(0.5))
    assert isinstance(fix, tag_pnp.TagRejection) and fix.reason == tag_pnp.OFF_FIELD


def _forward_mount(pitch_down: float = 0.0, yaw: float = 0.0, at=(0.2, -0.1, 0.3)) -> np.ndarray:
    """base_link <- optical for a camera at ``at`` looking along base yaw ``yaw``, pitched down."""
    optical_in_level = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    cp, sp = math.cos(pitch_down), math.sin(pitch_down)
    pitch = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # about +y: x tips down
    cy, sy = math.cos(yaw), math.sin(yaw)
    yaw_m = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = yaw_m @ pitch @ optical_in_level
    T[:3, 3] = at
    return T


@pytest.mark.parametrize("pitch_down", [0.0, 0.35])
@pytest.mark.parametrize("yaw", [0.0, 2.5])
def test_floor_wedge_spans_the_horizontal_field_of_view(pitch_down: float, yaw: float) -> None:
    """The edge rays of a level camera are ±hfov/2 about its axis; pitched down by p they widen
    to ±atan(tan(hfov/2) / cos p) on the floor (the ray (±tan(hfov/2), 0, 1) keeps its sideways
    part while its forward part shrinks by cos p). Left is +y of the camera's heading."""
    hfov = math.radians(70.0)
    cam = PinholeCamera.from_fov(640, 480, hfov)
    wedge = cam.floor_wedge(_forward_mount(pitch_down, yaw), reach=2.0)
    assert wedge.shape == (3, 2)
    np.testing.assert_allclose(wedge[1], [0.2, -0.1], atol=1e-12)
    half = math.atan(math.tan(hfov / 2) / math.cos(pitch_down))
    left, right = wedge[0] - wedge[1], wedge[2] - wedge[1]
    np.testing.assert_allclose(np.hypot(*left), 2.0, rtol=1e-12)
    np.testing.assert_allclose(np.hypot(*right), 2.0, rtol=1e-12)
    assert math.isclose(math.atan2(left[1], left[0]), wrap_angle(yaw + half), abs_tol=1e-9)
    assert math.isclose(math.atan2(right[1], right[0]), wrap_angle(yaw - half), abs_tol=1e-9)


def test_floor_wedge_with_a_vertical_edge_ray_is_none() -> None:
    """A camera looking straight down whose principal point is on the image's left edge: that
    edge's ray is the optical axis, vertical, with no direction on the floor."""
    T = np.eye(4)
    T[:3, :3] = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]  # optical z down
    assert PinholeCamera(640, 480, 500.0, 500.0, -0.5, 239.5).floor_wedge(T, 2.0) is None
    assert PinholeCamera(640, 480, 500.0, 500.0, 319.5, 239.5).floor_wedge(T, 2.0) is not None
