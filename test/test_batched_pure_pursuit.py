"""BatchedPurePursuit: N trials at once give the commands of N PurePursuitFollower objects.

The batched follower drives N noisy kinematic robots (seeded); N reference followers are
fed the very same poses and stamps, and the batched commands and state (progress, target,
leg, done) must equal theirs to TOL. The two compute the same expressions, but numpy's
hypot and the masked whole-path searches round differently from the scalar code (about
1e-16), and the PIDs' derivative terms (kd/Δt = 10 per metre) and the integrals carry such
differences from step to step; 1e-9 m/s and 1e-9 m leave six orders of magnitude for that
and still catch any wrong branch (a leg end, a cap or a target a step late is off by
1e-4 or more). The scenarios visit the
edge cases on purpose, and the test checks that they happened: robots starting off the
path so far that the lookahead circle misses it (nearest-point target), the leg end
inside the circle, an intermediate stop point, the path end reached by different trials
at different steps (done trials return zeros), a repeated stamp and a first call mid-path.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from ekf_localization.control.field_path import FieldPath, Waypoint, load_preset
from ekf_localization.control.pid import PIDGains
from ekf_localization.control.pure_pursuit import FollowerConfig, PurePursuitFollower
from seed_experiments.batched.pure_pursuit import BatchedPurePursuit

DT_NS = 20_000_000
TOL = 1e-9


def stop_path() -> FieldPath:
    """A corner, an arc and an intermediate stop point, then back (two legs)."""
    arc = [Waypoint(1.0 + 0.4 * math.sin(a), 0.4 - 0.4 * math.cos(a)) for a in np.linspace(0.3, 2.8, 9)]
    return FieldPath([Waypoint(0.0, 0.0), Waypoint(0.9, 0.0), *arc, Waypoint(0.4, 1.0, stop=True),
                      Waypoint(0.4, 1.6), Waypoint(-0.3, 1.6)])


def drive(path: FieldPath, cfg: FollowerConfig, starts: np.ndarray, seed: int,
          max_steps: int = 3000) -> dict[str, int]:
    """Closed loop on the reference; returns how often each edge case occurred."""
    rng = np.random.default_rng(seed)
    n = len(starts)
    refs = [PurePursuitFollower(path, cfg) for _ in range(n)]
    batch = BatchedPurePursuit(path, cfg, n)
    pose = starts.astype(float).copy()
    seen = {"circle_misses": 0, "leg_end_in_circle": 0, "leg_changes": 0, "done_steps": 0,
            "repeated_stamp": 0, "finish_steps": 0}
    t = 0
    prev_leg = np.zeros(n, dtype=int)
    done_at: dict[int, int] = {}  # trial -> the step its follower finished
    for step in range(max_steps):
        if step == 40:  # the same stamp again: no Δt, the PIDs keep their history
            t -= DT_NS
            seen["repeated_stamp"] += 1
        ref_cmd = np.array([refs[i].update(*pose[i].tolist(), t) for i in range(n)])
        cmd = batch.update(pose[:, 0], pose[:, 1], pose[:, 2], t)
        assert np.abs(cmd - ref_cmd).max() <= TOL, step
        for name in ("progress", "target_s", "target_heading", "cross_track_error"):
            ref = np.array([getattr(f, name) for f in refs])
            assert np.abs(getattr(batch, name) - ref).max() <= TOL, (step, name)
        assert np.abs(batch.target - np.array([f.target for f in refs])).max() <= TOL
        assert (batch.leg == [f.leg for f in refs]).all() and (batch.done == [f.done for f in refs]).all()
        for i, f in enumerate(refs):
            if f.done:
                seen["done_steps"] += 1
                done_at.setdefault(i, step)
                continue
            seen["leg_changes"] += f.leg != prev_leg[i]
            prev_leg[i] = f.leg
            leg_end = path.stop_s[f.leg]
            near = path.nearest(pose[i, 0], pose[i, 1], f.progress, leg_end)
            if near[3] > cfg.lookahead_distance and f.target_s < leg_end:
                seen["circle_misses"] += 1
            if f.target_s >= leg_end and f.progress < leg_end:
                seen["leg_end_in_circle"] += 1
        if batch.done.all():
            break
        # a noisy kinematic robot (seeded): the body twist for Δt, plus pose noise
        h = DT_NS * 1e-9
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        pose[:, 0] += h * (cmd[:, 0] * c - cmd[:, 1] * s) + rng.normal(0.0, 2e-4, n)
        pose[:, 1] += h * (cmd[:, 0] * s + cmd[:, 1] * c) + rng.normal(0.0, 2e-4, n)
        pose[:, 2] += h * cmd[:, 2] + rng.normal(0.0, 2e-3, n)
        t += DT_NS
    assert batch.done.all(), "every trial must reach the path end"
    seen["finish_steps"] = len(set(done_at.values()))
    return seen


def test_batched_equals_n_followers_with_stop_point_and_off_path_starts() -> None:
    path = stop_path()
    cfg = FollowerConfig(lookahead_distance=0.2, max_linear_velocity=0.8)
    rng = np.random.default_rng(17)
    n = 10
    starts = np.column_stack([rng.normal(0.0, 0.05, n), rng.normal(0.0, 0.05, n), rng.normal(0.0, 0.3, n)])
    starts[:3, 1] += [0.5, -0.6, 0.8]  # lookahead circle misses the path: nearest-point target
    starts[3] = [0.45, 0.02, 0.1]  # joins mid-leg on its first call
    seen = drive(path, cfg, starts, seed=5)
    assert seen["circle_misses"] > 0 and seen["leg_end_in_circle"] > 0
    assert seen["leg_changes"] >= n  # every trial passed the intermediate stop point
    assert seen["done_steps"] > 0 and seen["finish_steps"] > 1  # done at different steps
    assert seen["repeated_stamp"] == 1


def test_batched_equals_n_followers_on_the_seed000_path() -> None:
    from seed_experiments.experiments.seed000_sim import FOLLOWER  # the seed 000 follower settings

    path = load_preset("seed000_test_path")
    n = 8
    starts = np.tile(np.array(path.start), (n, 1))
    seen = drive(path, FOLLOWER, starts, seed=2000)
    assert seen["leg_end_in_circle"] > 0 and seen["finish_steps"] > 1


def test_no_slowdown_ramp_a_narrow_window_and_clamped_pid_outputs() -> None:
    cfg = FollowerConfig(slowdown_distance=0.0, search_window_factor=1.5, lookahead_distance=0.35,
                         pid_x=PIDGains(kp=6.0, ki=1.0, kd=0.3, integral_limit=0.05, output_limit=0.6),
                         pid_yaw=PIDGains(kp=5.0, ki=0.5, kd=0.2, output_limit=1.0))
    starts = np.array([[0.0, 0.0, 0.0], [0.1, -0.4, 1.0], [0.3, 0.05, -0.5]])
    seen = drive(stop_path(), cfg, starts, seed=9)
    assert seen["circle_misses"] > 0 and seen["leg_end_in_circle"] > 0 and seen["finish_steps"] > 1


def test_differential_mode_and_bad_poses_are_refused() -> None:
    path = stop_path()
    with pytest.raises(ValueError, match="holonomic"):
        BatchedPurePursuit(path, replace(FollowerConfig(), mode="differential"), 2)
    batch = BatchedPurePursuit(path, FollowerConfig(), 2)
    with pytest.raises(ValueError, match="trial 1"):
        batch.update(np.zeros(2), np.array([0.0, math.nan]), np.zeros(2), 0)
    with pytest.raises(ValueError, match="shape"):
        batch.update(np.zeros(3), np.zeros(3), np.zeros(3), 0)


def test_seed000_loop_gives_the_same_numbers_with_either_follower() -> None:
    # the simulator and the experiments only here: the tests above need the follower alone
    from seed_experiments.experiments import seed000_estimators as est
    from seed_experiments.experiments.seed000_sim import FOLLOWER_KINDS, simulate

    path = load_preset("seed000_test_path")
    specs = (est.MODEL, est.MODEL_ODO_CAMERA)
    runs = [simulate(path, specs, 4, 3, max_duration_ns=8_000_000_000, record_trials=2, follower_kind=kind)
            for kind in FOLLOWER_KINDS]
    a, b = runs
    for name in a.names:
        np.testing.assert_allclose(b.sq_err[name], a.sq_err[name], rtol=1e-9)
    # rounding-level differences in the commands do not move a leg end by a whole step
    assert np.array_equal(a.steps, b.steps) and np.array_equal(a.done_ns, b.done_ns)
    np.testing.assert_allclose(b.history.path_progress_m, a.history.path_progress_m, rtol=0, atol=1e-9)
    assert a.history.path_progress_m[-1].min() > 1.0  # the followers did drive
    with pytest.raises(ValueError, match="follower_kind"):
        simulate(path, specs, 2, 3, follower_kind="other")
