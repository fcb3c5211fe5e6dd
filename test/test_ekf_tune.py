"""ekf_tune on short simulated bags (sim world, no DDS): it improves a bad start, works without
truth, writes a loadable tuned.yaml and report, and rejects bad input with exit status 2."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.images import assert_plot_png
from helpers.ros_helpers import REPO

from ekf_localization.models.registry import MODELS
from ekf_localization.ros.ekf_parameters import load_ekf_config, load_ekf_settings, parse_ekf_config
from ekf_localization.ros.parameters import parameters_from_yaml
from ekf_localization.tools import bag_replay, ekf_tune, tune_search, tuning
from ekf_localization.tools.consistency import InnovationLog, mean_chi2_band, negative_log_likelihood
from sim_robot.ros.sim_bag import TOPIC_TYPES, write_sim_bag
from sim_robot.world.world import WorldConfig

DURATION_S = 5.0


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("tune_bags")
    no_truth = tuple(t for t in TOPIC_TYPES if t != "/ground_truth/odom")
    return {"truth": write_sim_bag(root / "truth", DURATION_S, seed=5),
            "no_truth": write_sim_bag(root / "no_truth", DURATION_S, seed=6, topics=no_truth),
            "truth_only": write_sim_bag(root / "truth_only", 1.0, seed=7, topics=("/ground_truth/odom",)),
            # WorldConfig() defaults: no camera latency, so no rewinds (the demo world has them)
            "no_lag": write_sim_bag(root / "no_lag", DURATION_S, seed=5, world_config=WorldConfig())}


def _start_yaml(path: Path, process_noise_factor: float, variance_scale_factor: float) -> Path:
    values = parameters_from_yaml(REPO / "config" / "ekf.yaml")  # its start pose is the sim_bag's
    bad = tuning.scaled_noise(values, parse_ekf_config(values, MODELS), process_noise_factor,
                                variance_scale_factor)
    ekf_tune.write_tuned_yaml(path, bad, "ekf_node", "# test start\n")
    return path


@pytest.fixture(scope="module")
def bad_start(tmp_path_factory) -> Path:
    return _start_yaml(tmp_path_factory.mktemp("start") / "start.yaml", 100.0, 0.01)


def _problem(bag: Path, params: Path, objective: str) -> tuning.Problem:
    values = parameters_from_yaml(params)
    cfg = parse_ekf_config(values, MODELS)
    values = tuning.effective_values(values, cfg)
    knobs = tuning.make_knobs(values, cfg, tuning.DEFAULT_DECADES, {})
    return tuning.Problem(values, knobs, [ekf_tune.load_bag(bag, cfg, "/ground_truth/odom")], objective)


@pytest.mark.slow  # a whole fit from a bad start: a study (CI's slow step)
@pytest.mark.timeout(900)  # about 40 s on an idle 2-core machine; the shared one can be 10x slower
def test_a_badly_started_config_improves(bags, bad_start, tmp_path):
    out = tmp_path / "tuned"
    rc = ekf_tune.main([str(bags["truth"]), "--params", str(bad_start), "--out", str(out),
                        "--jobs", "2", "--max-evals", "24", "--holdout", str(bags["no_truth"])])
    assert rc == 0
    tuned = load_ekf_config(out / "tuned.yaml", MODELS)  # the EKF parameter loader reads it
    problem = _problem(bags["truth"], bad_start, "truth")
    x0 = np.log10([k.start for k in problem.knobs])
    x1 = np.log10([k.get(tuning.effective_values(parameters_from_yaml(out / "tuned.yaml"), tuned))
                   for k in problem.knobs])
    before, after = tuning.score(problem, x0), tuning.score(problem, x1)
    assert after.feasible and after.value("truth") < before.value("truth") - 1.0, (before, after)
    # the start is overconfident (NEES far above its band); the tuned config is much closer
    assert after.nees[0] < 0.5 * before.nees[0], (before, after)
    report = (out / "report.md").read_text()
    for text in ("## Parameters", "odom0_variance_scale", "RMSE xy", "NEES", "Holdout bag 1",
                 "fit1_tuned.png", "holdout1_tuned.png"):
        assert text in report
    # every before/after row has both (rows pair by quantity even when the update counts differ)
    assert not [line for line in report.splitlines() if line.startswith("| mean") and line.endswith("| - |")]
    # consistency.plot_consistency: 9 in wide at 100 dpi, 2.2 in per row (NIS per input part, NEES)
    img = assert_plot_png(out / "fit1_tuned.png", 900)
    assert img.shape[0] % 220 == 0 and img.shape[0] >= 440, img.shape


@pytest.mark.slow  # a whole fit from a bad start: a study (CI's slow step)
@pytest.mark.timeout(900)
def test_likelihood_objective_without_truth(bags, bad_start, tmp_path):
    out = tmp_path / "tuned"
    rc = ekf_tune.main([str(bags["no_truth"]), "--params", str(bad_start), "--out", str(out),
                        "--jobs", "1", "--max-evals", "20"])
    assert rc == 0
    assert "innovation negative log likelihood" in (out / "report.md").read_text()
    tuned = load_ekf_settings(out / "tuned.yaml", MODELS)
    start = load_ekf_settings(bad_start, MODELS)
    nll = {}
    for name, cfg in (("start", start), ("tuned", tuned)):
        log = InnovationLog()
        bag_replay.replay(bags["no_truth"], cfg, innovation_listener=log)
        total, count = negative_log_likelihood(log.per_input())
        nll[name] = total / count
    assert nll["tuned"] < nll["start"] - 1.0, nll
    # the start's covariance scales are 100x too small: the fit raises them
    assert tuned.config.inputs[0].variance_scale > 3 * start.config.inputs[0].variance_scale


def test_innovations_match_the_filter_update_mahalanobis(bags):
    """ν and S from the listener give the NIS the engine's own gate computes."""
    cfg = bag_replay.load_settings(REPO / "config" / "ekf.yaml")
    log = InnovationLog()
    res = bag_replay.replay(bags["no_lag"], cfg, innovation_listener=log)
    per = log.per_input()
    assert set(per) >= {"odom0 twist", "pose0 pose", "imu0 orientation", "imu0 angular_velocity"}
    loc = res.localizer
    assert loc.rewinds == 0  # else the first-pass sums below differ from the final pass
    for key, (nis_sum, count, dim) in loc.nis.items():
        label = key.replace("/", " ")
        assert per[label].dim == dim
        # the Localizer sums the first pass; the log keeps the final pass (no rewinds here)
        assert per[label].nis.size == count
        np.testing.assert_allclose(per[label].nis.sum(), nis_sum, rtol=1e-6)
    lo, hi = mean_chi2_band(3, 1000)
    assert lo < 3.0 < hi and hi - lo < 0.5


