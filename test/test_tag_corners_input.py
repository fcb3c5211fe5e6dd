"""The tag_corners input kind (inputs/tag_corners.py): a tag's corner pixels fused directly.

Checked: h against the PnP module's projection; the analytic Jacobian against central
differences; bad observations rejected with their reason; the parameters (required corners
and intrinsics) fail naming the parameter; the Localizer fuses two tags' corners into the pose.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import tag_images

from ekf_localization.core.measurements import REJECT_FRAME, REJECT_IMPLAUSIBLE, REJECT_NONFINITE
from ekf_localization.inputs import KINDS
from ekf_localization.inputs.tag_corners import TagCornerObservation, TagCorners, camera_rotation_translation
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError

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
