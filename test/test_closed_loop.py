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
from ekf_localization.tools.replay import load_config, replay

pytestmark = [pytest.mark.ros, pytest.mark.slow]

PATH_FILE = REPO / "config" / "paths" / "seed000_test_path.yaml"  # the demo's default path
# README "Over DDS" (bash scripts/demo.sh on this path): the EKF's (x, y) RMSE was 1.19 cm and
# 0.54 cm on an idle machine (two fresh clones, 2026-12-02) and 1.08 cm at load 8. The run must
# stay within twice the worst of them: a broken fusion (dead reckoning alone gives 1.76-2.54 cm
# there) or a lost camera fails it, while the spread between runs (x2.2 between the two idle
# ones) passes.
DOCUMENTED_XY_RMSE_M = 0.0119
XY_RMSE_MARGIN = 2.0

# Online vs offline: the replay feeds the recorded messages in receive order to the same
# Localizer the node runs, and takes each estimate when the bag's clock reaches the stamp of a
# recorded /odometry/filtered. What it cannot know is the node executor's order when a message
# and the publish timer fell in the same sim-clock tick (~10 ms): it computes both orders and
# keeps the closer one. When several messages (odometry, IMU) and the publish share a tick,
# the executor may also interleave them in an order neither extreme reproduces; the heading
# shows it most, because seed 000's truth puts white noise of 0.67 rad/s std on the yaw rate
# that the IMU measures. Such ties are rarer in real time than at --rtf 2.0: measured at 1.0,
# position max <= 0.4 mm and heading max <= 5e-5 rad (3 runs); at 2.0, up to 4.3 mm and
# 0.08 rad (9 runs). The bounds hold for both.
POSITION_MEDIAN_M, POSITION_P99_M, POSITION_MAX_M = 0.0005, 0.01, 0.02
HEADING_MEDIAN_RAD, HEADING_P95_RAD, HEADING_MAX_RAD = 0.002, 0.03, 0.15


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
    [3.6, 9.1] (χ²₀.₀₂₅(36)/6, χ²₀.₉₇₅(36)/6). README's idle runs: 8.45 and 7.85."""
    out, res = demo_run
    assert res.returncode == 0
    lines = [line for line in res.stdout.splitlines() if line.startswith("NEES mean ")]
    assert len(lines) == 1, res.stdout[-3000:]
    nees = float(lines[0].split()[2])
    truth = bag_io.read_odometry(out / "bag", "/ground_truth/odom")
    duration_s = (truth.t_ns[-1] - truth.t_ns[0]) * 1e-9
    lo, hi = mean_chi2_band(6, max(1.0, duration_s * NEES_SAMPLES_PER_SECOND))
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
    config = load_config(out / "ekf_params.yaml")
    # Compared at the stamps both produced: the recorder can receive the very first input a
    # tick after ekf_node did, so the replay may have no estimate yet at the first output.
    runs = [replay(bag, config, "recorded", ties=t).trajectory() for t in ("inputs_first", "outputs_first")]
    common = np.intersect1d(np.intersect1d(online.t_ns, runs[0].t_ns), runs[1].t_ns)
    assert len(common) >= len(online) - 3, (len(common), len(online))
    on = online.states[np.searchsorted(online.t_ns, common)]
    d_pos, d_yaw = [], []
    for offline in runs:
        off = offline.states[np.searchsorted(offline.t_ns, common)]
        d_pos.append(np.hypot(*(on[:, :2] - off[:, :2]).T))
        d_yaw.append(np.abs(wrap_angles(on[:, 2] - off[:, 2])))
    d_pos, d_yaw = np.minimum(*d_pos), np.minimum(*d_yaw)
    Path(out / "replay_agreement.txt").write_text(
        f"position: median {np.median(d_pos):.2e} m, p99 {np.percentile(d_pos, 99):.2e} m, "
        f"max {d_pos.max():.2e} m; heading: median {np.median(d_yaw):.2e} rad, "
        f"p95 {np.percentile(d_yaw, 95):.2e} rad, max {d_yaw.max():.2e} rad\n")
    assert np.median(d_pos) < POSITION_MEDIAN_M, np.percentile(d_pos, [50, 99, 100])
    assert np.percentile(d_pos, 99) < POSITION_P99_M, np.percentile(d_pos, [50, 99, 100])
    assert d_pos.max() < POSITION_MAX_M, np.percentile(d_pos, [50, 99, 100])
    assert np.median(d_yaw) < HEADING_MEDIAN_RAD, np.percentile(d_yaw, [50, 99, 100])
    assert np.percentile(d_yaw, 95) < HEADING_P95_RAD, np.percentile(d_yaw, [50, 95, 100])
    assert d_yaw.max() < HEADING_MAX_RAD, np.percentile(d_yaw, [50, 95, 100])
