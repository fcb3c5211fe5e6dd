"""The closed loop from camera images (issue 33): ``ekf_demo --camera images`` over real DDS.

sim_node renders the field's AprilTags, tag_localizer (a process of its own) detects them and
publishes camera/pose, ekf_node fuses it with the dead wheels, the IMU and cmd_vel, and
pure_pursuit_node drives seed 000's test path on the estimate. Checked: the path is completed,
tag fixes were accepted and reach the EKF, its (x, y) RMSE is within the bound
test_closed_loop.py holds the direct-pose demo to and below dead reckoning, and the live pose
NEES (the published covariances against the truth, χ²(3)) is in [1, 7] as the issue asks.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest
from helpers.ros_helpers import REPO, allocate_domain
from test_closed_loop import DOCUMENTED_XY_RMSE_M, PATH_FILE, XY_RMSE_MARGIN

from ekf_localization.core.chi2_bands import mean_chi2_band
from ekf_localization.tools import bag_io
from ekf_localization.tools.evaluation import rmse

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NEES_LIVE_POSE_BAND = (1.0, 7.0)  # issue 33's figure for the images demo
# seed 000's path is ~9 s: 180 captures at 20 Hz, of which a run accepts ~100 (seeds 0-5,
# 2026-12-06); a detector or PnP that broke would leave far fewer
MIN_ACCEPTED = 40


@pytest.fixture(scope="module")
def images_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo_images")
    cmd = [sys.executable, "-m", "ekf_localization.tools.demo", "--path-file", str(PATH_FILE),
           "--camera", "images", "--out", str(out), "--timeout", "150"]
    env = dict(os.environ, ROS_DOMAIN_ID=str(allocate_domain()))
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=240, cwd=REPO, env=env)
    return out, res


def test_images_loop_completes_with_tag_fixes(images_run) -> None:
    out, res = images_run
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "path completed" in res.stdout
    m = re.search(r"^tag fixes: (\d+) accepted, (\d+) rejected", res.stdout, re.MULTILINE)
    assert m, res.stdout[-3000:]
    assert int(m.group(1)) >= MIN_ACCEPTED, m.group(0)
    types = bag_io.topic_types(out / "bag")
    assert types.get("/camera/pose") == "geometry_msgs/msg/PoseWithCovarianceStamped", types
    assert "/camera/image_raw" not in types  # 6 MB/s: not recorded
    nis = [line for line in res.stdout.splitlines() if line.startswith("NIS pose0/pose mean ")]
    assert nis and int(re.search(r"(\d+) updates", nis[0]).group(1)) >= MIN_ACCEPTED, nis


def test_images_loop_accuracy_and_live_consistency(images_run) -> None:
    out, res = images_run
    assert res.returncode == 0, res.stdout[-3000:]
    truth = bag_io.read_odometry(out / "bag", "/ground_truth/odom")
    ekf = rmse(bag_io.read_odometry(out / "bag", "/odometry/filtered"), truth)["xy"]
    dead = rmse(bag_io.read_odometry(out / "bag", "/odometry/dead_wheels"), truth)["xy"]
    assert ekf < XY_RMSE_MARGIN * DOCUMENTED_XY_RMSE_M, (ekf, dead)
    assert ekf < dead, (ekf, dead)
    m = re.search(r"^NEES live pose mean ([0-9.]+)", res.stdout, re.MULTILINE)
    assert m, res.stdout[-3000:]
    lo, hi = NEES_LIVE_POSE_BAND
    assert lo <= float(m.group(1)) <= hi, m.group(0)


def test_tag_fixes_are_honest(images_run) -> None:
    """The fixes' own NEES (x, y, θ against the truth with the covariance tag_localizer
    published) is in the 99.9 % band of a mean of that many χ²(3) values. The corner noise of
    config/tag_localizer.yaml was fitted on seeds 11-20; this is the default seed. Before the
    shared-shift and blur model (pixel_std 1.0 alone) it was 0.25-0.90, below the band."""
    _out, res = images_run
    m = re.search(r"^tag fixes NEES mean ([0-9.]+) \(chi2\(3\), (\d+) fixes", res.stdout, re.MULTILINE)
    assert m, res.stdout[-3000:]
    lo, hi = mean_chi2_band(3, int(m.group(2)), mass=0.999)
    assert lo <= float(m.group(1)) <= hi, (m.group(0), lo, hi)
