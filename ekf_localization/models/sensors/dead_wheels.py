"""Three dead-wheel encoders E_L, E_R, E_a (seed 000, eq. 29-33).

Sign convention (eq. 30): ``E_a = ẏ − D·θ̇``, i.e. the lateral (perpendicular) wheel sits
a distance D *behind* the robot centre for D > 0 (use a negative D for a wheel in front).
W is the half distance between the two parallel wheels (each at ±W from the centre
line). Encoder speeds are linear surface speeds (m/s, or in/s for the paper's units).

:class:`PodGeometry` is the general form a calibration fits (docs/models.md, "Dead-wheel
pods"): each pod's offset across its rolling direction, its rolling direction's angle and
its scale; eq. 30's rows are the symmetric case.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.linear import LinearMeasurement


@dataclass(frozen=True)
class DeadWheelGeometry:
    """W: half spacing of the parallel wheels; D: lateral wheel offset behind centre (eq. 29)."""

    half_track: float  # W
    lateral_offset: float  # D

    def __post_init__(self) -> None:
        if not (math.isfinite(self.half_track) and self.half_track > 0.0):
            raise ValueError(f"half_track (W) must be positive, got {self.half_track!r}")
        if not math.isfinite(self.lateral_offset):
            raise ValueError(f"lateral_offset (D) must be finite, got {self.lateral_offset!r}")

    @property
    def encoders_from_twist(self) -> np.ndarray:
        """(3, 3) body twist [ẋ ẏ θ̇] -> encoders [E_L E_R E_a], eq. 30."""
        W, D = self.half_track, self.lateral_offset
        return np.array([[1.0, 0.0, -W], [1.0, 0.0, W], [0.0, 1.0, -D]])

    @property
    def twist_from_encoders(self) -> np.ndarray:
        """(3, 3) encoders -> body twist [ẋ ẏ θ̇], eq. 29 rearranged."""
        W, D = self.half_track, self.lateral_offset
        return np.array([[0.5, 0.5, 0.0],
                         [-D / (2.0 * W), D / (2.0 * W), 1.0],
                         [-1.0 / (2.0 * W), 1.0 / (2.0 * W), 0.0]])


POD_FIELDS = ("offsets", "angles", "scales")


@dataclass(frozen=True)
class PodGeometry:
    """Each pod i rolls along the direction at angle α_i from base_link's x, on a line o_i to the
    left of the centre (its offset across the rolling direction), and reads k_i times its
    surface speed: ``E_i = k_i·(cos α_i·ẋ + sin α_i·ẏ − o_i·θ̇)`` (docs/models.md, "Dead-wheel
    pods"). A pod's position along its rolling direction does not enter (not observable)."""

    offsets: tuple[float, ...]  # o_i, m
    angles: tuple[float, ...]  # α_i, rad
    scales: tuple[float, ...]  # k_i

    def __post_init__(self) -> None:
        n = len(self.offsets)
        if n == 0 or len(self.angles) != n or len(self.scales) != n:
            raise ValueError(f"pod offsets, angles and scales: one of each per pod, got {n}, "
                             f"{len(self.angles)} and {len(self.scales)}")
        if not all(math.isfinite(v) for v in self.offsets + self.angles):
            raise ValueError("pod offsets and angles must be finite")
        if not all(math.isfinite(k) and k > 0.0 for k in self.scales):
            raise ValueError(f"pod scales must be finite and > 0, got {self.scales!r}")

    @classmethod
    def symmetric(cls, half_spacing: float, lateral_offset: float, count: int = 3) -> PodGeometry:
        """Eq. 30's pods: left o = W, right o = −W along x, the lateral one o = D along y."""
        W, D = float(half_spacing), float(lateral_offset)
        return cls((W, -W, D)[:count], (0.0, 0.0, 0.5 * math.pi)[:count], (1.0,) * count)

    @property
    def count(self) -> int:
        return len(self.offsets)

    @property
    def vector(self) -> np.ndarray:
        """[o_1.., α_1.., k_1..]: the parameters in the order of :data:`POD_FIELDS`."""
        return np.array(self.offsets + self.angles + self.scales, dtype=float)

    @classmethod
    def from_vector(cls, p: np.ndarray) -> PodGeometry:
        n = len(p) // 3
        return cls(*(tuple(float(v) for v in p[i * n:(i + 1) * n]) for i in range(3)))

    @property
    def encoders_from_twist(self) -> np.ndarray:
        """(k, 3) body twist [ẋ ẏ θ̇] -> encoder speeds E."""
        o, a, k = (np.asarray(v, dtype=float) for v in (self.offsets, self.angles, self.scales))
        return k[:, None] * np.column_stack([np.cos(a), np.sin(a), -o])

    def rows_jacobian(self) -> np.ndarray:
        """(k, 3, 3k): ∂(encoders_from_twist)/∂[o.., α.., k..]; row i depends on pod i alone."""
        n = self.count
        o, a, k = (np.asarray(v, dtype=float) for v in (self.offsets, self.angles, self.scales))
        J = np.zeros((n, 3, 3 * n))
        i = np.arange(n)
        J[i, 2, i] = -k
        J[i, 0, n + i], J[i, 1, n + i] = -k * np.sin(a), k * np.cos(a)
        J[i, 0, 2 * n + i], J[i, 1, 2 * n + i], J[i, 2, 2 * n + i] = np.cos(a), np.sin(a), -o
        return J


def speed_variance(E, coeff: float, floor: float):
    """Eq. 32, ``coeff·E² + floor``, for a speed or an array of them (the simulator's compiled
    sampler calls it too)."""
    return coeff * E * E + floor


@dataclass(frozen=True)
class EncoderNoise:
    """Per-encoder speed variance ``speed_variance_coeff · E² + variance_floor`` (eq. 32)."""

    speed_variance_coeff: float = 0.002
    variance_floor: float = 0.001

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speed_variance_coeff) and self.speed_variance_coeff >= 0.0):
            raise ValueError(f"speed_variance_coeff must be finite and >= 0 (dimensionless), "
                             f"got {self.speed_variance_coeff!r}")
        if not (math.isfinite(self.variance_floor) and self.variance_floor > 0.0):
            raise ValueError(f"variance_floor must be finite and > 0 ((m/s)²), got {self.variance_floor!r}")

    def variances(self, E: np.ndarray) -> np.ndarray:
        """Eq. 32: per-encoder variance for encoder speeds E (any shape), (m/s)²."""
        return speed_variance(np.asarray(E, dtype=float), self.speed_variance_coeff, self.variance_floor)

    def covariance(self, E: np.ndarray) -> np.ndarray:
        """Diagonal encoder covariance, (3, 3) for E (3,) or (N, 3, 3) for E (N, 3)."""
        v = self.variances(E)
        return v[..., :, None] * np.eye(v.shape[-1])


def encoder_measurement(geometry: DeadWheelGeometry) -> LinearMeasurement:
    """h(s) = [ẋ − Wθ̇, ẋ + Wθ̇, ẏ − Dθ̇] on the 6-state mecanum model, Jacobian eq. 33."""
    H = np.zeros((3, 6))
    H[:, 3:6] = geometry.encoders_from_twist
    return LinearMeasurement(H)


def twist_measurement() -> LinearMeasurement:
    """h(s) = [ẋ ẏ θ̇]: the encoders' information expressed as a body twist."""
    H = np.zeros((3, 6))
    H[:, 3:6] = np.eye(3)
    return LinearMeasurement(H)


def encoders_to_twist(geometry: DeadWheelGeometry, E: np.ndarray,
                      encoder_cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Body twist from encoder speeds with the covariance propagated exactly (it is linear).

    E is (3,) or (N, 3); encoder_cov is (3, 3) or (N, 3, 3). Returns (twist, twist_cov).
    """
    M = geometry.twist_from_encoders
    E = np.asarray(E, dtype=float)
    C = np.asarray(encoder_cov, dtype=float)
    return E @ M.T, M @ C @ M.T