def test_a_diverging_candidate_is_infeasible(bags, bad_start, monkeypatch):
    problem = _problem(bags["truth"], bad_start, "truth")
    x0 = np.log10([k.start for k in problem.knobs])
    real_replay = tuning.replay

    def diverging(*a, **kw):
        res = real_replay(*a, **kw)
        res.localizer.predict_failures += 1
        return res

    monkeypatch.setattr(tuning, "replay", diverging)
    s = tuning.score(problem, x0)
    assert not s.feasible
    for objective in ("truth", "rmse", "likelihood"):
        assert s.value(objective) == tuning.INFEASIBLE and math.isfinite(s.value(objective))


def test_ctrl_c_writes_the_best_config_so_far(bags, bad_start, tmp_path, monkeypatch):
    calls = []
    real = tune_search.Tuner.scores

    def interrupted(self, xs):
        if len(calls) == 2:  # after two covariance-matching replays: the best so far is not the start
            raise KeyboardInterrupt
        calls.append(1)
        return real(self, xs)

    monkeypatch.setattr(tune_search.Tuner, "scores", interrupted)
    out = tmp_path / "tuned"
    rc = ekf_tune.main([str(bags["truth"]), "--params", str(bad_start), "--out", str(out), "--jobs", "1"])
    assert rc == 130
    tuned = load_ekf_config(out / "tuned.yaml", MODELS)
    start = load_ekf_config(bad_start, MODELS)
    assert tuned.inputs[0].variance_scale > 3 * start.inputs[0].variance_scale  # not the start


