"""The tag layout YAML and the pinhole camera: corner order, parsing errors, projection."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import corners_in_tag, load_tag_layout, tag_layout_from_dict

REPO_ROOT = Path(__file__).resolve().parents[1]

LAYOUT = {"tag_family": "tag36h11", "field": {"length": 3.6576, "width": 3.6576},
          "tags": [{"id": 3, "size": 0.1, "position": [0.0, 1.0, 0.2], "yaw": 0.0},
                   {"id": 7, "size": 0.2, "position": [3.6, 2.0, 0.3],
                    "orientation": [0.0, 0.0, 1.0, 0.0]}]}


def test_corners_are_counter_clockwise_on_the_image_of_a_facing_camera() -> None:
    # A camera 1 m in front of tag 3 (on the wall x = 0, facing +x), looking at it (-x).
    layout = tag_layout_from_dict(LAYOUT)
    corners = layout.tags[3].corners_map()
    # map -> optical frame of a camera at (1, 1, 0.2) looking along -x: z_opt = -x, x_opt = +y
    # (the camera's right), y_opt = -z (down).
    rel = corners - np.array([1.0, 1.0, 0.2])
    optical = np.column_stack([rel[:, 1], -rel[:, 2], -rel[:, 0]])
    px = PinholeCamera.from_fov(640, 480, math.radians(70.0)).project(optical)
    bl, br, tr, tl = px
    assert bl[0] < br[0] and bl[1] > tl[1]          # bottom-left is left of br and below tl
    assert tr[0] > tl[0] and tr[1] < br[1]
    # counter-clockwise as seen on the screen (y down): the shoelace sum is negative
    area = sum(px[i, 0] * px[(i + 1) % 4, 1] - px[(i + 1) % 4, 0] * px[i, 1] for i in range(4))
    assert area < 0


def test_yaw_and_quaternion_give_the_same_pose() -> None:
    layout = tag_layout_from_dict(LAYOUT)
    R = layout.tags[7].pose_in_map[:3, :3]
    np.testing.assert_allclose(R, [[-1, 0, 0], [0, -1, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(corners_in_tag(0.2)[:, 0], 0.0)
    assert layout.on_field(1.0, 1.0) and not layout.on_field(5.0, 1.0)


@pytest.mark.parametrize(("change", "message"), [
    ({"tag_family": "tag25h9"}, "tag_family"),
    ({"tags": []}, "tags must be a non-empty list"),
    ({"tags": [{"id": 1, "size": -0.1, "position": [0, 0, 0], "yaw": 0.0}]}, r"tags\[0\].size"),
    ({"tags": [{"id": 1, "size": 0.1, "position": [0, 0], "yaw": 0.0}]}, r"tags\[0\].position"),
    ({"tags": [{"id": 1, "size": 0.1, "position": [0, 0, 0]}]}, "exactly one of"),
    ({"tags": [{"id": 1, "size": 0.1, "position": [0, 0, 0], "yaw": 0.0}] * 2}, "appears twice"),
])
def test_a_bad_layout_names_the_key(change: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        tag_layout_from_dict({**LAYOUT, **change})


def test_field_origin_moves_the_field() -> None:
    """A map frame at the field centre (the simulator's): origin [-L/2, -W/2]."""
    data = {"field": {"length": 4.0, "width": 2.0, "origin": [-2.0, -1.0]},
            "tags": [{"id": 1, "size": 0.1, "position": [0.0, 0.0, 0.1], "yaw": 0.0}]}
    layout = tag_layout_from_dict(data)
    assert layout.on_field(-1.9, -0.9) and layout.on_field(1.9, 0.9)
    assert not layout.on_field(2.1, 0.0) and not layout.on_field(0.0, -1.1)
    with pytest.raises(ValueError, match="field: unknown"):
        tag_layout_from_dict({**data, "field": {"length": 4.0, "width": 2.0, "centre": [0, 0]}})


def test_simulated_field_layout_loads() -> None:
    layout = load_tag_layout(REPO_ROOT / "config" / "tags" / "ftc_seed000.yaml")
    assert sorted(layout.tags) == list(range(1, 13))
    assert layout.on_field(0.0, 0.0) and not layout.on_field(2.0, 0.0)
    for tag in layout.tags.values():   # every tag faces the field centre
        assert np.dot(tag.pose_in_map[:2, 0], -tag.pose_in_map[:2, 3]) > 0.0
