"""Covariance ellipses and circles as point lists, for markers and the field view (no ROS).

A 2-D Gaussian's confidence region ``(p - m)ᵀ P⁻¹ (p - m) <= k²`` at probability ``q`` has
``k² = χ²₂(q) = -2 ln(1 - q)`` (the χ² distribution with 2 degrees of freedom is exponential
with mean 2, so its quantile has this closed form: 5.991 at 95 %). Its semi-axes are
``k sqrt(λᵢ)`` along the eigenvectors of ``P``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ekf_localization.core.linalg import symmetrise

CONFIDENCE_95 = 0.95
DEFAULT_SEGMENTS = 48


def chi2_2dof_quantile(probability: float) -> float:
    """k² with P(χ²₂ <= k²) = ``probability`` (0 < probability < 1)."""
    if not 0.0 < probability < 1.0:
        raise ValueError(f"probability must be in (0, 1), got {probability!r}")
    return -2.0 * math.log1p(-probability)


class EllipseAxes(NamedTuple):
    """Semi-axes (``major`` >= ``minor``, same length unit as the mean) and the major axis' angle (rad)."""

    major: float
    minor: float
    angle: float


def ellipse_axes(covariance: np.ndarray, probability: float = CONFIDENCE_95) -> EllipseAxes:
    """The ``probability`` confidence ellipse of a 2x2 covariance (symmetrised; negative
    eigenvalues from round-off are clipped to 0). Raises ValueError on a non-finite or
    non-2x2 matrix."""
    P = np.asarray(covariance, dtype=float)
    if P.shape != (2, 2):
        raise ValueError(f"expected a 2x2 covariance, got shape {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("covariance is not finite")
    k = math.sqrt(chi2_2dof_quantile(probability))
    lam, vec = np.linalg.eigh(symmetrise(P))  # ascending
    lam = np.clip(lam, 0.0, None)
    angle = math.atan2(vec[1, 1], vec[0, 1])
    if angle > 0.5 * math.pi:  # an axis direction: keep it in (-pi/2, pi/2]
        angle -= math.pi
    elif angle <= -0.5 * math.pi:
        angle += math.pi
    return EllipseAxes(k * math.sqrt(lam[1]), k * math.sqrt(lam[0]), angle)


def ellipse_points(mean: tuple[float, float] | np.ndarray, covariance: np.ndarray,
                   probability: float = CONFIDENCE_95, segments: int = DEFAULT_SEGMENTS) -> np.ndarray:
    """The ellipse's outline, (segments + 1, 2) points, closed (the last equals the first)."""
    ax = ellipse_axes(covariance, probability)
    t = np.linspace(0.0, 2.0 * math.pi, segments + 1)
    c, s = math.cos(ax.angle), math.sin(ax.angle)
    u, v = ax.major * np.cos(t), ax.minor * np.sin(t)
    m = np.asarray(mean, dtype=float)
    pts = np.column_stack([m[0] + c * u - s * v, m[1] + s * u + c * v])
    pts[-1] = pts[0]
    return pts


def circle_points(centre: tuple[float, float] | np.ndarray, radius: float,
                  segments: int = DEFAULT_SEGMENTS) -> np.ndarray:
    """A closed circle outline, (segments + 1, 2) points."""
    if not (math.isfinite(radius) and radius >= 0.0):
        raise ValueError(f"radius must be finite and >= 0, got {radius!r}")
    t = np.linspace(0.0, 2.0 * math.pi, segments + 1)
    c = np.asarray(centre, dtype=float)
    pts = np.column_stack([c[0] + radius * np.cos(t), c[1] + radius * np.sin(t)])
    pts[-1] = pts[0]
    return pts
