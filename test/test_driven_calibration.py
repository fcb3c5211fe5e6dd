"""The driven wheels' radius and turning lever (tools/driven_calibration.py through the pods' fit,
tools/pod_calibration.py) on synthetic drives, and ekf_calibrate on short simulated bags of the
mecanum and the tank world (docs/models.md, "Driven-wheel calibration")."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from helpers.ros_helpers import REPO
from test_pod_calibration import WALK, assert_jacobian_is_the_difference, synthetic, tags_camera, twist

from ekf_localization.models import differential, mecanum
from ekf_localization.models.registry import MODELS
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import parameters_from_yaml
from ekf_localization.tools import ekf_calibrate
from ekf_localization.tools import pod_calibration as pc
from ekf_localization.tools.driven_calibration import DrivenGeometry, lever_parameters
from ekf_localization.tools.pod_calibration import PodData

R0 = 0.048  # config/ekf_driven_wheels.yaml's wheel radius
MEC = DrivenGeometry("mecanum", R0, R0, 0.348)  # the file: L + l = 0.168 + 0.18
MEC_TRUE = DrivenGeometry("mecanum", R0, R0 * 1.03, 0.348 * 0.97, 0.9)  # strafes 90 % of eq. 23's
DIFF = DrivenGeometry("differential", R0, R0, 0.2)
DIFF_TRUE = DrivenGeometry("differential", R0, R0 * 0.97, 0.2 * 1.03)
NOISE = (0.0, 1.0e-6)  # config/ekf_driven_wheels.yaml's a, b
LINE = re.compile(r"^(\S+) (\S+) ± (\S+) \(was (\S+)\)$")


def no_sideways(t: np.ndarray, pushes: bool = True) -> np.ndarray:
    """The pods' test drive without ẏ: what a differential drive can do."""
    v = twist(t, pushes)
    v[:, 1] = 0.0
    return v


def problem(*pairs) -> pc.Problem:
    return pc.build_problem(list(pairs), WALK, NOISE)


def test_the_rows_are_the_models_driven_wheel_rows() -> None:
    """r₀ × the model's rows at (r, L, l) with L + l = k: what the joint handler fuses, in m/s at r₀."""
    g = DrivenGeometry("mecanum", R0, 0.05, 0.3)
    np.testing.assert_allclose(g.encoders_from_twist / R0,
                               mecanum.driven_wheel_rows("mecanum", 0.05, 0.1, 0.2)[:, 3:6], rtol=1e-12)
    g = DrivenGeometry("differential", R0, 0.05, 0.21)
    H = differential.driven_wheel_rows("differential", 0.05, 0.168, 0.21)
    np.testing.assert_allclose(g.encoders_from_twist[:, [0, 2]] / R0, H[:, [2, 4]], rtol=1e-12)  # [v ω]


def test_the_strafe_scale_divides_the_rows_on_y() -> None:
    """The robot strafes σ × eq. 23's: the wheels turn 1/σ as fast per m/s of ẏ; ẋ and θ̇ unchanged."""
    one = DrivenGeometry("mecanum", R0, 0.05, 0.3)
    M1, M = one.encoders_from_twist, dataclasses.replace(one, strafe=0.9).encoders_from_twist
    np.testing.assert_allclose(M[:, 1], M1[:, 1] / 0.9, rtol=1e-12)
    np.testing.assert_array_equal(M[:, [0, 2]], M1[:, [0, 2]])
    assert len(DIFF.vector) == 2 and len(MEC.vector) == 3 and MEC.strafe == 1.0
    with pytest.raises(ValueError, match="strafe"):
        DrivenGeometry("differential", R0, R0, 0.2, 0.9)