def test_covariance_matching_then_nees_calibration(bags, bad_start):
    """Matching brings every input's NIS per dimension to 1; one common factor on every variance
    then moves the NEES into its band and leaves the estimate (so the RMSE) unchanged."""
    problem = _problem(bags["truth"], bad_start, "truth")
    tuner = tune_search.Tuner(problem, jobs=1, max_evals=40)
    with tuner:
        start = tuner.scores([tuner.best_x])[0]
        x = tuner.match_scales(tuner.best_x.copy())
        matched = tuner.scores([x])[0]
        calibrated_x = tuner.calibrate_nees(x)
        calibrated = tuner.scores([calibrated_x])[0]
    assert max(abs(math.log(v)) for v in start.input_nis.values()) > math.log(10.0), start.input_nis
    assert max(abs(math.log(v)) for v in matched.input_nis.values()) < math.log(1.1), matched.input_nis
    lo, hi = calibrated.nees_band[0]
    assert abs(math.log(calibrated.nees[0] / math.sqrt(lo * hi))) < math.log(1.1), (matched, calibrated)
    # exact but for the transient of the initial covariance, which is not scaled (4% on 5 s,
    # < 0.01% on a 20 s bag)
    assert calibrated.rmse_xy[0] == pytest.approx(matched.rmse_xy[0], rel=0.1)
    assert tuner.best_f <= calibrated.value("truth")


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("ekf_tune: "), err
    return err[0]


def test_bad_inputs_exit_2(bags, bad_start, tmp_path, capsys):
    out = str(tmp_path / "o")
    base = ["--params", str(bad_start), "--out", out]
    assert ekf_tune.main([str(bags["truth_only"])] + base) == 2
    assert "/odometry/dead_wheels" in _one_error_line(capsys)
    assert ekf_tune.main([str(tmp_path / "nothing")] + base) == 2
    assert "no bag" in _one_error_line(capsys)
    broken = tmp_path / "broken.yaml"
    values = yaml.safe_load(bad_start.read_text())
    values["ekf_node"]["ros__parameters"]["frequency"] = -1.0
    broken.write_text(yaml.safe_dump(values))
    assert ekf_tune.main([str(bags["truth"]), "--params", str(broken), "--out", out]) == 2
    assert "frequency" in _one_error_line(capsys)
    for bound in ("odom0_variance_scale=5.0:1.0", "odom0_variance_scale=0.0:1.0",
                  "odom0_variance_scale=1.0:2.0"):  # empty, not positive, excludes the start (0.01)
        assert ekf_tune.main([str(bags["truth"]), *base, "--bound", bound]) == 2
        assert "cannot be met" in _one_error_line(capsys)
    assert ekf_tune.main([str(bags["truth"]), *base, "--bound", "no_such=1.0:2.0"]) == 2
    assert "not a fitted parameter" in _one_error_line(capsys)
    assert ekf_tune.main([str(bags["no_truth"]), *base, "--objective", "truth"]) == 2
    assert "/ground_truth/odom" in _one_error_line(capsys)


def test_bag_replay_report_writes_the_consistency_section(bags, tmp_path):
    out = tmp_path / "replay"
    params = REPO / "config" / "ekf.yaml"
    assert bag_replay.main([str(bags["truth"]), "--params", str(params), "--grid", "--out", str(out),
                            "--report"]) == 0
    text = (out / "report.md").read_text()
    assert "NIS odom0 twist" in text and "NEES pose" in text and "consistency.png" in text
    img = assert_plot_png(out / "consistency.png", 900)
    assert img.shape[0] % 220 == 0 and img.shape[0] >= 440, img.shape


def test_timing_is_fitted_only_on_request():
    """The latency and time constants are the drive's, not noise: only with fit_timing, ±1 decade."""
    values = parameters_from_yaml(REPO / "config" / "ekf.yaml")
    cfg = parse_ekf_config(values, MODELS)
    values = tuning.effective_values(values, cfg)
    assert cfg.control_latency > 0.0
    names = {k.name for k in tuning.make_knobs(values, cfg, tuning.DEFAULT_DECADES, {})}
    assert "control_latency" not in names and "odom0_variance_scale" in names
    knobs = tuning.make_knobs(values, cfg, tuning.DEFAULT_DECADES, {}, fit_timing=True)
    latency = next(k for k in knobs if k.name == "control_latency")
    assert latency.lower == pytest.approx(latency.start / 10.0)
    assert latency.upper == pytest.approx(latency.start * 10.0)


