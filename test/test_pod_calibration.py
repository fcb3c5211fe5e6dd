"""The dead-wheel pods' fit (tools/pod_calibration.py) on synthetic drives, and ekf_calibrate's pod
part on a short simulated bag (docs/models.md, "Dead-wheel pods")."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from helpers.ros_helpers import REPO

from ekf_localization.models.registry import MODELS
from ekf_localization.models.sensors.dead_wheels import PodGeometry
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import parameters_from_yaml
from ekf_localization.tools import ekf_calibrate
from ekf_localization.tools import pod_calibration as pc
from ekf_localization.tools.pod_calibration import PodData, PoseFixes

TRUE = PodGeometry((0.19, -0.15, 0.12), (0.02, -0.03, 1.55), (1.03, 0.97, 1.02))
NOMINAL = PodGeometry.symmetric(0.17, 0.1)
WALK = (1.29e-6, 1.29e-6, 1e-5)  # config/ekf_joint_states.yaml's x, y, yaw process noise
NOISE = (0.002, 6.45e-7)  # its pods' a, b
JOINT_YAML = REPO / "config" / "ekf_joint_states.yaml"
LINE = re.compile(r"^(\S+) (\S+) ± (\S+) \(was (\S+)\)$")


def twist(t: np.ndarray, pushes: bool = True) -> np.ndarray:
    """Turns at 1 and -0.5 rad/s, pushes forward, sideways and diagonally (or none), repeating."""
    ph = t % 26.0
    conds = [ph < 9, ph < 12, ph < 15, ph < 20, ph < 23]
    on = 1.0 if pushes else 0.0
    return np.column_stack([np.select(conds, [0, 0.3 * on, 0, 0, 0.2 * on], 0.0),
                            np.select(conds, [0, 0, 0.3 * on, 0, -0.2 * on], 0.0),
                            np.select(conds, [1.0, 0, 0, -0.5, 0.3], 0.0)])


def synthetic(seconds: float, pods: PodGeometry = TRUE, fix_sd: float = 0.0, seed: int = 0,
              pushes: bool = True, drive=twist) -> tuple[PoseFixes, PodData]:
    """Pods read every 10 ms and fixes every 50 ms of a path integrated the way the fit integrates
    (the heading at each step's middle), so noise-free data fit exactly; ``drive(t, pushes)``:
    the body twist (any encoder geometry of the fit: ``pods``)."""
    rng = np.random.default_rng(seed)
    dt = 0.01
    t = np.arange(int(round(seconds / dt)) + 1) * dt
    db = drive(t, pushes)[:-1] * dt
    phi = np.r_[0.0, np.cumsum(db[:, 2])]
    mid = phi[:-1] + 0.5 * db[:, 2]
    c, s = np.cos(mid), np.sin(mid)
    xy = np.vstack([np.zeros(2), np.cumsum(np.column_stack([c * db[:, 0] - s * db[:, 1],
                                                            s * db[:, 0] + c * db[:, 1]]), axis=0)])
    pose = np.column_stack([xy, phi])
    d = np.vstack([np.zeros(pods.count), np.cumsum(db @ pods.encoders_from_twist.T, axis=0)])
    k = np.arange(0, len(t), 5)
    z = pose[k] + fix_sd * rng.standard_normal((len(k), 3))
    z[:, 2] = np.remainder(z[:, 2] + math.pi, 2 * math.pi) - math.pi
    return PoseFixes(t[k], z, np.full((len(k), 3), max(fix_sd, 1e-3) ** 2)), PodData(t, d)


def problem(*pairs) -> pc.Problem:
    return pc.build_problem(list(pairs), WALK, NOISE)


def assert_jacobian_is_the_difference(f: pc._Fit, x: np.ndarray, columns, step: float, tol: float) -> None:
    """Each of ``columns`` of the fit's sparse Jacobian at ``x`` against central differences of
    ``step``, within ``tol`` of the column's largest entry (at least 1)."""
    J = f.jacobian(x).toarray()
    for i in columns:
        dx = np.zeros_like(x)
        dx[i] = step
        fd = (f.residuals(x + dx) - f.residuals(x - dx)) / (2 * step)
        np.testing.assert_allclose(J[:, i], fd, atol=tol * max(1.0, np.abs(fd).max()))


def test_noise_free_data_give_the_pods_exactly() -> None:
    r = pc.fit(problem(synthetic(30.0)), NOMINAL, np.ones(9, bool))
    np.testing.assert_allclose(r.pods.vector, TRUE.vector, atol=1e-8)
    assert r.rms < 1e-6


def test_the_jacobian_is_the_finite_difference() -> None:
    p = problem(synthetic(30.0, fix_sd=0.01, seed=2))
    free = np.ones(9, bool)
    f = pc._Fit(p, NOMINAL, free)
    rng = np.random.default_rng(1)
    x = np.r_[pc.initial_poses(p, NOMINAL).ravel(), NOMINAL.vector] + 1e-3 * rng.standard_normal(3 * p.n + 9)
    assert_jacobian_is_the_difference(f, x, [*range(12), *range(3 * p.n - 6, 3 * p.n + 9)], 1e-6, 1e-6)


def test_noisy_fixes_give_the_pods_within_their_formal_std() -> None:
    """1 cm and 0.6° camera noise: every parameter within 4 σ of its formal std (a 1-in-16000 miss
    per parameter for a correct std), and the bootstrap near the formal std."""
    p = problem(synthetic(52.0, fix_sd=0.01, seed=3))
    free, _ = pc.observable(p, NOMINAL)
    assert free.all()
    r = pc.fit(p, NOMINAL, free)
    assert np.all(np.abs(r.pods.vector - TRUE.vector) < 4.0 * r.formal_std)
    boot = pc.bootstrap_std(p, r, free, 20, seed=0)
    assert np.array_equal(boot, pc.bootstrap_std(p, r, free, 20, seed=0))  # deterministic
    # 20 replicates estimate a std to about ±16 %; a factor 2 either way is a wrong model
    assert np.all((0.5 * r.formal_std < boot) & (boot < 2.0 * r.formal_std))


def test_a_drive_without_pushes_holds_what_only_translation_shows() -> None:
    """Turning in place shows each pod's k·o (its reading per radian) but not k or α apart: the
    scales or offsets that cannot be separated are held, and what is fitted is still right."""
    p = problem(synthetic(52.0, fix_sd=0.01, seed=3, pushes=False))
    free, std = pc.observable(p, NOMINAL)
    assert not free.all() and np.all(std[~free] > pc.limits(3)[~free])
    assert not free[3:6].any()  # no angle: a pod's direction shows only when the robot moves
    r = pc.fit(p, NOMINAL, free)
    k_o = r.pods.vector[6:] * r.pods.vector[:3]
    np.testing.assert_allclose(k_o, np.array(TRUE.scales) * TRUE.offsets, atol=2e-3)


def test_a_new_bag_or_a_gap_in_the_encoders_breaks_the_chain() -> None:
    a, b = synthetic(10.0), synthetic(10.0)
    p = problem(a, b)
    assert p.n == len(a[0].t) + len(b[0].t) and p.link.sum() == p.n - 2
    fixes, pods = synthetic(10.0)
    keep = (pods.t < 4.0) | (pods.t > 5.0)
    p = problem((fixes, PodData(pods.t[keep], pods.d[keep])))
    assert p.link.sum() < len(fixes.t) - 1 - 15  # the fixes inside the second's gap join nothing


# --- ekf_calibrate on a simulated bag ---------------------------------------------------------------

def mismatched_world():
    """The demo's world with the pods 2 cm and 3 % off and a camera as good as tags (σ 6 mm at 2 m)."""
    from sim_robot.ros.sim_bag import demo_world_config

    world = demo_world_config()
    pods = PodGeometry((0.19, -0.19, 0.12), (0.0, 0.0, 0.5 * math.pi), (1.03, 0.97, 1.03))
    return dataclasses.replace(tags_camera(world),
                               dead_wheels=dataclasses.replace(world.dead_wheels, pods=pods)), pods


def tags_camera(world):
    """``world`` with a camera as good as tags (σ 6 mm and 0.3° at 2 m)."""
    camera = dataclasses.replace(world.camera, position_noise=dataclasses.replace(
        world.camera.position_noise, distance_variance_coeff=1e-5), yaw_noise=dataclasses.replace(
        world.camera.yaw_noise, distance_variance_coeff=1.2e-5, variance_floor=1e-6))
    return dataclasses.replace(world, camera=camera)


def test_the_bootstrap_blocks_last_as_long_as_the_residuals_stay_correlated() -> None:
    """White residuals: blocks of one fix; an AR(1) with 0.8 per fix: several fixes, at most the
    longest given; a fit's residuals of white camera errors (negatively correlated over the
    poses' smoothing): one fix."""
    rng = np.random.default_rng(0)
    assert pc.correlated_run(rng.standard_normal((2000, 3)), 100) == 1
    ar = np.zeros((2000, 3))
    for i, e in enumerate(rng.standard_normal((1999, 3))):
        ar[i + 1] = 0.8 * ar[i] + e
    assert 5 <= pc.correlated_run(ar, 100) < 100 and pc.correlated_run(ar, 4) == 4
    p = problem(synthetic(26.0, fix_sd=0.01, seed=3))
    r = pc.fit(p, NOMINAL, np.ones(9, bool))
    z = pc._Fit(p, r.pods, np.zeros(9, bool)).residuals(r.poses.ravel())[:3 * p.n].reshape(-1, 3)
    assert pc.correlated_run(z, 100) == 1


def test_the_command_fits_the_pods_of_a_simulated_drive(tmp_path: Path, capsys) -> None:
    pytest.importorskip("rosbags")
    from sim_robot.ros.sim_bag import JOINT_STATES, write_sim_bag

    world, pods = mismatched_world()
    bag = write_sim_bag(tmp_path / "bag", 65.0, seed=2, world_config=world, drive="calibration",
                        topics=("/imu/data", "/camera/pose", JOINT_STATES))
    out = tmp_path / "cal.yaml"
    argv = [str(bag), "--params", str(JOINT_YAML), "--out", str(out), "--bootstrap", "8"]
    assert ekf_calibrate.main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    fitted = {m[1]: (float(m[2]), float(m[3]), m[4]) for m in map(LINE.match, lines) if m}
    assert fitted["joint0_pod_offsets[0]"][2] == "0.17" and fitted["joint0_pod_scales[1]"][2] == "1"
    assert any(line.startswith("pods residual (RMS, normalised): before ") for line in lines)
    after = parameters_from_yaml(out)
    truth = pods.vector
    for i, field in enumerate(("offsets", "angles", "scales")):
        for j in range(3):
            name = f"joint0_pod_{field}[{j}]"
            if name in fitted:
                value, std, _ = fitted[name]
                assert after[f"joint0_pod_{field}"][j] == pytest.approx(value, rel=1e-5)
                # 5 σ of the bootstrap std (8 replicates: the std itself is known to about ±25 %)
                assert abs(value - truth[3 * i + j]) < 5.0 * std, name
    assert {"joint0_pod_offsets", "joint0_pod_scales"} <= set(after)
    parse_ekf_config(after, MODELS)


def test_a_bag_without_joint_states_names_the_pods_and_fits_the_imu(tmp_path: Path, capsys) -> None:
    pytest.importorskip("rosbags")
    from sim_robot.ros.sim_bag import write_sim_bag

    world, _ = mismatched_world()
    bag = write_sim_bag(tmp_path / "bag", 65.0, seed=2, world_config=world, drive="calibration",
                        topics=("/imu/data", "/camera/pose"))
    out = tmp_path / "cal.yaml"
    argv = [str(bag), "--params", str(JOINT_YAML), "--out", str(out), "--bootstrap", "4"]
    assert ekf_calibrate.main(argv) == 0
    text = capsys.readouterr().out
    assert "joint0 pods:" in text and "no joint positions" in text and "left unchanged" in text
    assert "joint0_pod_offsets" not in parameters_from_yaml(out)


def test_params_with_nothing_to_calibrate_exit_2(tmp_path: Path, capsys) -> None:
    pytest.importorskip("rosbags")
    from sim_robot.ros.sim_bag import write_sim_bag

    bag = write_sim_bag(tmp_path / "bag", 2.0, seed=1, topics=("/camera/pose",))
    argv = [str(bag), "--params", str(JOINT_YAML), "--out", str(tmp_path / "o.yaml"), "--joint", "joint7"]
    assert ekf_calibrate.main(argv) == 2
    err = capsys.readouterr().err
    assert "no dead-wheel jointN input named joint7" in err and "Traceback" not in err


def test_two_pods_on_a_state_without_lateral_velocity_fit_offsets_and_scales() -> None:
    """Two parallel pods (a differential robot's): ẋ and θ̇ from their readings, ẏ = 0."""
    two = PodGeometry((0.19, -0.15), (0.0, 0.0), (1.03, 0.97))
    t = np.arange(3001) * 0.01
    start = PodGeometry.symmetric(0.17, 0.1, 2)
    free = np.array([True, True, False, False, True, True])
    # a differential drive cannot move sideways: rebuild the data from a drive without ẏ
    dt = 0.01
    db = twist(t)[:-1] * dt
    db[:, 1] = 0.0
    phi = np.r_[0.0, np.cumsum(db[:, 2])]
    mid = phi[:-1] + 0.5 * db[:, 2]
    xy = np.vstack([np.zeros(2), np.cumsum(np.column_stack([np.cos(mid) * db[:, 0], np.sin(mid) * db[:, 0]]),
                                           axis=0)])
    k = np.arange(0, len(t), 5)
    pose = np.column_stack([xy, phi])[k]
    pose[:, 2] = np.remainder(pose[:, 2] + math.pi, 2 * math.pi) - math.pi
    d = np.vstack([np.zeros(2), np.cumsum(db @ two.encoders_from_twist.T, axis=0)])
    p = problem((PoseFixes(t[k], pose, np.full((len(k), 3), 1e-6)), PodData(t, d)))
    r = pc.fit(p, start, free)
    np.testing.assert_allclose(r.pods.vector, two.vector, atol=1e-8)


def test_pods_that_cannot_give_a_twist_exit_2_naming_them(tmp_path: Path, capsys) -> None:
    """Three pods all rolling along x cannot tell ẏ: one line naming the input, nothing written."""
    pytest.importorskip("rosbags")
    from sim_robot.ros.sim_bag import JOINT_STATES, write_sim_bag

    bag = write_sim_bag(tmp_path / "bag", 2.0, seed=1, topics=("/imu/data", "/camera/pose", JOINT_STATES))
    params = tmp_path / "p.yaml"
    line = "    joint0_lateral_offset: 0.1"
    params.write_text(JOINT_YAML.read_text().replace(line, "    joint0_pod_angles: [0.0, 0.0, 0.0]\n" + line))
    out = tmp_path / "o.yaml"
    assert ekf_calibrate.main([str(bag), "--params", str(params), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "joint0: the pods as the params file gives them" in err and "Traceback" not in err
    assert not out.exists()
