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
with dead-wheel pods: a common rotation of every pod is a mount yaw (held by :func:`pod_gauge`:
the parallel pods' mean angle kept at the file's, the last of them following the others), and a
shift of base_link moves every pod's offset and the mount's translation alike (so with pods the
mount's x and y are held at the file's).
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
class Tie:
    """Parameter ``index`` of the vector follows ``others``: their sum with it is ``total`` (the
    parallel pods' mean angle held while each of them is fitted)."""

    index: int
    others: tuple[int, ...]
    total: float


@dataclass(frozen=True)
class Mounted:
    """``geom`` (any encoder geometry of the pods' fit) and the fixes' body-frame offset ``delta``
    Δ = (dx m, dy m, dθ rad); ``tie``: a parameter of ``geom`` set from others (the gauge, held
    out of the free ones), None: none."""

    geom: Any
    delta: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tie: Tie | None = None

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
        p = np.array(p, dtype=float)
        if self.tie is not None:
            p[self.tie.index] = self.tie.total - p[list(self.tie.others)].sum()
        d = (float(p[-3]), float(p[-2]), float(p[-1]))
        return replace(self, geom=self.geom.from_vector(p[:-3]), delta=d)

    @property
    def encoders_from_twist(self) -> np.ndarray:
        return self.geom.encoders_from_twist

    def rows_jacobian(self) -> np.ndarray:
        """The geometry's, with zero columns for Δ (the encoders do not see the camera) and a tied
        parameter's column carried into those it follows (∂/∂p_other − ∂/∂p_tied)."""
        J = self.geom.rows_jacobian()
        J = np.concatenate([J, np.zeros((*J.shape[:2], 3))], axis=2)
        if self.tie is not None:
            J[:, :, list(self.tie.others)] -= J[:, :, [self.tie.index]]
        return J


def inverse(m: np.ndarray) -> np.ndarray:
    """The planar transform [x y θ]'s inverse."""
    c, s = math.cos(m[2]), math.sin(m[2])
    return np.array([-c * m[0] - s * m[1], s * m[0] - c * m[1], -m[2]])


def corrected_mount(delta: np.ndarray, believed: np.ndarray) -> np.ndarray:
    """The true mount M = Δ ∘ M₀ (planar [x y yaw]) from the fitted Δ and the believed M₀."""
    m = at_mount(np.asarray(delta, dtype=float)[None, :], np.asarray(believed, dtype=float))[0]
    m[2] = wrap_angle(m[2])
    return m


def pod_gauge(pods: Any) -> Tie | None:
    """The tie that holds the mean angle of the pods parallel to the first (within 45° of it,
    either way) at its value in ``pods``: the last of them follows the others. The reference that
    a mount yaw would otherwise trade with a common rotation of every pod; None without pod angles
    or with a single parallel pod (then that pod's angle is the one to hold)."""
    angles = getattr(pods, "angles", None)
    if angles is None:
        return None
    a = np.asarray(angles, dtype=float)
    parallel = pods.count + np.flatnonzero(np.abs(np.sin(a - a[0])) < math.sqrt(0.5))
    if len(parallel) < 2:
        return None
    return Tie(int(parallel[-1]), tuple(int(i) for i in parallel[:-1]), float(pods.vector[parallel].sum()))


def limits(inner_limits: np.ndarray) -> np.ndarray:
    """The inner geometry's limits followed by :data:`MOUNT_MAX_STD`."""
    return np.r_[inner_limits, MOUNT_MAX_STD]