def test_x_and_y_pose_diffusion_are_one_knob_unless_separated():
    """Equal start values of the x and y pose diffusion are fitted as one knob that sets both."""
    values = parameters_from_yaml(REPO / "config" / "ekf.yaml")
    cfg = parse_ekf_config(values, MODELS)
    values = tuning.effective_values(values, cfg)
    knobs = tuning.make_knobs(values, cfg, tuning.DEFAULT_DECADES, {})
    names = [k.name for k in knobs]
    assert "process_noise_covariance[x,y]" in names and "process_noise_covariance[y]" not in names
    out = dict(values)
    knobs[names.index("process_noise_covariance[x,y]")].set(out, 3e-5)
    q = out["process_noise_covariance"]
    assert q[0] == q[tuning.N_FIELDS + 1] == 3e-5
    separate = [k.name for k in tuning.make_knobs(values, cfg, tuning.DEFAULT_DECADES, {},
                                                    tie_position=False)]
    assert {"process_noise_covariance[x]", "process_noise_covariance[y]"} <= set(separate)
    values["process_noise_covariance"] = list(q)
    values["process_noise_covariance"][0] = 1e-5  # unequal start: fitted separately
    unequal = [k.name for k in tuning.make_knobs(values, cfg, tuning.DEFAULT_DECADES, {})]
    assert "process_noise_covariance[y]" in unequal


def test_nis_spread_penalty_holds_inputs_together_and_ignores_the_common_level():
    consistent = {"odom0": 1.0, "pose0": 1.2, "imu0": 0.9}
    assert tuning.nis_spread_penalty(consistent) == 0.0
    camera_off = {"odom0": 1.0, "pose0": 1e-3, "imu0": 0.9}  # a camera switched off by its scale
    assert tuning.nis_spread_penalty(camera_off) > 10.0
    scaled = {k: 7.0 * v for k, v in camera_off.items()}  # every variance / 7: the same spread
    assert tuning.nis_spread_penalty(scaled) == pytest.approx(tuning.nis_spread_penalty(camera_off))
    assert tuning.nis_spread_penalty({"odom0": 50.0}) == 0.0
    s = tuning.Score(True, rmse_xy=[0.01], nees=[3.0], nees_band=[(2.0, 4.2)], input_nis=camera_off)
    assert s.value("rmse") == pytest.approx(math.log(0.01) + tuning.nis_spread_penalty(camera_off))


def test_coordinate_search_follows_a_flat_direction_and_drops_insensitive_knobs(monkeypatch):
    """The likelihood stage moves a knob whose objective slope is tiny (0.003 per decade, as the
    pose diffusion's) by whole decades to its minimum, and stops trying knobs that change nothing."""
    values = parameters_from_yaml(REPO / "config" / "ekf.yaml")
    cfg = parse_ekf_config(values, MODELS)
    values = tuning.effective_values(values, cfg)
    knobs = tuning.make_knobs(values, cfg, tuning.DEFAULT_DECADES, {})
    problem = tuning.Problem(values, knobs, [], "likelihood")
    i_xy = [k.name for k in knobs].index("process_noise_covariance[x,y]")
    x0 = np.log10([k.start for k in knobs])
    target = x0[i_xy] - 3.0

    def fake_score(_problem, x, _innovations=None):
        return tuning.Score(True, nll_per_input=0.003 * abs(x[i_xy] - target),
                            input_nis={inp.name: 1.0 for inp in cfg.inputs})

    monkeypatch.setattr(tune_search, "score", fake_score)
    tuner = tune_search.Tuner(problem, jobs=1, max_evals=200)
    with tuner:
        x = tuner.pattern_search(x0.copy(), "likelihood")
    assert abs(x[i_xy] - target) <= 0.5
    others = [i for i in range(len(knobs)) if i != i_xy]
    assert np.array_equal(x[others], x0[others])
    n_moves = 2 * sum(1 for k in knobs if not k.parameter.endswith("_variance_scale"))
    assert tuner.evals < 2 * n_moves  # only the first batch tries every knob
    assert "coordinate search" in tuner.stages[-1]


def test_nees_band_counts_effective_samples():
    """The band of a 20 s mean NEES is that of 0.3 independent samples per second (6), not 20."""
    from ekf_localization.tools.consistency import Nees

    nees = Nees(np.zeros(1000, np.int64), np.full(1000, 3.0), 20.0)
    lo, hi = nees.band
    assert (lo, hi) == pytest.approx(mean_chi2_band(3, 6.0))
    assert lo == pytest.approx(1.37, abs=0.01) and hi == pytest.approx(5.25, abs=0.01)
    assert mean_chi2_band(3, 5.5)[1] > mean_chi2_band(3, 6.0)[1]  # fractional counts interpolate
