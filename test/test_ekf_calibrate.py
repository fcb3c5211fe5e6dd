"""ekf_calibrate: the IMU yaw-rate scale and bias from camera heading fixes (tools/calibration.py)."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from helpers.ros_helpers import REPO

from ekf_localization.models.registry import MODELS
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import parameters_from_yaml
from ekf_localization.tools import calibration, ekf_calibrate
from ekf_localization.tools.calibration import Fixes, Gyro

pytest.importorskip("rosbags")

SCALE, BIAS = 1.02, 0.01  # the simulated gyro's miscalibration
EKF_YAML = REPO / "config" / "ekf.yaml"
WALK = 1e-5  # config/ekf.yaml's yaw process noise, rad²/s
LINE = re.compile(r"^(imu0_yaw_rate_(?:scale|bias)) (\S+) ± (\S+) \(was (\S+)\)$")


def synthetic(rate, seconds: float, s: float = SCALE, b: float = BIAS, gyro_sd: float = 0.0,
              fix_sd: float = 0.0, seed: int = 0) -> tuple[Fixes, Gyro]:
    """A gyro at 100 Hz reporting s·ω + b (+ noise) and heading fixes at 20 Hz on its samples: the
    true heading is the trapezoid integral of ω, the integral the fit takes of the gyro."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * 100) + 1) * 0.01
    w = rate(t)
    heading = np.r_[0.0, np.cumsum(0.5 * (w[1:] + w[:-1]) * 0.01)]
    g = s * w + b + gyro_sd * rng.standard_normal(len(t))
    k = np.arange(0, len(t), 5)
    yaw = np.remainder(heading[k] + fix_sd * rng.standard_normal(len(k)) + math.pi, 2 * math.pi) - math.pi
    return (Fixes(t[k], yaw, np.full(len(k), max(fix_sd, 1e-3) ** 2)),
            Gyro(t, g, np.full(len(t), max(gyro_sd, 1e-3) ** 2)))


def turns(t: np.ndarray) -> np.ndarray:
    """Turning at 1 rad/s and -0.5 rad/s, and not at all."""
    return np.select([t % 30 < 12, t % 30 < 24], [1.0, -0.5], 0.0)


def test_noise_free_data_give_the_scale_and_bias_exactly() -> None:
    p = calibration.build_problem([synthetic(turns, 60.0)], WALK)
    r = calibration.fit(p, (1.0, 0.0))
    assert r.scale == pytest.approx(SCALE, abs=1e-9) and r.bias == pytest.approx(BIAS, abs=1e-9)
    assert r.rms < 1e-6


def test_a_drive_without_rotation_names_the_scale_unobservable_and_fits_the_bias() -> None:
    p = calibration.build_problem([synthetic(np.zeros_like, 60.0, gyro_sd=0.01, fix_sd=0.02)], WALK)
    assert calibration.observable(p, (1.0, 0.0)) == (False, True)
    r = calibration.fit(p, (1.0, 0.0), (False, True))
    assert r.scale == 1.0
    assert abs(r.bias - BIAS) < 4.0 * r.formal_std[1]  # 4 σ of the fit's own information


def test_a_constant_turn_rate_cannot_separate_scale_from_bias() -> None:
    """ω constant: s·ω + b is one number, so only one of them can be fitted; the bias is."""
    p = calibration.build_problem([synthetic(lambda t: np.full_like(t, 0.8), 60.0, gyro_sd=0.01,
                                             fix_sd=0.02)], WALK)
    assert calibration.observable(p, (1.0, 0.0)) == (False, True)


def test_the_bootstrap_is_deterministic_and_near_the_formal_std() -> None:
    p = calibration.build_problem([synthetic(turns, 60.0, gyro_sd=0.01, fix_sd=0.03, seed=4)], WALK)
    r = calibration.fit(p, (1.0, 0.0))
    a = calibration.bootstrap_std(p, r, (True, True), 40, seed=7)
    assert a == calibration.bootstrap_std(p, r, (True, True), 40, seed=7)
    # 40 replicates estimate a std to about ±1/sqrt(2·39) = 11 %; a factor 2 either way is a wrong model
    for boot, formal in zip(a, r.formal_std, strict=True):
        assert 0.5 * formal < boot < 2.0 * formal


def mismatched_world():
    """The demo's simulator world (config/sim.yaml) with the gyro miscalibrated."""
    from sim_robot.ros.sim_bag import demo_world_config

    world = demo_world_config()
    imu = dataclasses.replace(world.imu, yaw_rate_scale=SCALE, yaw_rate_bias=BIAS)
    return dataclasses.replace(world, imu=imu)


@pytest.fixture(scope="module")
def mismatched_bag(tmp_path_factory) -> Path:
    """65 s of the calibration drive (one cycle) with the gyro miscalibrated, no DDS."""
    from sim_robot.ros.sim_bag import write_sim_bag

    world = mismatched_world()
    return write_sim_bag(tmp_path_factory.mktemp("cal") / "bag", 65.0, seed=1, world_config=world,
                         topics=("/imu/data", "/camera/pose"), drive="calibration")


def test_the_simulated_drive_gives_the_true_values_within_their_std(mismatched_bag: Path) -> None:
    fixes, gyro = ekf_calibrate.read_bag(mismatched_bag, "/imu/data", ["/camera/pose"])
    p = calibration.build_problem([(fixes, gyro)], WALK)
    r = calibration.fit(p, (1.0, 0.0))
    assert abs(r.scale - SCALE) < 4.0 * r.formal_std[0]
    assert abs(r.bias - BIAS) < 4.0 * r.formal_std[1]
    assert r.formal_std[0] < 0.002 and r.formal_std[1] < 0.002  # the goals: 0.2 %, 0.002 rad/s


