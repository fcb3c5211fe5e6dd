"""Soak and fuzz in CI's slow leg (issue 35, item 9).

* The live soak, loaded: benchmarks/soak_dds.py for 2 minutes of wall time at real-time factor
  2 with a busy loop on each core, ekf_node at config/ekf.yaml's thread_priority (SCHED_FIFO 40)
  and the simulator, which stands for the physical world, at SCHED_FIFO 60: after the first
  minute (the start-up), ekf_node's RSS growth <= 10 MB, max position error <= 0.10 m, and no
  gap between /odometry/filtered stamps, net of /clock stalls, over 10 periods (0.2 s:
  pure_pursuit's odom_timeout, after which the follower stops the robot). CI's first run of it
  (2026-12-07) had a 0.570 s gap in minute 1, while pure_pursuit_node was still loading its
  path and the simulator warned it could not keep up; minute 2 had none over two periods. It
  needs the right to SCHED_FIFO (root, CAP_SYS_NICE or an rtprio limit) and skips, saying so,
  without it. Issue 35's own figure (30 minutes, no gap over two periods) is
  benchmarks/soak_dds.py's default; the loaded soaks without SCHED_FIFO (normal priority
  against the hogs: gaps of 0.2-1.4 s, errors of 0.1-0.5 m) are in docs/DEVELOPING.md.
* The live soak at real time without hogs, which needs no privilege, with the same limits.
* The fuzzer: 2 000 seeded Localizer sequences of good, invalid and absurd messages, stamps,
  resets, set_pose and clock jumps (helpers/fuzz_cases.py: finite output, symmetric positive-
  definite covariance, counters that add up); benchmarks/fuzz.py --quick-sequences 10000 is the
  figure.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from helpers.fuzz_cases import SEQUENCES, check_quick_sequence
from helpers.ros_helpers import REPO, fifo_allowed
from hypothesis import HealthCheck, given, seed, settings

pytestmark = pytest.mark.slow
WORLD_PRIORITY = 60  # soak_dds.py --world-priority's default, the highest it sets


def _soak(*args: str) -> None:
    cmd = [sys.executable, str(REPO / "benchmarks" / "soak_dds.py"), "--minutes", "2", *args,
           "--max-gap-periods", "10"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "refused" not in proc.stdout, proc.stdout[:1000]


@pytest.mark.ros
def test_live_soak_at_real_time_factor_2_with_both_cores_busy(ros_domain) -> None:
    if not fifo_allowed(WORLD_PRIORITY):
        pytest.skip("SCHED_FIFO is not allowed to this user (root, CAP_SYS_NICE or an rtprio limit)")
    _soak("--rtf", "2.0", "--hogs", "2")


@pytest.mark.ros
def test_live_soak_at_real_time(ros_domain) -> None:
    _soak("--rtf", "1.0", "--hogs", "0", "--world-priority", "0")


@seed(0)
@settings(max_examples=2000, deadline=None, database=None, derandomize=False,
          suppress_health_check=list(HealthCheck))
@given(SEQUENCES)
def test_fuzz_sequences_keep_every_invariant(ops) -> None:
    check_quick_sequence(ops)
