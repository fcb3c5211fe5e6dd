"""core/ellipse.py: the 95 % covariance ellipse and circle outlines (ROS-free)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from ekf_localization.core.ellipse import (
    chi2_2dof_quantile,
    circle_points,
    ellipse_axes,
    ellipse_points,
)


@pytest.mark.parametrize("q", [0.5, 0.9, 0.95, 0.99])
def test_quantile_matches_scipy(q: float) -> None:
    assert chi2_2dof_quantile(q) == pytest.approx(chi2.ppf(q, 2), rel=1e-12)


@pytest.mark.parametrize("q", [0.0, 1.0, -0.1, math.nan])
def test_quantile_refuses_bad_probability(q: float) -> None:
    with pytest.raises(ValueError):
        chi2_2dof_quantile(q)


def test_axis_aligned_ellipse() -> None:
    ax = ellipse_axes(np.diag([4.0, 1.0]))
    k = math.sqrt(chi2.ppf(0.95, 2))
    assert (ax.major, ax.minor) == pytest.approx((2.0 * k, 1.0 * k))
    assert abs(ax.angle) == pytest.approx(0.0, abs=1e-12)


def test_rotated_ellipse_points_lie_on_the_mahalanobis_contour() -> None:
    rng = np.random.default_rng(3)
    A = rng.normal(size=(2, 2))
    P = A @ A.T + 0.1 * np.eye(2)
    mean = np.array([0.7, -1.2])
    pts = ellipse_points(mean, P, 0.95, segments=64)
    assert pts.shape == (65, 2)
    assert np.array_equal(pts[0], pts[-1])
    d = pts - mean
    d2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(P), d)
    np.testing.assert_allclose(d2, chi2.ppf(0.95, 2), rtol=1e-9)


def test_coverage_of_samples_is_95_percent() -> None:
    rng = np.random.default_rng(7)
    P = np.array([[0.04, 0.015], [0.015, 0.01]])
    x = rng.multivariate_normal([0.0, 0.0], P, size=200_000)
    ax = ellipse_axes(P)
    c, s = math.cos(ax.angle), math.sin(ax.angle)
    u = c * x[:, 0] + s * x[:, 1]
    v = -s * x[:, 0] + c * x[:, 1]
    inside = (u / ax.major) ** 2 + (v / ax.minor) ** 2 <= 1.0
    assert inside.mean() == pytest.approx(0.95, abs=0.003)


def test_degenerate_and_bad_covariances() -> None:
    ax = ellipse_axes(np.array([[1.0, 1.0], [1.0, 1.0]]))  # rank 1: a line segment along (1, 1)
    assert ax.minor == pytest.approx(0.0, abs=1e-7)
    assert ax.angle == pytest.approx(math.pi / 4)
    with pytest.raises(ValueError):
        ellipse_axes(np.array([[math.nan, 0.0], [0.0, 1.0]]))
    with pytest.raises(ValueError):
        ellipse_axes(np.eye(3))


def test_circle_points() -> None:
    pts = circle_points((1.0, 2.0), 0.3, segments=12)
    np.testing.assert_allclose(np.hypot(pts[:, 0] - 1.0, pts[:, 1] - 2.0), 0.3)
    assert np.array_equal(pts[0], pts[-1])
    with pytest.raises(ValueError):
        circle_points((0.0, 0.0), -1.0)

