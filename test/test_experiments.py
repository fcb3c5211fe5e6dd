"""Reduced runs of the seeds' experiments (few trials): the qualitative results that must hold.

The full runs (100 trials, figures, docs/results.md) come from ``ekf_experiments``; here
the same code runs with few trials and seeded RNGs.
"""

from __future__ import annotations

import numpy as np
import pytest

from seed_experiments.experiments import (
    cli,
    seed000_estimators,
    seed000_tables,
    seed002_comparison,
    seed004_kf2d,
)
from seed_experiments.experiments.seed000_sim import STAT_COLUMNS


@pytest.fixture(scope="module")
def tables():
    return seed000_tables.compute(n_trials=6, seed=11, record_trials=0, show_progress=False)


def test_every_trial_finishes_the_path(tables):
    assert np.all(tables.done_ns > 0)
    assert np.all(tables.steps > 1000)  # more than 10 s of 10 ms steps each
    for name in tables.names:
        per_trial = tables.per_trial_rmse(name)
        # the (x, y) column is the RMSE of the position error norm: √(RMSE_x² + RMSE_y²) per trial
        np.testing.assert_allclose(per_trial["xy"], np.hypot(per_trial["x"], per_trial["y"]), rtol=1e-12)
        m = tables.mean_rmse(name)
        assert all(np.isfinite(v) for v in m.values()), (name, m)
        # inches and rad: every estimator tracks the robot (no divergence: well under 2 ft and
        # 0.5 rad), and none is exact (the truth and the sensors are noisy)
        assert 0.1 < m["xy"] < 24.0 and 0.01 < m["theta"] < 0.5, (name, m)


def test_fusion_beats_each_input_on_velocity(tables):
    fused = tables.mean_rmse("model + odo")
    model = tables.mean_rmse("model")
    odo = tables.mean_rmse("odo")
    for key in ("vx", "vy", "vtheta"):
        assert fused[key] < model[key], key
        assert fused[key] < odo[key], key
    # the model's velocity error is the truth's white velocity noise per 1 ms tick: √0.45 (eq. 26)
    for key in ("vx", "vy", "vtheta"):
        assert model[key] == pytest.approx(np.sqrt(0.45), rel=0.05)


def test_camera_cuts_position_rmse(tables):
    without = tables.mean_rmse("model + odo")
    with_cam = tables.mean_rmse("model + odo + camera")
    assert with_cam["xy"] < 0.5 * without["xy"]
    assert with_cam["theta"] < without["theta"]


def test_paper_anomaly_and_its_fix(tables):
    """The paper's fused position RMSE exceeds the model's; predicting at the truth's tick fixes it."""
    model = tables.mean_rmse("model")
    fused = tables.mean_rmse("model + odo")
    improved = tables.mean_rmse(seed000_estimators.IMPROVED.name)
    assert fused["xy"] > model["xy"]
    assert improved["xy"] < fused["xy"]
    assert improved["xy"] < 1.1 * model["xy"]
    for key in ("vx", "vy", "vtheta"):  # and it keeps the fusion's velocity accuracy
        assert improved[key] == pytest.approx(fused[key], rel=0.05)
    cam = tables.mean_rmse("model + odo + camera")
    improved_cam = tables.mean_rmse(seed000_estimators.IMPROVED_CAMERA.name)
    assert improved_cam["xy"] < cam["xy"]


def test_rmse_columns_are_consistent(tables):
    for name in tables.names:
        r = tables.per_trial_rmse(name)
        assert set(r) == set(STAT_COLUMNS)
        np.testing.assert_allclose(r["xy"] ** 2, r["x"] ** 2 + r["y"] ** 2)


def test_seed004_misreading_std_as_variance_is_worse():
    std = seed004_kf2d.run("std", n_trials=200, seed=3)
    misread = seed004_kf2d.run("misread as variances", n_trials=200, seed=3)  # same world
    np.testing.assert_array_equal(std.truth, misread.truth)
    # the KF with the true Q and R is the minimum-variance estimator: the misread one can only lose
    # (by little here: with one fix per eight steps the gain at a fix is near 1 either way) ...
    assert misread.rmse() > std.rmse()
    assert 1.7 < std.nees().mean() < 2.3  # consistent
    assert 0.9 < std.inside_95() < 0.99
    assert misread.nees().mean() < 0.5  # ... what goes wrong is the covariance: far too large
    assert misread.inside_95() > 0.995
    # ... and drawing the noise with √figure (the report's first run) makes the world itself noisier
    noisy = seed004_kf2d.run("variances everywhere", n_trials=200, seed=3)
    assert noisy.rmse() > 2.0 * std.rmse()


def test_seed002_filters_beat_dead_reckoning_and_ekf_handles_turns():
    straight = seed002_comparison.simulate("straight", 4, 21)
    weave = seed002_comparison.simulate("weave", 4, 22)
    rmse = {}
    for name, data in (("straight", straight), ("weave", weave)):
        rmse[name] = {
            "dr": seed002_comparison.rmse_xy(seed002_comparison.run_dead_reckoning(data), data).mean(),
            "kf": seed002_comparison.rmse_xy(seed002_comparison.run_filter(
                data, "kf", *seed002_comparison.true_noise("kf", name)), data).mean(),
            "ekf": seed002_comparison.rmse_xy(seed002_comparison.run_filter(
                data, "ekf", *seed002_comparison.true_noise("ekf", name)), data).mean(),
        }
    assert rmse["straight"]["kf"] < 0.5 * rmse["straight"]["dr"]
    assert rmse["straight"]["ekf"] < 0.5 * rmse["straight"]["dr"]
    assert rmse["weave"]["ekf"] < 0.8 * rmse["weave"]["kf"]  # the fixed heading is wrong when turning


def test_cli_writes_the_note_and_figures(tmp_path):
    assert cli.main(["--quick", "--only", "seed004", "--out", str(tmp_path), "--no-progress"]) == 0
    note = (tmp_path / "results.md").read_text()
    assert "Seed 004" in note and "| setting |" in note
    pngs = sorted((tmp_path / "results").glob("seed004_*.png"))
    assert len(pngs) == 2
    for p in pngs:
        assert p.stat().st_size > 20_000
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_shipped_configuration_is_consistent_and_cmd_vel_helps_in_a_dropout():
    """config/ekf.yaml against config/sim.yaml (a few trials: the note's run has 50): the mean
    NEES inside the χ² band of the trial mean, each input's NIS near its dimension, and during
    a dead-wheel dropout the position error with cmd_vel at most half of that without."""
    from seed_experiments.experiments import shipped_consistency as sc

    res = sc.run(4, odom_dropout=(3.0, 0.5))
    lo, hi = res.nees_band
    assert lo <= res.nees_mean <= hi, sc.summary(res)
    for key, (nis, dim) in res.nis.items():
        assert abs(nis / dim - 1.0) < 0.2, (key, nis, dim)
    assert res.dropout_error[sc.WITH] <= 0.5 * res.dropout_error[sc.WITHOUT], sc.summary(res)
    assert res.rmse_state[sc.WITH][3] < 0.5 * res.rmse_state[sc.WITHOUT][3]  # vx
