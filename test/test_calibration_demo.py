"""``bash scripts/demo.sh --calibration``: the calibration demo end to end (sim_bag, ekf_calibrate,
the replay before and after), as a new user runs it."""

from __future__ import annotations

import math
import re
import subprocess

import pytest
from helpers.ros_helpers import REPO

from ekf_localization.tools.calibration_demo import POD_ANGLES, POD_OFFSETS, POD_SCALES

pytestmark = pytest.mark.slow  # sets the environment up, records 65 s, fits and replays three times

# 65 s (one cycle of the drive), seed 1: the bootstrap stds are about 0.0007 (gyro scale), 0.0004
# rad/s (bias), 0.6 mm (offsets), 2 mrad (angles), 0.0024 (scales); bounds 5 σ, and the issue's
# 3 mm for the offsets
BOUNDS = {"imu0_yaw_rate_scale": 0.0035, "imu0_yaw_rate_bias": 0.002, "joint0_pod_offsets": 0.003,
          "joint0_pod_angles": 0.01, "joint0_pod_scales": 0.012}
TRUE = {"imu0_yaw_rate_scale": [1.02], "imu0_yaw_rate_bias": [0.01], "joint0_pod_offsets": POD_OFFSETS,
        "joint0_pod_angles": POD_ANGLES, "joint0_pod_scales": POD_SCALES}


def _row(table: str, row: str) -> list[float]:
    line = next(line for line in table.splitlines() if line.startswith(row))
    return [float(v) for v in re.split(r"\s{2,}", line.strip())[1:]]  # (x,y) m, in, x, y, θ, ...


def test_demo_sh_calibration_fits_the_gyro_pods_and_mount_and_the_replay_improves(tmp_path):
    out = tmp_path / "cal"
    run = subprocess.run(["bash", str(REPO / "scripts" / "demo.sh"), "--calibration", "--duration", "65.0",
                          "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    fitted = {(name, int(i or 0)): float(v) for name, i, v in
              re.findall(r"^(\w+?)(?:\[(\d)\])? (\S+) ±", run.stdout, re.M)}
    assert {name for name, _ in fitted} == set(TRUE), run.stdout
    for (name, i), value in fitted.items():
        assert abs(value - TRUE[name][i]) < BOUNDS[name], (name, i, value, run.stdout)
    yaw = re.search(r"^static_transforms\[base_link camera_link\]\.yaw (\S+) ±", run.stdout, re.M)
    assert yaw and abs(float(yaw[1]) - math.radians(2.0)) < math.radians(0.3), run.stdout  # the 0.3°
    table = (out / "rmse.txt").read_text()
    as_said, calibrated, true = (_row(table, r) for r in ("as ekf_joint_states.yaml says", "calibrated",
                                                          "true values"))
    assert calibrated[0] < 0.5 * as_said[0], table  # the pods' error was most of the position error
    for k in (0, 4):  # (x, y) and θ: the goal, calibrated within 1.1x of the true values
        assert calibrated[k] <= 1.1 * true[k], table
    for name in ("calibrated.yaml", "trajectory.png", "errors.png", "sim_true.yaml", "ekf_params.yaml"):
        assert (out / name).is_file(), name
