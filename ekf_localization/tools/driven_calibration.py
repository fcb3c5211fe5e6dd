"""The driven wheels' radius, turning lever and (mecanum) strafe scale as an encoder geometry for
the pods' fit (no ROS).

A jointN input with ``geometry`` mecanum or differential reads the drive's own wheels. Its rows
on the body twist [ẋ ẏ θ̇] are the model's inverse kinematics (docs/models.md, "Driven
wheels"): mecanum's eq. 23 inverse with k = L + l and its ẏ column divided by the strafe scale σ,
a differential pair's with its half track l.
:class:`DrivenGeometry` gives them the interface of ``PodGeometry`` (``count``, ``vector``,
``from_vector``, ``encoders_from_twist``, ``rows_jacobian``, ``columns``), so that
:mod:`ekf_localization.tools.pod_calibration` fits p = [r, k] (mecanum [r, k, σ]) from camera
pose fixes with the
wheels' integrated displacement between them as links (docs/models.md, "Driven-wheel
calibration"). The wheels' distances are the joint positions times the params file's radius
r₀ (what the filter computes), so the rows are r₀/r times the kinematics at unit radius.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ekf_localization.models.differential import tank_kinematics
from ekf_localization.models.mecanum import MecanumKinematics

DRIVEN = ("mecanum", "differential")
FIELDS = ("radius", "lever", "strafe")  # a differential drive has no strafe
MAX_STD_FRACTION = 0.01  # a parameter whose formal std exceeds 1 % of its file value is held


@dataclass(frozen=True)
class DrivenGeometry:
    """``geometry`` (mecanum or differential), the distances' radius r₀ (m), and the fitted
    wheel ``radius`` r (m), turning ``lever`` (m: mecanum's L + l, a differential's l) and
    mecanum's ``strafe`` scale σ (the robot's ẏ per eq. 23's)."""

    geometry: str
    unit_radius: float
    radius: float
    lever: float
    strafe: float = 1.0

    def __post_init__(self) -> None:
        if self.geometry not in DRIVEN:
            raise ValueError(f"no driven-wheel geometry '{self.geometry}' ({', '.join(DRIVEN)})")
        for name in ("unit_radius", "radius", "lever", "strafe"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"driven wheels: {name} must be positive and finite, got {v!r}")
        if self.geometry != "mecanum" and self.strafe != 1.0:
            raise ValueError(f"driven wheels: a strafe scale needs geometry mecanum, got {self.geometry}")

    @property
    def count(self) -> int:
        """Encoders: mecanum's four wheels m1..m4, a differential's [left right]."""
        return 4 if self.geometry == "mecanum" else 2

    @property
    def columns(self) -> np.ndarray:
        """The twist components the wheels determine (a differential drive has no ẏ)."""
        return np.array([0, 1, 2] if self.geometry == "mecanum" else [0, 2])

    @property
    def fields(self) -> tuple[str, ...]:
        """The parameters' names: :data:`FIELDS`, a differential's without the strafe."""
        return FIELDS if self.geometry == "mecanum" else FIELDS[:2]

    @property
    def vector(self) -> np.ndarray:
        """[r, k] (mecanum [r, k, σ]): the parameters in the order of :attr:`fields`."""
        return np.array([getattr(self, f) for f in self.fields], dtype=float)

    def from_vector(self, p: np.ndarray) -> DrivenGeometry:
        return replace(self, **{f: float(v) for f, v in zip(self.fields, p, strict=True)})

    @property
    def encoders_from_twist(self) -> np.ndarray:
        """(count, 3) body twist -> the wheels' speeds in m/s at radius r₀: r₀ × the inverse kinematics
        (mecanum's ẏ column over σ)."""
        if self.geometry == "mecanum":
            G = MecanumKinematics(self.radius, 0.5 * self.lever, 0.5 * self.lever).inverse_matrix
            G[:, 1] /= self.strafe
        else:
            G = tank_kinematics(self.radius, self.lever)[0]
        return self.unit_radius * G

    def rows_jacobian(self) -> np.ndarray:
        """(count, 3, parameters): ∂(encoders_from_twist)/∂[r, k, σ]. Every row is ∝ 1/r, its θ̇
        entry ∝ k and its ẏ entry ∝ 1/σ."""
        M = self.encoders_from_twist
        J = np.zeros((*M.shape, len(self.fields)))
        J[:, :, 0] = -M / self.radius
        J[:, 2, 1] = M[:, 2] / self.lever
        if self.geometry == "mecanum":
            J[:, 1, 2] = -M[:, 1] / self.strafe
        return J

    def limits(self) -> np.ndarray:
        """The largest formal std each parameter may have to be fitted: 1 % of the start value."""
        return MAX_STD_FRACTION * self.vector


def lever_of(geometry: str, half_wheelbase: float, half_track: float) -> float:
    """The turning lever a params file gives: mecanum L + l, differential l."""
    return half_wheelbase + half_track if geometry == "mecanum" else half_track


def lever_parameters(name: str, geometry: str, half_wheelbase: float, half_track: float,
                     lever: float) -> dict[str, float]:
    """The jointN parameters for a fitted lever: a differential's ``half_track``; mecanum's L and
    l scaled by one factor (only L + l is observable from the wheels, their ratio is kept)."""
    if geometry != "mecanum":
        return {f"{name}_half_track": float(lever)}
    f = lever / (half_wheelbase + half_track)
    return {f"{name}_half_wheelbase": float(half_wheelbase * f), f"{name}_half_track": float(half_track * f)}
