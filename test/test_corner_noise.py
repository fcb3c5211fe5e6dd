"""The corner noise model behind a tag fix's covariance (vision/corner_noise.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from ekf_localization.vision import tag_pnp
from ekf_localization.vision.corner_noise import CornerNoise, pose_covariance
from ekf_localization.vision.detection import TagDetection

pytest.importorskip("cv2")

from test_tag_pnp import CAMERA, LAYOUT, MOUNT, _detections  # noqa: E402

TRUTH = np.array([1.6, 1.9, 0.0, 0.0, 0.0, math.pi])
# the robot turning at 1.5 rad/s and driving 0.5 m/s: a few px of blur over 4 ms
VELOCITY = np.array([-0.5, 0.0, 0.0, 0.0, 0.0, 1.5])
NOISE = CornerNoise(pixel_std=0.1, tag_shift_std=0.15, blur_std_per_px=0.08, exposure_time=0.004,
                    unknown_motion_blur_px=4.0)


def _problem(ids: tuple[int, ...] = (1, 2, 3)) -> tag_pnp.PnPProblem:
    problem, _ = tag_pnp.build_problem(_detections(TRUTH, ids), LAYOUT, CAMERA, MOUNT)
    return problem


def test_independent_corners_give_the_gauss_newton_covariance() -> None:
    problem = _problem()
    _, J = tag_pnp.residuals_and_jacobian(problem, TRUTH)
    cov = tag_pnp.pose_covariance(problem, TRUTH, CornerNoise(0.7))
    np.testing.assert_allclose(cov, 0.49 * np.linalg.inv(J.T @ J), rtol=1e-9, atol=1e-15)


def test_tag_covariance_is_shared_shift_plus_blur_along_the_motion() -> None:
    cov = NOISE.tag_covariance(np.array([3.0, 4.0]))        # 5 px of blur along (0.6, 0.8)
    grown = (0.08 * 5.0) ** 2
    u = np.array([0.6, 0.8])
    own = 0.1**2 * np.eye(2) + grown * np.outer(u, u)
    shared = 0.15**2 * np.eye(2) + grown * np.outer(u, u)
    np.testing.assert_allclose(cov[:2, :2], own + shared)         # one corner
    np.testing.assert_allclose(cov[:2, 6:8], shared)              # two corners of one tag
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    across = np.array([-0.8, 0.6])
    assert across @ cov[:2, :2] @ across == pytest.approx(0.1**2 + 0.15**2)


def test_image_blur_is_the_corner_motion_over_the_exposure() -> None:
    problem = _problem((2,))
    blur = tag_pnp.image_blur(problem, TRUTH, VELOCITY, 0.004)
    before, _ = tag_pnp.residuals_and_jacobian(problem, TRUTH - 0.002 * VELOCITY)
    after, _ = tag_pnp.residuals_and_jacobian(problem, TRUTH + 0.002 * VELOCITY)
    np.testing.assert_allclose(blur[0], (after - before).reshape(4, 2).mean(axis=0))
    # turning left moves the scene right in the image (+u), by about fx * ω * t
    assert blur[0, 0] == pytest.approx(CAMERA.fx * 1.5 * 0.004, rel=0.3)
    assert abs(blur[0, 1]) < 0.1 * blur[0, 0]


def test_pose_velocity_from_the_previous_fix() -> None:
    pose = np.array([1.0, 2.0, 0.0, 0.0, 0.0, -math.pi + 0.05])
    before = np.array([0.99, 2.0, 0.0, 0.0, 0.0, math.pi - 0.05])
    v = tag_pnp.pose_velocity(pose, 1_050_000_000, (1_000_000_000, before), 250_000_000)
    np.testing.assert_allclose(v, [0.2, 0.0, 0.0, 0.0, 0.0, 2.0], atol=1e-9)   # yaw wrapped
    assert tag_pnp.pose_velocity(pose, 1_300_000_000, (1_000_000_000, before), 250_000_000) is None
    assert tag_pnp.pose_velocity(pose, 1_000_000_000, (1_000_000_000, before), 250_000_000) is None
    assert tag_pnp.pose_velocity(pose, 1_000_000_000, None, 250_000_000) is None


def test_fixes_under_the_modelled_noise_are_consistent_and_the_iid_model_is_not() -> None:
    """Corners drawn from the model (shared shift + blur): the 6-D NEES of the fixes with the
    model's covariance lies in χ²(6N)/N's 99 % band; the independent-corner covariance with the
    same per-corner std (what the model was before) is overconfident, far above it."""
    rng = np.random.default_rng(7)
    problem = _problem()
    true_uv = problem.image_points.reshape(-1)
    sigma = NOISE.corner_covariance(tag_pnp.image_blur(problem, TRUTH, VELOCITY, NOISE.exposure_time))
    L = np.linalg.cholesky(sigma)
    per_corner_std = math.sqrt(np.mean(np.diag(sigma)))
    trials, nees_model, nees_iid = 300, [], []
    for _ in range(trials):
        uv = (true_uv + L @ rng.standard_normal(true_uv.size)).reshape(-1, 4, 2)
        dets = [TagDetection(i, c) for i, c in zip(problem.tag_ids, uv, strict=True)]
        noisy, _ = tag_pnp.build_problem(dets, LAYOUT, CAMERA, MOUNT)
        pose, _ = tag_pnp.refine(noisy, TRUTH)
        e = pose - TRUTH
        cov = tag_pnp.pose_covariance(noisy, pose, NOISE, VELOCITY)
        iid = tag_pnp.pose_covariance(noisy, pose, CornerNoise(per_corner_std))
        nees_model.append(e @ np.linalg.solve(cov, e))
        nees_iid.append(e @ np.linalg.solve(iid, e))
    lo, hi = chi2.ppf([0.005, 0.995], 6 * trials) / trials
    assert lo < np.mean(nees_model) < hi, (np.mean(nees_model), lo, hi)
    assert np.mean(nees_iid) > 2 * hi


def test_a_fit_whose_residual_fails_its_check_gets_a_wider_covariance() -> None:
    problem = _problem()
    r, J = tag_pnp.residuals_and_jacobian(problem, TRUTH)
    sigma = CornerNoise(0.1).corner_covariance(np.zeros((3, 2)))
    plain = pose_covariance(J, r, sigma)                                   # r = 0: no scaling
    np.testing.assert_allclose(plain, 0.01 * np.linalg.inv(J.T @ J), rtol=1e-9, atol=1e-15)
    rng = np.random.default_rng(3)
    small = 0.1 * rng.standard_normal(r.size)                             # as the model says
    assert np.array_equal(pose_covariance(J, small - J @ np.linalg.lstsq(J, small, rcond=None)[0],
                                          sigma), plain)
    big = small.copy()
    big[4] += 3.0                                                          # one corner 3 px off
    big -= J @ np.linalg.lstsq(J, big, rcond=None)[0]                      # what the fit leaves
    H = J @ np.linalg.solve(J.T @ J, J.T)
    ratio = (big @ big) / np.trace((np.eye(r.size) - H) @ sigma)
    np.testing.assert_allclose(pose_covariance(J, big, sigma), ratio * plain, rtol=1e-9)
    assert ratio > 10


def test_unknown_motion_assumes_the_model_blur_along_the_rows() -> None:
    problem = _problem((1, 2))
    unknown = tag_pnp.pose_covariance(problem, TRUTH, NOISE, None)
    still = tag_pnp.pose_covariance(problem, TRUTH, NOISE, np.zeros(6))
    rows = tag_pnp.pose_covariance(problem, TRUTH, CornerNoise(0.1, 0.15, 0.08, 0.0), None)
    assert np.trace(unknown) > np.trace(still)
    np.testing.assert_allclose(rows, tag_pnp.pose_covariance(problem, TRUTH, NOISE, np.zeros(6)))
