"""The closed-loop demo with both cores busy: the live covariances stay honest.

Two CPU-bound loops at normal priority run beside ``ekf_demo`` (seeds 1 and 2, seed 000's
path at real time). Each run's /odometry/filtered, with the covariances ekf_node published, is
compared with the truth at its own stamp (the demo's ``NEES live`` lines; docs/under_load.md).
What it catches: a demo that compares with a truth interpolated across the drive's command
onsets, or cuts the loaded bag short; a simulated drive starved into acting late on commands
that ekf_node had on time; a filter acting on a late-received command in its past. Each makes
the twist covariance look about half of what the errors need.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

import numpy as np
import pytest
from helpers.ros_helpers import REPO, allocate_domain

pytestmark = [pytest.mark.ros, pytest.mark.slow]

SEEDS = (1, 2)
BUSY_LOOPS = 2  # both cores of the CI machine
# The pooled twist NEES of seeds 1 and 2 (~900 estimates, errors correlated over a few outputs):
# 2.71 with both cores busy and 3.15 idle (docs/under_load.md), every run there 2.3-3.7; with the
# faults above, 3.6-5.0 with both cores busy.
# The pose errors are correlated over seconds: two runs hold few independent samples, so the
# pooled pose NEES gets a wider band. No seed outside [1, 10].
POOLED_TWIST = (1.5, 3.5)
POOLED_POSE = (1.0, 4.5)
PER_SEED = (1.0, 10.0)
LINE = re.compile(r"^NEES live (pose|twist) mean ([0-9.]+) \(chi2\(3\), (\d+)", re.MULTILINE)


@pytest.fixture(scope="module")
def loaded_runs(tmp_path_factory):
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(BUSY_LOOPS)]
    runs = {}
    try:
        for seed in SEEDS:
            out = tmp_path_factory.mktemp(f"loaded_s{seed}")
            cmd = [sys.executable, "-m", "ekf_localization.tools.demo", "--seed", str(seed),
                   "--out", str(out), "--timeout", "200"]
            env = dict(os.environ, ROS_DOMAIN_ID=str(allocate_domain()))
            runs[seed] = subprocess.run(cmd, capture_output=True, text=True, timeout=400, cwd=REPO, env=env)
    finally:
        for p in busy:
            p.kill()
            p.wait()
    return runs


def _nees(res) -> dict[str, tuple[float, int]]:
    return {name: (float(mean), int(n)) for name, mean, n in LINE.findall(res.stdout)}


def test_live_nees_is_honest_with_both_cores_busy(loaded_runs):
    pooled = {"pose": [0.0, 0], "twist": [0.0, 0]}
    for seed, res in loaded_runs.items():
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
        found = _nees(res)
        assert set(found) == {"pose", "twist"}, res.stdout[-3000:]
        for name, (mean, n) in found.items():
            assert n > 100, (seed, name, n)  # most outputs have a truth sample at their stamp
            assert PER_SEED[0] <= mean <= PER_SEED[1], (seed, name, mean)
            pooled[name][0] += mean * n
            pooled[name][1] += n
    twist = pooled["twist"][0] / pooled["twist"][1]
    pose = pooled["pose"][0] / pooled["pose"][1]
    report = {s: _nees(r) for s, r in loaded_runs.items()}
    assert POOLED_TWIST[0] <= twist <= POOLED_TWIST[1], (twist, report)
    assert POOLED_POSE[0] <= pose <= POOLED_POSE[1], (pose, report)
    assert np.isfinite(twist) and np.isfinite(pose)
