"""The tag_corners input kind (inputs/tag_corners.py): a tag's corner pixels fused directly.

Checked: h against the PnP module's projection; the analytic Jacobian against central
differences; bad observations rejected with their reason; the parameters (required corners
and intrinsics) fail naming the parameter; the Localizer fuses two tags' corners into the pose;
R is the corner noise model's (blur from the estimate) or the diagonal; the residual check
widens R by NIS / m above χ²(8)'s 0.99 quantile, before the gate, and counts it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers import tag_images

from ekf_localization.core.ekf import ExtendedKalmanFilter
from ekf_localization.core.linear import LinearMeasurement, LinearProcessModel
from ekf_localization.core.measurements import REJECT_FRAME, REJECT_IMPLAUSIBLE, REJECT_NONFINITE
from ekf_localization.core.outcomes import Estimate
from ekf_localization.inputs import KINDS
from ekf_localization.inputs.tag_corners import TagCornerObservation, TagCorners, camera_rotation_translation
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError
from ekf_localization.vision.corner_noise import RESIDUAL_CHECK_MASS, CornerNoise

CAM = tag_images.CAMERA
CAMERA = (CAM.fx, CAM.fy, CAM.cx, CAM.cy)
MOUNT = tag_images.MOUNT_XYZ_RPY
TRUTH = np.array([1.6, 1.8, math.pi + 0.1])          # x, y, yaw
FIELDS = {0: 0, 1: 1, 5: 2, 6: 3, 7: 4, 11: 5}        # mecanum: x y yaw vx vy vyaw


def _fusion(tag_id: int, **extra) -> TagCorners:
    corners = tuple(tag_images.LAYOUT.tags[tag_id].corners_map().reshape(-1))
    return TagCorners(corners, CAMERA, MOUNT, extra.get("pixel_variance", 1.0), extra.get("frame", ""))


def _pose6(x: np.ndarray) -> np.ndarray:
    return np.array([x[0], x[1], 0.0, 0.0, 0.0, x[2]])


def test_h_is_the_projection_of_the_pnp_scene() -> None:
    model, angles = _fusion(2).measurement_model(FIELDS, 6)
    assert angles == ()
    x = np.array([*TRUTH, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(model.h(x[None])[0], tag_images.project_tag(_pose6(TRUTH), 2).reshape(-1),
                               atol=1e-9)
    R_bc, _ = camera_rotation_translation(MOUNT)
    np.testing.assert_allclose(R_bc, tag_images.mount()[:3, :3], atol=1e-12)


def test_jacobian_matches_central_differences() -> None:
    rng = np.random.default_rng(4)
    model, _ = _fusion(3).measurement_model(FIELDS, 6)
    for _ in range(30):
        x = np.array([*TRUTH, 0.0, 0.0, 0.0]) + rng.normal(0, [0.2, 0.2, 0.15, 1, 1, 1])
        H = model.jacobian(x[None])[0]
        num = np.zeros_like(H)
        for j in range(6):
            e = np.zeros(6)
            e[j] = 1e-6
            num[:, j] = (model.h((x + e)[None])[0] - model.h((x - e)[None])[0]) / 2e-6
        np.testing.assert_allclose(H, num, rtol=1e-5, atol=1e-5 * np.abs(num).max())
        assert not H[:, 3:].any()


@pytest.mark.parametrize(("corners", "frame", "reason"), [
    (np.full((4, 2), math.nan), "camera_optical", REJECT_NONFINITE),
    (np.zeros((3, 2)), "camera_optical", REJECT_IMPLAUSIBLE),
    (np.zeros((4, 2)), "other_camera", REJECT_FRAME),
])
def test_bad_observations_are_rejected_with_their_reason(corners, frame, reason) -> None:
    fusion = _fusion(1, frame="camera_optical")
    assert fusion.fuse(TagCornerObservation(0, frame, corners), "base_link") == reason


def _params(**extra) -> dict:
    p0 = np.zeros((15, 15))
    q = np.zeros((15, 15))
    for f in (0, 1, 5):
        p0[f, f], q[f, f] = 0.09, 1e-6
    for f in (6, 7, 11):
        p0[f, f], q[f, f] = 1e-6, 1e-4
    params = {"model": "mecanum", "world_frame": "map", "initial_estimate_covariance": p0.ravel().tolist(),
              "process_noise_covariance": q.ravel().tolist()}
    for k, tag_id in enumerate((1, 2)):
        params[f"tag_corners{k}"] = f"tag_corners/tag_{tag_id}"
        params[f"tag_corners{k}_corners"] = tag_images.LAYOUT.tags[tag_id].corners_map().reshape(-1).tolist()
        params[f"tag_corners{k}_camera"] = list(CAMERA)
        params[f"tag_corners{k}_camera_mount"] = list(MOUNT)
    params.update(extra)
    return params


def test_parameters_need_corners_and_intrinsics() -> None:
    params = _params()
    del params["tag_corners1_camera"]
    with pytest.raises(ParameterError, match="tag_corners1_camera"):
        parse_ekf_config(params, MODELS)
    with pytest.raises(ParameterError, match="tag_corners0_corners"):
        parse_ekf_config(_params(tag_corners0_corners=[1.0, 2.0]), MODELS)
    assert "tag_corners" in KINDS


def test_localizer_fuses_two_tags_corners_into_the_pose() -> None:
    """Start 0.2 m and 0.1 rad off; noisy corners (1 px) of tags 1 and 2 at 10 Hz for 3 s."""
    config = parse_ekf_config(_params(initial_state=[TRUTH[0] - 0.2, TRUTH[1] + 0.15, 0.0, 0.0, 0.0,
                                                     TRUTH[2] - 0.1] + [0.0] * 9), MODELS)
    loc = make_localizer(config)
    rng = np.random.default_rng(8)
    stamp = 0
    for _ in range(30):
        stamp += 100_000_000
        for k, tag_id in enumerate((1, 2)):
            uv = tag_images.project_tag(_pose6(TRUTH), tag_id) + rng.normal(0, 1.0, (4, 2))
            result = loc.add_measurement(f"tag_corners{k}", TagCornerObservation(stamp, "camera_optical", uv),
                                         stamp)
            assert result.applied, result
    x = loc.estimate_at(stamp).state
    assert math.hypot(x[0] - TRUTH[0], x[1] - TRUTH[1]) < 0.02
    assert abs((x[2] - TRUTH[2] + math.pi) % (2 * math.pi) - math.pi) < 0.01


# --- R: the corner noise model's 8x8 covariance, or the diagonal ----------------------------------

NOISE = CornerNoise(0.10, 0.10, 0.05, 0.004, 4.0)   # config/tag_localizer.yaml's model


def _model_fusion(tag_id: int, noise: CornerNoise = NOISE, diagonal: bool = False) -> TagCorners:
    corners = tuple(tag_images.LAYOUT.tags[tag_id].corners_map().reshape(-1))
    return TagCorners(corners, CAMERA, MOUNT, 0.7, "", noise, diagonal)


def _estimate(pose: np.ndarray, velocity: np.ndarray) -> Estimate:
    """A mecanum estimate (x y yaw vx vy vyaw; RL fields 0 1 5 6 7 11), body velocity."""
    return Estimate(0, np.array([*pose, *velocity]), np.eye(6), (0, 1, 5, 6, 7, 11))


def test_r_is_the_corner_noise_models_covariance_with_the_estimates_blur() -> None:
    """The blur is the corners' mean motion over the exposure (the tag's projection at the
    pose -/+ half the exposure's motion, through the PnP scene's own projection)."""
    fusion = _model_fusion(2)
    uv = tag_images.project_tag(_pose6(TRUTH), 2)
    obs = TagCornerObservation(0, "camera_optical", uv)
    body = np.array([0.4, -0.2, 0.8])                   # vx, vy (base_link), yaw rate
    c, s = math.cos(TRUTH[2]), math.sin(TRUTH[2])
    world = np.array([c * body[0] - s * body[1], s * body[0] + c * body[1], body[2]])
    half = 0.5 * NOISE.exposure_time * world
    blur = (tag_images.project_tag(_pose6(TRUTH + half), 2)
            - tag_images.project_tag(_pose6(TRUTH - half), 2)).mean(axis=0)
    assert np.hypot(*blur) > 0.5                          # a blur the model grows R by
    z, R = fusion.fuse(obs, "base_link", _estimate(TRUTH, body))
    np.testing.assert_array_equal(z, uv.reshape(8))
    np.testing.assert_allclose(R, NOISE.tag_covariance(blur), rtol=1e-6, atol=1e-12)
    # no estimate (or none with a velocity): the model's unknown-motion blur; no exposure: none
    _, R_none = fusion.fuse(obs, "base_link", None)
    np.testing.assert_array_equal(R_none, NOISE.tag_covariance(NOISE.unknown_blurs(1)[0]))
    no_velocity = Estimate(0, TRUTH.copy(), np.eye(3), (0, 1, 5))
    np.testing.assert_array_equal(fusion.fuse(obs, "base_link", no_velocity)[1], R_none)
    still = dataclasses.replace(NOISE, exposure_time=0.0)
    _, R_still = _model_fusion(2, still).fuse(obs, "base_link", _estimate(TRUTH, body))
    np.testing.assert_array_equal(R_still, still.tag_covariance(np.zeros(2)))


def test_diagonal_covariance_is_pixel_variance_times_identity() -> None:
    obs = TagCornerObservation(0, "camera_optical", tag_images.project_tag(_pose6(TRUTH), 1))
    _, R = _model_fusion(1, diagonal=True).fuse(obs, "base_link", None)
    np.testing.assert_array_equal(R, 0.7 * np.eye(8))


def test_corner_noise_parameters_reach_the_fusion_and_are_checked() -> None:
    config = parse_ekf_config(_params(tag_corners0_pixel_std=0.1, tag_corners0_tag_shift_std=0.1,
                                      tag_corners0_blur_std_per_px=0.05, tag_corners0_exposure_time=0.004,
                                      tag_corners0_unknown_motion_blur_px=4.0,
                                      tag_corners1_diagonal_covariance=True), MODELS)
    settings = {inp.name: inp.settings for inp in config.inputs}
    assert settings["tag_corners0"].noise == NOISE and not settings["tag_corners0"].diagonal_covariance
    assert settings["tag_corners1"].noise == CornerNoise() and settings["tag_corners1"].diagonal_covariance
    for name, bad in (("pixel_std", 0.0), ("tag_shift_std", -0.1), ("exposure_time", math.nan)):
        with pytest.raises(ParameterError, match=f"tag_corners0_{name}"):
            parse_ekf_config(_params(**{f"tag_corners0_{name}": bad}), MODELS)


# --- the residual check ------------------------------------------------------------------------

def test_residual_check_bound_is_chi2_8_at_the_pnp_checks_mass() -> None:
    assert RESIDUAL_CHECK_MASS == 0.99
    # χ²(8)'s 0.99 quantile (scipy.stats.chi2.ppf(0.99, 8) = 20.0902...)
    assert _model_fusion(1).widen_above == pytest.approx(20.090235029663233, rel=1e-12)


@pytest.mark.parametrize("nis", [19.0, 30.0, 400.0])
def test_engine_widens_r_by_nis_over_m_above_the_bound(nis: float) -> None:
    """m = 2, P = R = I: S = 2 I, NIS = a²/2 for y = (a, 0). Above the bound R becomes k R,
    k = NIS / 2: the update is the scalar Kalman update with S = 1 + k, and the reported NIS
    a² / (1 + k) is at least m (S' <= k S)."""
    bound = 20.0
    a = math.sqrt(2.0 * nis)
    ekf = ExtendedKalmanFilter(LinearProcessModel(np.zeros((2, 1))), np.zeros(2), np.eye(2))
    result = ekf.update(LinearMeasurement(np.eye(2)), np.array([a, 0.0]), np.eye(2), widen_above=bound)
    k = nis / 2.0 if nis > bound else 1.0
    assert result.accepted and ekf.last_widening == pytest.approx(k, rel=1e-12)
    assert result.mahalanobis ** 2 == pytest.approx(a * a / (1.0 + k), rel=1e-12)
    assert result.mahalanobis ** 2 >= 2.0 - 1e-12
    np.testing.assert_allclose(ekf.x, [a / (1.0 + k), 0.0], rtol=1e-12)
    np.testing.assert_allclose(ekf.P, k / (1.0 + k) * np.eye(2), rtol=1e-12)   # all of R widened


def test_engine_gates_on_the_widened_nis() -> None:
    """NIS 400 widened by 200: S' = 201, d'² = 800 / 201 = 3.98: a 1.9 σ gate rejects it, 2.1 σ not."""
    a = math.sqrt(800.0)
    for gate, accepted in ((1.9, False), (2.1, True)):
        ekf = ExtendedKalmanFilter(LinearProcessModel(np.zeros((2, 1))), np.zeros(2), np.eye(2))
        result = ekf.update(LinearMeasurement(np.eye(2)), np.array([a, 0.0]), np.eye(2), gate_sigmas=gate,
                            widen_above=20.0)
        assert result.accepted is accepted and ekf.last_widening == pytest.approx(200.0)


def test_localizer_widens_and_counts_corners_that_fit_worse_than_the_model() -> None:
    """At the truth with a confident prior, corners within the model are fused as they are; one
    tag's corners moved 3 px (30 σ of the model's 0.1 px) are fused widened and counted."""
    p0 = np.zeros((15, 15))
    for f in (0, 1, 5, 6, 7, 11):
        p0[f, f] = 1e-6
    params = _params(initial_estimate_covariance=p0.ravel().tolist(),
                     initial_state=[TRUTH[0], TRUTH[1], 0.0, 0.0, 0.0, TRUTH[2]] + [0.0] * 9,
                     tag_corners0_pixel_std=0.1, tag_corners1_pixel_std=0.1)
    loc = make_localizer(parse_ekf_config(params, MODELS))
    uv = tag_images.project_tag(_pose6(TRUTH), 1)
    assert loc.add_measurement("tag_corners0", TagCornerObservation(100_000_000, "camera_optical", uv),
                               100_000_000).applied
    assert loc.stats["tag_corners0"].widened == 0
    bad = tag_images.project_tag(_pose6(TRUTH), 2) + np.array([3.0, 0.0])
    assert loc.add_measurement("tag_corners1", TagCornerObservation(200_000_000, "camera_optical", bad),
                               200_000_000).applied
    assert loc.stats["tag_corners1"].widened == 1
    from ekf_localization.ros.ekf_diagnostics import EkfDiagnostics  # rclpy's messages: here only

    statuses = {s.name: {kv.key: kv.value for kv in s.values}
                for s in EkfDiagnostics(loc, False).statuses("ekf", 0, 200_000_000, 0, ())}
    assert statuses["ekf: tag_corners0"]["widened"] == "0"
    assert statuses["ekf: tag_corners1"]["widened"] == "1"
