"""The whole loop over real DDS: sim_node + ekf_node + pure_pursuit_node as processes.

Seed 000's test path (the one README's "Over DDS" figures are for) is driven with ekf_demo
(three node processes plus the recorder, as ``bash scripts/demo.sh``); its accuracy and
consistency are checked against the documented figures, the bag it writes is read back with
rosbags and with the mcap library, and an offline replay of that bag reproduces the online
/odometry/filtered.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers.images import assert_plot_png
from helpers.ros_helpers import REPO, allocate_domain

from ekf_localization.control.field_path import load_path
from ekf_localization.core.angles import wrap_angles
from ekf_localization.tools import bag_io
from ekf_localization.tools.consistency import NEES_SAMPLES_PER_SECOND, mean_chi2_band
from ekf_localization.tools.evaluation import rmse
from ekf_localization.tools.replay import load_settings, replay

pytestmark = [pytest.mark.ros, pytest.mark.slow]

PATH_FILE = REPO / "config" / "paths" / "seed000_test_path.yaml"  # the demo's default path
# README "Over DDS" (bash scripts/demo.sh on this path): the EKF's (x, y) RMSE was 1.19 cm and
# 0.54 cm on an idle machine (two fresh clones, 2026-12-02) and 1.08 cm at load 8. The run must
# stay within twice the worst of them: a broken fusion (dead reckoning alone gives 1.76-2.54 cm
# there) or a lost camera fails it, while the spread between runs (x2.2 between the two idle
# ones) passes.
DOCUMENTED_XY_RMSE_M = 0.0119
XY_RMSE_MARGIN = 2.0

# Online vs offline: ekf_node publishes its fusion log (ros/fusion_log.py: each message it fused,
# in its order, with its clock, and each publish), the recorder records it, and the replay
# follows it, so it is the live filter: every published estimate is reproduced. The bounds
# (1 mm, 1 cm/s, 1e-5 rad) leave room only for the message's float64 round trip.
REPLAY_POSITION_M, REPLAY_VELOCITY_MPS, REPLAY_HEADING_RAD = 0.001, 0.01, 1e-5
CONSISTENCY_GATE_MASS = 0.999  # the χ² band a CI gate uses: a false alarm once in 1000 runs


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    cmd = [sys.executable, "-m", "ekf_localization.tools.demo", "--path-file", str(PATH_FILE), "--rtf", "1.0",
           "--out", str(out), "--timeout", "150"]
    env = dict(os.environ, ROS_DOMAIN_ID=str(allocate_domain()))
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=240, cwd=REPO, env=env)
    return out, res


def test_short_closed_loop_completes(demo_run):
    out, res = demo_run
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "path completed" in res.stdout
    assert "EKF /odometry/filtered" in res.stdout and "dead reckoning" in res.stdout
    # the same run replayed without cmd_vel, and the run's consistency (ekf.yaml fuses cmd_vel)
    rows = [line for line in res.stdout.splitlines() if line.startswith("replay: without cmd_vel")]
    assert len(rows) == 1, res.stdout[-3000:]
    for part in ("odom0/twist", "imu0/angular_velocity", "imu0/orientation"):
        assert any(line.startswith(f"NIS {part} mean ") for line in res.stdout.splitlines()), part
    assert_plot_png(out / "trajectory.png", 880, 880)  # report.py: 8 x 8 in at 110 dpi
    assert_plot_png(out / "errors.png", 1100, 715)  # 10 x 6.5 in at 110 dpi
    truth = bag_io.read_odometry(out / "bag", "/ground_truth/odom")
    end, goal = truth.states[-1], load_path(PATH_FILE).points()[-1]
    assert np.hypot(*(end[:2] - goal[:2])) < 0.10, f"robot ended at {end[:2]}, the path at {goal}"


def test_accuracy_is_the_documented_one(demo_run):
    out, res = demo_run
    assert res.returncode == 0
    truth = bag_io.read_odometry(out / "bag", "/ground_truth/odom")
    ekf = rmse(bag_io.read_odometry(out / "bag", "/odometry/filtered"), truth)["xy"]
    dead = rmse(bag_io.read_odometry(out / "bag", "/odometry/dead_wheels"), truth)["xy"]
    assert ekf < XY_RMSE_MARGIN * DOCUMENTED_XY_RMSE_M, (ekf, dead, res.stdout[-2000:])
    assert ekf < dead, (ekf, dead)  # README: 0.54-1.19 cm against 1.76-2.54 cm


def test_consistency_is_inside_its_band(demo_run):
    """The run's mean NEES (demo: the bag replayed with the run's parameters, 6 states against
    the truth at every 50 Hz output) inside the 95 % band of a mean of χ²(6) values. Consecutive
    outputs are strongly correlated, so the band counts NEES_SAMPLES_PER_SECOND (0.3/s, measured
    over 20 seeds of this world, docs/ekf_tune.md "Consistency bands") independent samples per
    second of the run, not the outputs: for this path's ~20 s, N_eff ≈ 6 and the band is about
    [3.6, 9.1] (χ²₀.₀₂₅(36)/6, χ²₀.₉₇₅(36)/6). README's idle runs: 8.45 and 7.85.

    As a pass/fail gate the band holds 99.9 % (CONSISTENCY_GATE_MASS), not the 95 % the reports
    print: a 95 % band fails a perfectly consistent filter once in 20 runs (CI, 2026-12-06: 11.61
    against [2.65, 10.70] on a 9.3 s run, every NIS at its mean), while a broken covariance
    (NEES x5) still fails it."""
    out, res = demo_run
    assert res.returncode == 0
    lines = [line for line in res.stdout.splitlines() if line.startswith("NEES mean ")]
    assert len(lines) == 1, res.stdout[-3000:]
    nees = float(lines[0].split()[2])
    truth = bag_io.read_odometry(out / "bag", "/ground_truth/odom")
    duration_s = (truth.t_ns[-1] - truth.t_ns[0]) * 1e-9
    lo, hi = mean_chi2_band(6, max(1.0, duration_s * NEES_SAMPLES_PER_SECOND), CONSISTENCY_GATE_MASS)
    assert lo <= nees <= hi, (f"mean NEES {nees:.2f} outside [{lo:.2f}, {hi:.2f}] ({duration_s:.1f} s)",
                              [line for line in res.stdout.splitlines() if line.startswith("NIS ")])


def test_bag_reads_back_with_rosbags_and_mcap(demo_run):
    out, res = demo_run
    assert res.returncode == 0
    bag = out / "bag"
    types = bag_io.topic_types(bag)
    expected = {"/odometry/dead_wheels": "nav_msgs/msg/Odometry",
                "/camera/pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
                "/imu/data": "sensor_msgs/msg/Imu", "/ground_truth/odom": "nav_msgs/msg/Odometry",
                "/odometry/filtered": "nav_msgs/msg/Odometry", "/cmd_vel": "geometry_msgs/msg/TwistStamped",
                "/clock": "rosgraph_msgs/msg/Clock"}
    for topic, msgtype in expected.items():
        assert types.get(topic) == msgtype, (topic, types)
    est = bag_io.read_odometry(bag, "/odometry/filtered")
    assert len(est) > 50 and np.all(np.isfinite(est.states)) and np.all(np.isfinite(est.covariances))

    from mcap.reader import make_reader

    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as fh:
        summary = make_reader(fh).get_summary()
    counts = summary.statistics.channel_message_counts
    by_topic = {ch.topic: counts.get(cid, 0) for cid, ch in summary.channels.items()}
    assert by_topic["/odometry/filtered"] == len(est)
    assert by_topic["/odometry/dead_wheels"] > 100


def test_offline_replay_matches_online(demo_run):
    out, res = demo_run
    assert res.returncode == 0
    bag = out / "bag"
    online = bag_io.read_odometry(bag, "/odometry/filtered")
    # The demo wrote the exact parameters ekf_node ran with next to the bag.
    result = replay(bag, load_settings(out / "ekf_params.yaml"), "recorded")
    assert result.followed_log and result.missing == 0, (result.followed_log, result.missing)
    offline = result.trajectory()
    np.testing.assert_array_equal(offline.t_ns, online.t_ns)  # every published stamp, no other
    d_pos = np.hypot(*(online.states[:, :2] - offline.states[:, :2]).T)
    d_vel = np.hypot(*(online.states[:, 3:5] - offline.states[:, 3:5]).T)
    d_yaw = np.abs(wrap_angles(online.states[:, 2] - offline.states[:, 2]))
    Path(out / "replay_agreement.txt").write_text(
        f"{len(d_pos)} stamps: position max {d_pos.max():.2e} m, velocity max {d_vel.max():.2e} m/s, "
        f"heading max {d_yaw.max():.2e} rad\n")
    assert d_pos.max() < REPLAY_POSITION_M, (d_pos.max(), online.t_ns[d_pos.argmax()])
    assert d_vel.max() < REPLAY_VELOCITY_MPS, (d_vel.max(), online.t_ns[d_vel.argmax()])
    assert d_yaw.max() < REPLAY_HEADING_RAD, (d_yaw.max(), online.t_ns[d_yaw.argmax()])
    np.testing.assert_allclose(offline.covariances, online.covariances, rtol=1e-6, atol=1e-12)
