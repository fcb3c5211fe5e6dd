"""The deterministic fusion scenario (helpers/fusion_scenario.py) is what it claims to be."""

from __future__ import annotations

import numpy as np
from helpers.fusion_scenario import make_scenario


def test_truth_follows_the_body_twist() -> None:
    scn = make_scenario(duration_s=2.0)
    d = np.diff(scn.truth[:, :2], axis=0) / 1e-3
    th = scn.truth[:-1, 2]
    vx = d[:, 0] * np.cos(th) + d[:, 1] * np.sin(th)
    np.testing.assert_allclose(vx, scn.truth[:-1, 3], atol=1e-9)


def test_camera_poses_arrive_after_their_latency() -> None:
    scn = make_scenario(duration_s=1.0)
    ev = scn.events()
    arrivals = [a for a, s, _ in ev]
    assert arrivals == sorted(arrivals)
    for a, s, j in ev:
        if s == "pose0":
            assert a - scn.camera_pose(j).stamp_ns == scn.camera_latency_ns
