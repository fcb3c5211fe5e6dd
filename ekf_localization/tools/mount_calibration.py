"""A camera mount's error as three more unknowns of the pods' (or driven wheels') fit (no ROS).

A camera measures the pose of its own frame; the robot's software turns it into base_link's
through the mount it believes, M₀. When the true mount is M, each fix is
``F = B ∘ M ∘ M₀⁻¹ = B ∘ Δ``: base_link's true pose B composed with one constant body-frame
offset Δ = (dx, dy, dθ) (docs/models.md, "Camera mount"). :class:`Mounted` wraps an encoder
geometry of :mod:`ekf_localization.tools.pod_calibration` and appends Δ to its parameters; the fit
then predicts each fix as B ∘ Δ. The corrected mount is ``M = Δ ∘ M₀`` (:func:`corrected_mount`).

What a drive shows: Δ's translation makes the fix trace a circle of radius |(dx, dy)| as the
robot turns in place, against the encoders' centre of rotation; Δθ is a constant heading offset,
seen only against the direction the encoders give the body's motion. Two freedoms are shared
with dead-wheel pods: a common rotation of every pod is a mount yaw (held by :func:`pod_gauge`,
the parallel pods' mean angle kept at the file's), and a shift of base_link moves every pod's
offset and the mount's translation alike (so with pods the mount's x and y are held at the file's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ekf_localization.core.angles import wrap_angle
from ekf_localization.tools.pod_calibration import at_mount, columns_of

MOUNT_NAMES = ("x", "y", "yaw")
MOUNT_MAX_STD = np.array([0.01, 0.01, 0.01])  # m, m, rad: a larger formal std is not observable


@dataclass(frozen=True)
class Mounted:
    """``geom`` (any encoder geometry of the pods' fit) and the fixes' body-frame offset ``delta``
    Δ = (dx m, dy m, dθ rad); ``gauge``: weights over ``vector`` whose sum is held at ``start``
    (None: no gauge row)."""

    geom: Any
    delta: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gauge: np.ndarray | None = None

    @property
    def mount(self) -> np.ndarray:
        """Δ, applied by the fit to every pose it compares with a fix."""
        return np.asarray(self.delta, dtype=float)

    @property
    def count(self) -> int:
        return self.geom.count

    @property
    def columns(self) -> np.ndarray:
        return columns_of(self.geom)

    @property
    def vector(self) -> np.ndarray:
        return np.r_[self.geom.vector, self.delta]

    def from_vector(self, p: np.ndarray) -> Mounted:
        p = np.asarray(p, dtype=float)
        d = (float(p[-3]), float(p[-2]), float(p[-1]))
        return replace(self, geom=self.geom.from_vector(p[:-3]), delta=d)

    @property
    def encoders_from_twist(self) -> np.ndarray:
        return self.geom.encoders_from_twist

    def rows_jacobian(self) -> np.ndarray:
        """The geometry's, with zero columns for Δ (the encoders do not see the camera)."""
        J = self.geom.rows_jacobian()
        return np.concatenate([J, np.zeros((*J.shape[:2], 3))], axis=2)


def inverse(m: np.ndarray) -> np.ndarray:
    """The planar transform [x y θ]'s inverse."""
    c, s = math.cos(m[2]), math.sin(m[2])
    return np.array([-c * m[0] - s * m[1], s * m[0] - c * m[1], -m[2]])


def corrected_mount(delta: np.ndarray, believed: np.ndarray) -> np.ndarray:
    """The true mount M = Δ ∘ M₀ (planar [x y yaw]) from the fitted Δ and the believed M₀."""
    m = at_mount(np.asarray(delta, dtype=float)[None, :], np.asarray(believed, dtype=float))[0]
    m[2] = wrap_angle(m[2])
    return m


def pod_gauge(pods: Any) -> np.ndarray | None:
    """Weights over ``Mounted(pods).vector``: the mean angle of the pods parallel to the first
    (within 45° of it, either way), the reference that a mount yaw would otherwise trade with a
    common rotation of every pod. None for a geometry without pod angles."""
    angles = getattr(pods, "angles", None)
    if angles is None:
        return None
    a = np.asarray(angles, dtype=float)
    parallel = np.abs(np.sin(a - a[0])) < math.sqrt(0.5)
    g = np.zeros(len(pods.vector) + 3)
    g[pods.count + np.flatnonzero(parallel)] = 1.0 / parallel.sum()
    return g


def limits(inner_limits: np.ndarray) -> np.ndarray:
    """The inner geometry's limits followed by :data:`MOUNT_MAX_STD`."""
    return np.r_[inner_limits, MOUNT_MAX_STD]
