"""Single tags decided by the filter's heading: the history (vision/heading_prior.py), the
choice of IPPE solution, the held yaw's covariance and the fallback (vision/tag_pnp.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2
from test_tag_pnp import CAMERA, LAYOUT, MOUNT, _detections, _error

from ekf_localization.core.angles import wrap_angle
from ekf_localization.vision import tag_pnp
from ekf_localization.vision.corner_noise import CornerNoise
from ekf_localization.vision.heading_prior import (
    AMBIGUITY,
    FIXED_HEADING,
    HEADING,
    Heading,
    HeadingHistory,
    nearest_yaw,
)

pytest.importorskip("cv2")

MS = 1_000_000


def test_history_interpolates_holds_and_goes_stale() -> None:
    h = HeadingHistory(max_age_ns=100 * MS)
    assert h.at(0) is None                                   # missing
    assert h.add(1000 * MS, 0.1, 1e-4) and h.add(1020 * MS, 0.3, 3e-4)
    got = h.at(1005 * MS)
    assert got.yaw == pytest.approx(0.15) and got.variance == pytest.approx(1.5e-4)
    assert h.at(1020 * MS).yaw == pytest.approx(0.3) and h.at(1020 * MS).variance == 3e-4
    assert h.at(1100 * MS).yaw == pytest.approx(0.3)          # newer: the newest held
    assert h.at(1121 * MS) is None                           # stale
    assert h.at(999 * MS) is None                            # older than the history
    # across +-pi: interpolated the short way round
    h.add(1040 * MS, math.pi - 0.1, 1e-4)
    h.add(1060 * MS, -math.pi + 0.1, 1e-4)
    assert abs(wrap_angle(h.at(1050 * MS).yaw - math.pi)) < 1e-12
    # a gap wider than twice max_age in the middle: stale there
    h.add(1400 * MS, 0.0, 1e-4)
    assert h.at(1230 * MS) is None and h.at(1150 * MS) is not None and h.at(1310 * MS) is not None


def test_history_refuses_bad_samples_and_keeps_order_and_capacity() -> None:
    h = HeadingHistory(max_age_ns=100 * MS, capacity=3)
    assert not h.add(0, math.nan, 1e-4)
    assert not h.add(0, 0.0, math.inf)
    assert not h.add(0, 0.0, -1e-4)
    assert len(h) == 0
    for t, yaw in ((30, 0.3), (10, 0.1), (20, 0.2), (40, 0.4)):   # out of order; the oldest dropped
        h.add(t * MS, yaw, 0.0)
    assert len(h) == 3 and h.at(10 * MS) is None and h.at(20 * MS).yaw == pytest.approx(0.2)
    h.add(20 * MS, 0.25, 0.0)                                      # same stamp: replaced
    assert h.at(20 * MS).yaw == pytest.approx(0.25) and len(h) == 3
    with pytest.raises(ValueError):
        HeadingHistory(0)


def test_nearest_yaw_on_the_circle() -> None:
    assert nearest_yaw([3.1, 0.0], -3.1) == 0
    assert nearest_yaw([0.2, -0.05], 0.0) == 1
    with pytest.raises(ValueError):
        nearest_yaw([], 0.0)


def _oblique(rng: np.random.Generator) -> np.ndarray:
    """A robot pose 1.5 m from tag 1, 22 degrees off its axis (test_tag_pnp's ambiguous case)."""
    target = LAYOUT.tags[1].pose_in_map[1, 3]
    c = np.array([1.5, target + 0.6]) + rng.normal(0, 0.05, 2)
    yaw = math.atan2(target - c[1], -c[0]) + rng.normal(0, 0.03)
    return np.array([c[0] - 0.1 * math.cos(yaw), c[1] - 0.1 * math.sin(yaw), 0.0, 0.0, 0.0, yaw])


def test_heading_picks_the_ippe_solution_nearest_the_filters_yaw() -> None:
    """300 noisy single-tag frames: without the gate 15 take the mirrored tilt (test_tag_pnp);
    with the filter's heading (0.5 deg std) none does (the mirror is 19-42 deg off) and none is
    rejected. Given the mirrored solution's yaw as the heading, the mirror is taken:
    the heading decides."""
    rng = np.random.default_rng(33)
    pixel_std, trials, mirrored_ungated = 0.5, 300, 0
    heading_std = math.radians(0.5)
    for _ in range(trials):
        truth = _oblique(rng)
        dets = _detections(truth, (1,), rng, pixel_std)
        free, _ = tag_pnp.localize(dets, LAYOUT, CAMERA, MOUNT, CornerNoise(pixel_std), max_ambiguity=1.0)
        mirrored_ungated += abs(_error(free, truth)[5]) > math.radians(12.0)
        heading = Heading(wrap_angle(truth[5] + rng.normal(0.0, heading_std)), heading_std**2)
        fix, _ = tag_pnp.localize(dets, LAYOUT, CAMERA, MOUNT, CornerNoise(pixel_std), max_ambiguity=0.0,
                                  single_tag=HEADING, heading=heading)
        assert isinstance(fix, tag_pnp.TagFix) and fix.method == HEADING and not fix.heading_fallback
        assert abs(_error(fix, truth)[5]) < math.radians(12.0)
    assert mirrored_ungated >= 5
    # the heading decides: at the mirrored solution's yaw, the mirrored solution comes out
    truth = _oblique(np.random.default_rng(5))
    problem, _ = tag_pnp.build_problem(_detections(truth, (1,)), LAYOUT, CAMERA, MOUNT)
    starts, _ = tag_pnp._single_tag_starts(problem, LAYOUT)
    k = int(np.argmax([abs(wrap_angle(s[5] - truth[5])) for s in starts]))
    fix = tag_pnp.solve(problem, LAYOUT, CornerNoise(0.5), single_tag=HEADING,
                        heading=Heading(float(starts[k][5]), 1e-6))
    assert abs(wrap_angle(fix.pose[5] - truth[5])) > math.radians(12.0)


def test_without_a_heading_a_single_tag_falls_back_to_the_ambiguity_gate() -> None:
    far = np.array([3.4, 1.4, 0.0, 0.0, 0.0, math.pi])       # head-on from far: ambiguous
    dets = _detections(far, (1,), np.random.default_rng(1), 1.0)
    for method in (HEADING, FIXED_HEADING):
        fix, _ = tag_pnp.localize(dets, LAYOUT, CAMERA, MOUNT, CornerNoise(1.0), max_ambiguity=0.2,
                                  single_tag=method, heading=None)
        assert isinstance(fix, tag_pnp.TagRejection) and fix.reason == tag_pnp.AMBIGUOUS
        fix, _ = tag_pnp.localize(dets, LAYOUT, CAMERA, MOUNT, CornerNoise(1.0), max_ambiguity=1.0,
                                  single_tag=method, heading=None)
        assert fix.method == AMBIGUITY and fix.heading_fallback
        fix, _ = tag_pnp.localize(dets, LAYOUT, CAMERA, MOUNT, CornerNoise(1.0), max_ambiguity=0.2,
                                  single_tag=method, heading=Heading(math.pi, 1e-6))
        assert isinstance(fix, tag_pnp.TagFix) and fix.method == method and not fix.heading_fallback
    # a heading too uncertain to tell the two solutions' yaws apart: the gate again
    fix, _ = tag_pnp.localize(dets, LAYOUT, CAMERA, MOUNT, CornerNoise(1.0), max_ambiguity=0.2,
                              single_tag=HEADING, heading=Heading(math.pi, 1.0))
    assert isinstance(fix, tag_pnp.TagRejection) and fix.reason == tag_pnp.AMBIGUOUS
    # several tags never use the heading
    fix, _ = tag_pnp.localize(_detections(far, (1, 2)), LAYOUT, CAMERA, MOUNT, CornerNoise(1.0),
                              single_tag=HEADING, heading=Heading(0.0, 1e-6))
    assert fix.method == AMBIGUITY and not fix.heading_fallback
    assert abs(wrap_angle(fix.pose[5] - math.pi)) < 1e-6


def test_fixed_heading_carries_the_headings_error_into_x_y() -> None:
    """The yaw held at a heading 2 deg off (std) at 1.5 m moves x, y by centimetres: with its
    variance in the covariance the NEES of 300 fixes' (x, y, yaw) is in its χ²(3) band; the
    same fixes' (x, y) against the corner noise alone lie far above χ²(2)'s. (The 6-D NEES
    runs higher, about 7.6: one tag's roll and pitch are not Gaussian to first order.)"""
    rng = np.random.default_rng(7)
    pixel_std, trials, sigma = 0.5, 300, math.radians(2.0)
    nees, nees_without = [], []
    xy_yaw = [0, 1, 5]
    for _ in range(trials):
        truth = _oblique(rng)
        heading = Heading(wrap_angle(truth[5] + rng.normal(0.0, sigma)), sigma**2)
        dets = _detections(truth, (1,), rng, pixel_std)
        fix, _ = tag_pnp.localize(dets, LAYOUT, CAMERA, MOUNT, CornerNoise(pixel_std),
                                  single_tag=FIXED_HEADING, heading=heading)
        assert isinstance(fix, tag_pnp.TagFix) and fix.method == FIXED_HEADING
        assert fix.pose[5] == heading.yaw and fix.covariance[5, 5] == heading.variance
        e = _error(fix, truth)[xy_yaw]
        nees.append(float(e @ np.linalg.solve(fix.covariance[np.ix_(xy_yaw, xy_yaw)], e)))
        problem, _ = tag_pnp.build_problem(dets, LAYOUT, CAMERA, MOUNT)
        cov = tag_pnp.pose_covariance(problem, fix.pose, CornerNoise(pixel_std), None, 0.0)
        nees_without.append(float(e[:2] @ np.linalg.solve(cov[:2, :2], e[:2])))
    lo, hi = chi2.ppf([0.005, 0.995], 3 * trials) / trials
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)
    assert np.mean(nees_without) > 2 * chi2.ppf(0.995, 2 * trials) / trials