def test_the_command_writes_a_yaml_ekf_node_loads(mismatched_bag: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "calibrated.yaml"
    assert ekf_calibrate.main([str(mismatched_bag), "--params", str(EKF_YAML), "--out", str(out),
                               "--bootstrap", "20"]) == 0
    lines = capsys.readouterr().out.splitlines()
    fitted = {m[1]: (float(m[2]), float(m[3]), m[4]) for m in map(LINE.match, lines) if m}
    assert set(fitted) == {"imu0_yaw_rate_scale", "imu0_yaw_rate_bias"}
    assert fitted["imu0_yaw_rate_scale"][2] == "1" and fitted["imu0_yaw_rate_bias"][2] == "0"
    assert any(line.startswith("residual (RMS, normalised): before ") for line in lines)
    before = parameters_from_yaml(EKF_YAML)
    after = parameters_from_yaml(out)
    assert {k: v for k, v in after.items() if not k.startswith("imu0_yaw_rate_")} == before
    assert after["imu0_yaw_rate_scale"] == pytest.approx(fitted["imu0_yaw_rate_scale"][0], rel=1e-5)
    cfg = parse_ekf_config(after, MODELS)
    imu = next(i for i in cfg.inputs if i.name == "imu0")
    assert imu.settings.yaw_rate_scale == after["imu0_yaw_rate_scale"]
    assert out.read_text().splitlines()[1] == "/**/ekf_node:"  # the same node key


def test_a_bag_without_camera_fixes_exits_2_with_a_message(tmp_path: Path, capsys) -> None:
    from sim_robot.ros.sim_bag import write_sim_bag

    bag = write_sim_bag(tmp_path / "bag", 2.0, seed=1, topics=("/imu/data", "/odometry/dead_wheels"))
    assert ekf_calibrate.main([str(bag), "--params", str(EKF_YAML), "--out", str(tmp_path / "o.yaml")]) == 2
    err = capsys.readouterr().err
    assert "no camera pose fixes" in err and "/camera/pose" in err and "Traceback" not in err
    assert not (tmp_path / "o.yaml").exists()


@pytest.mark.parametrize(("args", "needle"), [
    (["missing_bag"], "missing_bag"),
    (["{bag}", "--imu", "imu3"], "imuN input named imu3"),
    (["{bag}", "--bootstrap", "-1"], "--bootstrap must be >= 0"),
])
def test_bad_input_exits_2_naming_it(mismatched_bag: Path, tmp_path: Path, capsys, args, needle) -> None:
    argv = [a.format(bag=mismatched_bag) for a in args] + ["--params", str(EKF_YAML), "--out",
                                                           str(tmp_path / "o.yaml")]
    assert ekf_calibrate.main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err


def test_the_demo_circle_names_the_scale_and_fits_the_bias_alone(tmp_path: Path, capsys) -> None:
    """20 s of the demo's circle: one direction at 0.6 ± 0.15 rad/s, the scale's formal std is above
    MAX_STD, so it is named and kept; the bias, fitted alone, takes up the scale's error too."""
    from sim_robot.ros.sim_bag import write_sim_bag

    world = mismatched_world()
    bag = write_sim_bag(tmp_path / "bag", 20.0, seed=1, world_config=world,
                        topics=("/imu/data", "/camera/pose"))
    out = tmp_path / "o.yaml"
    argv = [str(bag), "--params", str(EKF_YAML), "--out", str(out), "--bootstrap", "10"]
    assert ekf_calibrate.main(argv) == 0
    text = capsys.readouterr().out
    assert "imu0_yaw_rate_scale: not observable from these drives" in text and "left unchanged" in text
    after = parameters_from_yaml(out)
    assert "imu0_yaw_rate_scale" not in after
    # g = s·ω + b with s held at 1: the bias absorbs (s - 1)·ω at the drive's turn rates (0.45-0.75
    # rad/s), give or take 5 σ of its fit (σ about 0.001 rad/s here)
    low, high = BIAS + (SCALE - 1.0) * 0.45 - 0.005, BIAS + (SCALE - 1.0) * 0.75 + 0.005
    assert low < after["imu0_yaw_rate_bias"] < high


def test_a_drive_too_short_for_either_exits_2_naming_both(tmp_path: Path, capsys) -> None:
    """3 s: about 1.8 rad of turning seen through a few fixes of 4° std, far from the 1 % and
    0.01 rad/s that MAX_STD asks for; a fit would run anywhere, so nothing is fitted or written."""
    from sim_robot.ros.sim_bag import write_sim_bag

    bag = write_sim_bag(tmp_path / "bag", 3.0, seed=1, world_config=mismatched_world(),
                        topics=("/imu/data", "/camera/pose"))
    out = tmp_path / "o.yaml"
    assert ekf_calibrate.main([str(bag), "--params", str(EKF_YAML), "--out", str(out)]) == 2
    captured = capsys.readouterr()
    for name in ("imu0_yaw_rate_scale", "imu0_yaw_rate_bias"):
        assert f"{name}: not observable" in captured.out
    assert "nothing can be fitted" in captured.err and "Traceback" not in captured.err
    assert not out.exists()
