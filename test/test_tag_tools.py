"""tag_layout_from_wpilib (WPILib JSON -> layout YAML) and tag_detect (run as subprocesses)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import yaml

from ekf_localization.tools.tag_layout_from_wpilib import layout_from_wpilib
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import load_tag_layout, tag_layout_from_dict

# Two tags the way WPILib writes them: tag 1 on the far wall facing the blue alliance (yaw pi),
# tag 2 on the blue wall facing the field (identity), 1.2 m up.
WPILIB = {"tags": [
    {"ID": 1, "pose": {"translation": {"x": 16.0, "y": 4.0, "z": 1.2},
                       "rotation": {"quaternion": {"W": 0.0, "X": 0.0, "Y": 0.0, "Z": 1.0}}}},
    {"ID": 2, "pose": {"translation": {"x": 0.0, "y": 2.0, "z": 1.2},
                       "rotation": {"quaternion": {"W": 1.0, "X": 0.0, "Y": 0.0, "Z": 0.0}}}}],
    "field": {"length": 16.54, "width": 8.21}}


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=60)


def test_wpilib_json_to_layout(tmp_path) -> None:
    src, out = tmp_path / "field.json", tmp_path / "field.yaml"
    src.write_text(json.dumps(WPILIB))
    done = _run("ekf_localization.tools.tag_layout_from_wpilib", str(src), "-o", str(out),
                "--tag-size", "0.2")
    assert done.returncode == 0, done.stderr
    layout = load_tag_layout(out)
    assert sorted(layout.tags) == [1, 2] and layout.field_length == 16.54
    far, blue = layout.tags[1], layout.tags[2]
    assert far.size == 0.2
    np.testing.assert_allclose(far.pose_in_map[:3, 3], [16.0, 4.0, 1.2])
    # +x out of the face: tag 1 faces -x (towards the blue wall), tag 2 faces +x
    np.testing.assert_allclose(far.pose_in_map[:3, 0], [-1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(blue.pose_in_map[:3, 0], [1.0, 0.0, 0.0], atol=1e-12)
    # a camera at the field centre looking at tag 1 sees its corners bl, br, tr, tl
    R_map_opt = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    cam = PinholeCamera.from_fov(640, 480, math.radians(70.0))
    px = cam.project((far.corners_map() - [8.0, 4.0, 1.2]) @ R_map_opt)
    assert px[0, 0] < px[1, 0] and px[0, 1] > px[3, 1]          # bl left of br, below tl
    assert px[2, 0] > px[3, 0] and px[2, 1] < px[1, 1]          # tr right of tl, above br


def test_wpilib_bad_input(tmp_path) -> None:
    with pytest.raises(ValueError, match=r"tags\[0\].pose.translation: missing 'z'"):
        bad = json.loads(json.dumps(WPILIB))
        del bad["tags"][0]["pose"]["translation"]["z"]
        layout_from_wpilib(bad)
    src = tmp_path / "bad.json"
    src.write_text("{not json")
    done = _run("ekf_localization.tools.tag_layout_from_wpilib", str(src))
    assert done.returncode == 2 and "tag_layout_from_wpilib:" in done.stderr
    assert "Traceback" not in done.stderr
    assert tag_layout_from_dict(yaml.safe_load(yaml.safe_dump(layout_from_wpilib(WPILIB))))


def test_tag_detect_prints_and_draws(tmp_path) -> None:
    cv2 = pytest.importorskip("cv2")
    pytest.importorskip("dt_apriltags")
    from sim_robot.world.camera_render import CameraRenderer, RenderSettings, optical_pose, planar_pose

    cam = PinholeCamera.from_fov(640, 480, math.radians(70.0))
    layout = tag_layout_from_dict({"tags": [
        {"id": 17, "size": 0.1651, "position": [2.0, -0.3, 0.3], "yaw": math.pi + 0.4},
        {"id": 42, "size": 0.1651, "position": [2.5, 0.4, 0.3], "yaw": math.pi}]})
    # realistic: noise, a 5 px motion blur, dim, uneven light
    renderer = CameraRenderer(cam, layout, RenderSettings(noise_std=3.0, exposure_time=0.003,
                                                          illumination_gradient=0.3))
    start = optical_pose(planar_pose(0.0, 0.0, 0.3, 0.0))
    paths = []
    for i, end_yaw in enumerate((0.0, 0.005)):
        end = optical_pose(planar_pose(0.0, 0.0, 0.3, end_yaw))
        path = tmp_path / f"frame{i}.png"
        cv2.imwrite(str(path), renderer.render(start, end, np.random.default_rng(i)))
        paths.append(str(path))
    jpeg = tmp_path / "frame.jpg"
    cv2.imwrite(str(jpeg), renderer.render(start), [cv2.IMWRITE_JPEG_QUALITY, 90])
    paths.append(str(jpeg))
    draw = tmp_path / "drawn"
    done = _run("ekf_localization.tools.tag_detect", *paths, "--draw", str(draw))
    assert done.returncode == 0, done.stderr
    lines = [line.split() for line in done.stdout.splitlines()]
    assert [(f, int(i)) for f, i, *_ in lines] == [(p, t) for p in paths for t in (17, 42)]
    for f, tag_id, *xy in lines:
        corners = np.array(xy, float).reshape(4, 2)
        corners_map = layout.tags[int(tag_id)].corners_map()
        truth = cam.project((corners_map - start[:3, 3]) @ start[:3, :3])
        assert np.abs(corners - truth).max() < 2.0, (f, tag_id, corners, truth)
    drawn = cv2.imread(str(draw / "frame0.png"))
    assert drawn is not None and drawn.shape == (480, 640, 3)
    assert (drawn[..., 1].astype(int) - drawn[..., 2]).max() > 100   # green outlines


def test_tag_detect_unreadable_image(tmp_path) -> None:
    pytest.importorskip("cv2")
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"\x89PNG not really")
    done = _run("ekf_localization.tools.tag_detect", str(bad))
    assert done.returncode == 2 and "cannot read image" in done.stderr
