"""The corner noise behind a PnP fix's covariance: independent, shared by a tag, grown by blur.

A detector's corner error is not independent pixel noise. On rendered tag36h11 images with
motion blur (docs/tag_localizer.md, "How honest is the covariance") it has three parts:

* an independent part per corner, std ``pixel_std`` in each axis;
* a shift shared by the four corners of a tag, std ``tag_shift_std`` in each axis: the
  detector's edge fit moves the whole quad, and PnP can absorb such a shift into the pose, so
  the fit's residuals do not show it;
* both grow along the image motion during the exposure: ``blur_std_per_px`` px of std per px
  of blur, added in quadrature along the motion's direction.

For one tag with blur vector m (px, the corners' mean motion over the exposure, unit
direction u, length L) the 8x8 covariance of its corners (u0, v0, ..., u3, v3) is

    Σ_tag = I₄ ⊗ (a² I₂ + (k L)² u uᵀ) + 1₄1₄ᵀ ⊗ (c² I₂ + (k L)² u uᵀ)

with a = ``pixel_std``, c = ``tag_shift_std``, k = ``blur_std_per_px``. PnP is least squares
on unweighted residuals, so its pose covariance is the sandwich (Bar-Shalom et al. 2001,
sec. 3.4; a Gauss-Newton estimator under correlated errors)

    Σ_p = (JᵀJ)⁻¹ Jᵀ Σ J (JᵀJ)⁻¹,

which is σ² (JᵀJ)⁻¹ when Σ = σ² I (the model without blur or shared shift).

A fit whose residual r is inconsistent with Σ (rᵀr above its χ² bound at
:data:`RESIDUAL_CHECK_MASS`, with tr((I - H) Σ) its expected value, H the hat matrix) has a
corner error the model does not know (a blurred edge the detector misplaced, a tag partly
occluded); its Σ_p is scaled by the excess rᵀr / tr((I - H) Σ). A consistent fit is left as
it is, so the model is not bent by its own residuals (they cannot see the shared shift).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.chi2_bands import chi2_quantile

RESIDUAL_CHECK_MASS = 0.99


def residual_bound(dof: int) -> float:
    """The residual check's bound on a χ²(dof) statistic: its :data:`RESIDUAL_CHECK_MASS` quantile."""
    return chi2_quantile(RESIDUAL_CHECK_MASS, dof)


@dataclass(frozen=True)
class CornerNoise:
    """Corner noise model (px); the defaults are the plain independent model σ = 1 px."""

    pixel_std: float = 1.0              # independent, per corner and axis
    tag_shift_std: float = 0.0          # shared by a tag's four corners, per axis
    blur_std_per_px: float = 0.0        # std added along the motion per px of blur
    exposure_time: float = 0.0          # s: the blur is the image motion over it
    unknown_motion_blur_px: float = 0.0  # blur along the image rows when the motion is unknown

    def tag_covariance(self, blur: np.ndarray) -> np.ndarray:
        """Σ_tag (8x8) of one tag's corners for the blur vector ``blur`` (px)."""
        m = np.asarray(blur, dtype=float)
        grown = self.blur_std_per_px**2 * np.outer(m, m)   # (k L)² u uᵀ with m = L u
        own = self.pixel_std**2 * np.eye(2) + grown
        shared = self.tag_shift_std**2 * np.eye(2) + grown
        return np.kron(np.eye(4), own) + np.kron(np.ones((4, 4)), shared)

    def corner_covariance(self, blurs: np.ndarray) -> np.ndarray:
        """Σ (8T x 8T) of T tags' corners, block diagonal, for their (T, 2) blur vectors."""
        blurs = np.asarray(blurs, dtype=float).reshape(-1, 2)
        out = np.zeros((8 * len(blurs), 8 * len(blurs)))
        for i, b in enumerate(blurs):
            out[8 * i:8 * i + 8, 8 * i:8 * i + 8] = self.tag_covariance(b)
        return out

    def unknown_blurs(self, tags: int) -> np.ndarray:
        """The (T, 2) blur assumed when the camera's motion is unknown: along the image rows."""
        return np.tile([self.unknown_motion_blur_px, 0.0], (tags, 1))


def pose_covariance(J: np.ndarray, r: np.ndarray, corner_cov: np.ndarray) -> np.ndarray:
    """Σ_p of a least-squares fit with Jacobian J (2N, n) and residual r (2N,) under the corner
    covariance Σ (2N, 2N): the sandwich, scaled when r fails its χ² check (module docstring).
    inf where JᵀJ is singular."""
    A = J.T @ J
    if not np.all(np.isfinite(A)) or np.linalg.cond(A) > 1e14:
        return np.full((A.shape[0], A.shape[0]), math.inf)
    G = np.linalg.solve(A, J.T)                          # (JᵀJ)⁻¹ Jᵀ
    cov = G @ corner_cov @ G.T
    dof = r.size - A.shape[0]
    if dof > 0:
        expected = float(np.trace(corner_cov) - np.trace(J @ G @ corner_cov))   # tr((I - H) Σ)
        ratio = float(r @ r) / expected if expected > 0.0 else 1.0
        if ratio * dof > residual_bound(dof):
            cov = cov * ratio
    return 0.5 * (cov + cov.T)
