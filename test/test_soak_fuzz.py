"""Soak and fuzz in CI's slow leg (issue 35, item 9).

* The live soak, short: benchmarks/soak_dds.py for 2 minutes of wall time at real-time factor 2
  (ekf_node's RSS growth after the first minute <= 10 MB, max position error <= 0.10 m, no gap
  between /odometry/filtered stamps over two publish periods). Without CPU hogs: with one or two
  busy-loop hogs the error criterion fails (0.2-0.35 m during fast turns, 2026-12-06; issue 35,
  case 2 is open), so that run is a figure of benchmarks/soak_dds.py, not a test that passes.
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
from helpers.ros_helpers import REPO
from hypothesis import HealthCheck, given, seed, settings

pytestmark = pytest.mark.slow


@pytest.mark.ros
def test_live_soak_at_real_time_factor_2(ros_domain) -> None:
    cmd = [sys.executable, str(REPO / "benchmarks" / "soak_dds.py"), "--minutes", "2", "--rtf", "2.0",
           "--hogs", "0"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]


@seed(0)
@settings(max_examples=2000, deadline=None, database=None, derandomize=False,
          suppress_health_check=list(HealthCheck))
@given(SEQUENCES)
def test_fuzz_sequences_keep_every_invariant(ops) -> None:
    check_quick_sequence(ops)