@pytest.mark.parametrize("geom", [MEC_TRUE, DIFF_TRUE])
def test_the_rows_jacobian_is_the_finite_difference(geom: DrivenGeometry) -> None:
    J, p = geom.rows_jacobian(), geom.vector
    for m in range(len(p)):
        step = np.zeros(len(p))
        step[m] = 1e-7
        plus, minus = geom.from_vector(p + step), geom.from_vector(p - step)
        fd = (plus.encoders_from_twist - minus.encoders_from_twist) / 2e-7
        np.testing.assert_allclose(J[:, :, m], fd, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize(("start", "true", "drive"), [(MEC, MEC_TRUE, twist), (DIFF, DIFF_TRUE, no_sideways)])
def test_noise_free_data_give_the_geometry_exactly(start, true, drive) -> None:
    r = pc.fit(problem(synthetic(30.0, true, drive=drive)), start, np.ones(len(start.vector), bool))
    np.testing.assert_allclose(r.pods.vector, true.vector, rtol=1e-8)
    assert r.rms < 1e-6


def test_the_fits_jacobian_is_the_finite_difference_with_four_wheels() -> None:
    """Mecanum's four wheels over three unknowns: the least-squares inverse's derivative has a
    second term on the wheels' misfit, which noisy encoders make non-zero."""
    fixes, wheels = synthetic(30.0, MEC_TRUE, fix_sd=0.01, seed=2)
    rng = np.random.default_rng(4)
    p = problem((fixes, PodData(wheels.t, wheels.d + 1e-3 * rng.standard_normal(wheels.d.shape))))
    f = pc._Fit(p, MEC, np.ones(3, bool))
    x = np.r_[pc.initial_poses(p, MEC).ravel(), MEC.vector] + 1e-4 * rng.standard_normal(3 * p.n + 3)
    assert_jacobian_is_the_difference(f, x, [*range(6), 3 * p.n, 3 * p.n + 1, 3 * p.n + 2], 1e-7, 1e-5)


@pytest.mark.parametrize(("start", "true", "drive"), [(MEC, MEC_TRUE, twist), (DIFF, DIFF_TRUE, no_sideways)])
def test_noisy_fixes_give_the_geometry_within_its_formal_std(start, true, drive) -> None:
    """1 cm and 0.6° camera noise: both within 4 σ of the formal std, and the bootstrap near it."""
    p = problem(synthetic(52.0, true, fix_sd=0.01, seed=3, drive=drive))
    free, _ = pc.observable(p, start, None, start.limits())
    assert free.all()
    r = pc.fit(p, start, free)
    assert np.all(np.abs(r.pods.vector - true.vector) < 4.0 * r.formal_std)
    boot = pc.bootstrap_std(p, r, free, 20, seed=0)
    assert np.all((0.5 * r.formal_std < boot) & (boot < 2.0 * r.formal_std))


def test_turning_in_place_holds_one_and_fits_the_ratio() -> None:
    """Turning alone shows the lever per radius k/r: one of the two is held, the other takes the
    ratio."""
    p = problem(synthetic(52.0, MEC_TRUE, fix_sd=0.01, seed=3, pushes=False))
    free, std = pc.observable(p, MEC, None, MEC.limits())
    assert free.sum() == 1 and np.all(std[~free] > MEC.limits()[~free])
    r = pc.fit(p, MEC, free)
    ratio = r.pods.lever / r.pods.radius
    assert ratio == pytest.approx(MEC_TRUE.lever / MEC_TRUE.radius, rel=2e-3)


def test_a_drive_without_sideways_motion_holds_the_strafe_scale() -> None:
    """Pushes forward and turns only: r and k are fitted, σ is held at the file's value."""
    p = problem(synthetic(30.0, MEC_TRUE, fix_sd=0.01, seed=3, drive=no_sideways))
    free, std = pc.observable(p, MEC, None, MEC.limits())
    assert free.tolist() == [True, True, False] and std[2] > MEC.limits()[2]
    r = pc.fit(p, MEC, free)
    assert r.pods.strafe == 1.0
    assert r.pods.radius == pytest.approx(MEC_TRUE.radius, rel=3e-3)


def test_mecanum_keeps_the_ratio_of_l_and_w() -> None:
    assert lever_parameters("joint0", "mecanum", 0.168, 0.18, 0.348 * 1.1) == pytest.approx(
        {"joint0_half_wheelbase": 0.168 * 1.1, "joint0_half_track": 0.18 * 1.1})
    assert lever_parameters("joint0", "differential", 0.168, 0.2, 0.21) == {"joint0_half_track": 0.21}


# --- ekf_calibrate on simulated bags ------------------------------------------------------------------

DRIVEN_YAML = REPO / "config" / "ekf_driven_wheels.yaml"
TANK_JOINT = """    joint0: joint_states
    joint0_geometry: differential
    joint0_names: [wheel_rear_left, wheel_rear_right]
    joint0_wheel_radius: 0.048
    joint0_half_track: 0.2
    joint0_speed_variance_floor: 1.0e-6

"""


def tank_params(tmp_path: Path) -> Path:
    """config/ekf_tank.yaml with the tank's wheels as a differential joint0."""
    out = tmp_path / "ekf_tank_joint.yaml"
    text = (REPO / "config" / "ekf_tank.yaml").read_text()
    out.write_text(text.replace("    pose0: camera/pose\n", TANK_JOINT + "    pose0: camera/pose\n", 1))
    return out


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """40 s calibration drives of the mecanum and the tank world, made once: {case: (bag, truth)}."""
    pytest.importorskip("rosbags")
    root = tmp_path_factory.mktemp("driven")
    return {case: driven_bag(root / case, sim, 40.0)
            for case, sim in (("mecanum", "sim.yaml"), ("tank", "sim_tank.yaml"))}


def driven_bag(tmp_path: Path, sim: str, seconds: float):
    """A calibration drive of ``sim``'s world with the true radius 3 % more and the track 3 % less
    than the files say, and a camera as good as tags; (bag, (true radius, true lever))."""
    from sim_robot.ros.sim_bag import JOINT_STATES, demo_world, write_sim_bag
    from sim_robot.world.drives import TankKinematics

    world, names = demo_world(REPO / "config" / sim, driven_joint_states=True)
    if sim == "sim.yaml":
        k = world.mecanum
        true = dataclasses.replace(k, wheel_radius=k.wheel_radius * 1.03, half_length=k.half_length * 0.97,
                                   half_width=k.half_width * 0.97)
        world = dataclasses.replace(world, mecanum=true)
        truth = (true.wheel_radius, true.half_length + true.half_width)
    else:
        t = world.tank
        world = dataclasses.replace(world, tank=TankKinematics(t.wheel_radius * 1.03, t.half_track * 0.97))
        truth = (t.wheel_radius * 1.03, t.half_track * 0.97)
    bag = write_sim_bag(tmp_path / "bag", seconds, seed=2, world_config=tags_camera(world),
                        drive="calibration", topics=("/camera/pose", JOINT_STATES), driven_joints=names)
    return bag, truth


@pytest.mark.parametrize("case", ["mecanum", "tank"])
def test_the_command_fits_the_driven_wheels_of_a_simulated_drive(case: str, bags, tmp_path: Path,
                                                                 capsys) -> None:
    bag, truth = bags[case]
    params = DRIVEN_YAML if case == "mecanum" else tank_params(tmp_path)
    out = tmp_path / "cal.yaml"
    assert ekf_calibrate.main([str(bag), "--params", str(params), "--out", str(out), "--bootstrap", "8"]) == 0
    lines = capsys.readouterr().out.splitlines()
    fitted = {m[1]: (float(m[2]), float(m[3]), m[4]) for m in map(LINE.match, lines) if m}
    lever = "joint0_half_wheelbase+joint0_half_track" if case == "mecanum" else "joint0_half_track"
    assert fitted["joint0_wheel_radius"][2] == "0.048"
    after = parameters_from_yaml(out)
    for name, true in zip(("joint0_wheel_radius", lever), truth, strict=True):
        value, std, _ = fitted[name]
        # 5 σ of the bootstrap std (8 replicates: the std itself is known to about ±25 %)
        assert abs(value - true) < 5.0 * std, (name, value, true, std)
    got = after["joint0_half_wheelbase"] + after["joint0_half_track"] if case == "mecanum" \
        else after["joint0_half_track"]
    assert got == pytest.approx(fitted[lever][0], rel=1e-5)
    assert after["joint0_wheel_radius"] == pytest.approx(fitted["joint0_wheel_radius"][0], rel=1e-5)
    parse_ekf_config(after, MODELS)


def test_a_bag_without_wheel_joints_exits_2_naming_the_wheels(tmp_path: Path, capsys) -> None:
    """The mecanum params and a bag with the camera only (no gyro, no wheels): nothing to fit."""
    pytest.importorskip("rosbags")
    from sim_robot.ros.sim_bag import write_sim_bag

    bag = write_sim_bag(tmp_path / "bag", 2.0, seed=1, topics=("/camera/pose",))
    out = tmp_path / "o.yaml"
    assert ekf_calibrate.main([str(bag), "--params", str(DRIVEN_YAML), "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert "joint0 wheels:" in captured.out and "no joint positions" in captured.out
    assert "nothing can be fitted" in captured.err and "Traceback" not in captured.err
    assert not out.exists()


def test_a_wheel_with_the_wrong_direction_exits_2(bags, tmp_path: Path, capsys) -> None:
    """The tank's right wheel read backwards: driving straight looks like turning; one line, exit 2."""
    params = tank_params(tmp_path)
    line = "    joint0_half_track: 0.2\n"
    params.write_text(params.read_text().replace(line, line + "    joint0_directions: [1.0, -1.0]\n"))
    out = tmp_path / "o.yaml"
    assert ekf_calibrate.main([str(bags["tank"][0]), "--params", str(params), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ekf_calibrate: joint0") and "nothing written" in err and "Traceback" not in err
    assert not out.exists()


def test_turning_in_place_names_the_one_it_holds(tmp_path: Path, capsys) -> None:
    """15 s of the calibration drive is a turn in place: k/r only, so one of the two is named and
    left unchanged and the other is fitted (exit 0)."""
    pytest.importorskip("rosbags")
    bag, _ = driven_bag(tmp_path / "turn", "sim_tank.yaml", 15.0)
    out = tmp_path / "cal.yaml"
    assert ekf_calibrate.main([str(bag), "--params", str(tank_params(tmp_path)), "--out", str(out),
                               "--bootstrap", "4"]) == 0
    lines = capsys.readouterr().out.splitlines()
    held = [n for n in ("joint0_wheel_radius", "joint0_half_track")
            if any(line.startswith(f"{n}: not observable from these drives") for line in lines)]
    fitted = [m[1] for m in map(LINE.match, lines) if m and m[1].startswith("joint0")]
    file_values = {"joint0_wheel_radius": 0.048, "joint0_half_track": 0.2}
    assert len(held) == 1 and len(fitted) == 1 and set(held + fitted) == set(file_values)
    assert parameters_from_yaml(out)[held[0]] == file_values[held[0]]
