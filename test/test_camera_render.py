"""The camera renderer draws real tag36h11 tags where PinholeCamera.project puts them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ekf_localization.vision.detectors import make_detector
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import tag_layout_from_dict
from sim_robot.world.camera_render import CameraRenderer, RenderSettings, optical_pose, planar_pose

pytest.importorskip("cv2")
CAMERA = PinholeCamera.from_fov(640, 480, math.radians(70.0))
LAYOUT = tag_layout_from_dict({"tags": [
    {"id": 3, "size": 0.1651, "position": [2.0, 0.0, 0.3], "yaw": math.pi + 0.3},
    {"id": 7, "size": 0.1651, "position": [2.0, 0.6, 0.3], "yaw": math.pi}]})


def _truth(cam_pose: np.ndarray, tag_id: int) -> np.ndarray:
    corners = LAYOUT.tags[tag_id].corners_map()
    return CAMERA.project((corners - cam_pose[:3, 3]) @ cam_pose[:3, :3])


def test_tag_at_2m_corners_match_projection() -> None:
    """No noise, 2 m: the AprilRobotics library finds both tags within 0.5 px, in its order."""
    pytest.importorskip("dt_apriltags")
    renderer = CameraRenderer(CAMERA, LAYOUT)
    pose = optical_pose(planar_pose(0.0, 0.2, 0.28, 0.1))
    found = {d.tag_id: d for d in make_detector("apriltag").detect(renderer.render(pose))}
    assert sorted(found) == [3, 7]
    for tag_id, det in found.items():
        err = np.abs(det.corners - _truth(pose, tag_id)).max()
        assert err < 0.5, (tag_id, det.corners, _truth(pose, tag_id))


def test_opencv_detector_same_order_and_ids() -> None:
    """OpenCV's aruco reads the same ids, corners in the same order (a wrong order is off by
    the tag's width, ~40 px; OpenCV 5.1 is within 0.7 px here, 4.6 (Ubuntu 24.04) 1.2 px)."""
    renderer = CameraRenderer(CAMERA, LAYOUT)
    pose = optical_pose(planar_pose(0.0, 0.2, 0.28, 0.1))
    found = {d.tag_id: d for d in make_detector("opencv").detect(renderer.render(pose))}
    assert sorted(found) == [3, 7]
    for tag_id, det in found.items():
        assert np.abs(det.corners - _truth(pose, tag_id)).max() < 1.5


def test_visibility_noise_blur_and_exposure() -> None:
    settings = RenderSettings(noise_std=3.0, exposure_time=0.008)
    renderer = CameraRenderer(CAMERA, LAYOUT, settings)
    pose = optical_pose(planar_pose(0.0, 0.2, 0.28, 0.1))
    assert sorted(renderer.visible_tags(pose)) == [3, 7]
    assert renderer.visible_tags(optical_pose(planar_pose(0.0, 0.2, 0.28, math.pi))) == []
    still = renderer.render(pose, rng=np.random.default_rng(1))
    # twice the reference exposure: the background is twice as bright, noise std as set
    assert abs(float(np.median(still)) - 2 * settings.background_level) < 2.0
    assert 2.0 < float(np.std(still[:40, :40].astype(float))) < 4.0
    clean = CameraRenderer(CAMERA, LAYOUT)
    moving = clean.render(pose, optical_pose(planar_pose(0.0, 0.2, 0.28, 0.13)))
    # a 0.03 rad turn (~14 px) during the exposure smears the edges: less edge energy
    sharp = np.abs(np.diff(clean.render(pose).astype(float), axis=1)).sum()
    assert np.abs(np.diff(moving.astype(float), axis=1)).sum() < 0.8 * sharp


def test_optics_blur_spreads_edges_keeps_corners() -> None:
    """A Gaussian lens blur of 0.52 px (config/sim.yaml): the edges soften, the levels and the
    detected corners stay (the blur is symmetric about each edge)."""
    pytest.importorskip("dt_apriltags")
    pose = optical_pose(planar_pose(0.0, 0.2, 0.28, 0.1))
    sharp = CameraRenderer(CAMERA, LAYOUT).render(pose).astype(float)
    soft = CameraRenderer(CAMERA, LAYOUT, RenderSettings(optics_blur_std=0.52)).render(pose)
    assert abs(float(np.median(soft)) - float(np.median(sharp))) < 1.0
    edges = np.abs(np.diff(sharp, axis=1))
    assert np.abs(np.diff(soft.astype(float), axis=1)).max() < 0.9 * edges.max()
    found = {d.tag_id: d for d in make_detector("apriltag").detect(soft)}
    assert sorted(found) == [3, 7]
    for tag_id, det in found.items():
        assert np.abs(det.corners - _truth(pose, tag_id)).max() < 0.5


def test_bad_settings_rejected() -> None:
    with pytest.raises(ValueError, match="exposure_time"):
        RenderSettings(exposure_time=0.0)
    with pytest.raises(ValueError, match="optics_blur_std"):
        RenderSettings(optics_blur_std=-0.1)
    with pytest.raises(ValueError, match="optics_blur_std"):
        RenderSettings(optics_blur_std=float("nan"))
    with pytest.raises(ValueError, match="supersample"):
        RenderSettings(supersample=0)


def test_motion_blur_centred_at_mid_exposure() -> None:
    """The blurred tag's centroid sits where the camera at mid-exposure sees the tag."""
    layout = tag_layout_from_dict({"tags": [
        {"id": 5, "size": 0.1651, "position": [2.0, 0.0, 0.3], "yaw": math.pi}]})
    renderer = CameraRenderer(CAMERA, layout, RenderSettings(background_level=215.0))

    def dark_centroid(image: np.ndarray) -> np.ndarray:
        w = 215.0 - image.astype(float)
        v, u = np.indices(image.shape)
        return np.array([(w * u).sum(), (w * v).sum()]) / w.sum()

    start = optical_pose(planar_pose(0.0, 0.0, 0.3, 0.0))
    moving = renderer.render(start, optical_pose(planar_pose(0.0, 0.0, 0.3, 0.04)))
    mid = renderer.render(optical_pose(planar_pose(0.0, 0.0, 0.3, 0.02)))
    shift = dark_centroid(moving) - dark_centroid(renderer.render(start))
    assert shift[0] > 7.0   # the camera turned left by 0.04 rad (~18 px): the tag moved right
    assert np.abs(dark_centroid(moving) - dark_centroid(mid)).max() < 0.3
