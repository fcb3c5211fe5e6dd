"""Tilt compensation: body-frame velocity on a slope -> the planar state's horizontal velocity.

A robot on a ramp moves along the surface. Its body twist ``[vx vy wz]`` (what dead wheels,
wheel odometry and a velocity command give: speeds along the surface, yaw rate about the
body z axis = the surface normal) is not the horizontal motion the planar state integrates.
With the IMU's roll r and pitch p (REP-103 fixed-axis roll-pitch-yaw, R = Rz(ψ)·Ry(p)·Rx(r)),
the body velocity [vx vy 0] is ``R·v`` in the world; its horizontal part in the heading
frame (the planar state's body frame) and the heading rate are

    ẋ_h = vx·cos p + vy·sin r·sin p
    ẏ_h = vy·cos r
    ψ̇   = wz·cos r / cos p          (angular velocity along the surface normal only)

i.e. ``[ẋ_h ẏ_h ψ̇] = P(r, p)·[vx vy wz]`` (:func:`horizontal_projection`). The vertical
speed is ż = −vx·sin p + vy·sin r·cos p = −ẋ_h·tan p + ẏ_h·tan r / cos p
(:func:`vertical_rate`). Level ground gives P = I. Not in the seeds: this is the 3D rotation
the planar model of seed 000 (eq. 22) leaves out.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.linalg import symmetrise
from ekf_localization.core.units import ns_to_seconds

# The projection is undefined at |pitch| = 90°; a tilt beyond this is not a ground robot.
MAX_TILT_RAD = math.radians(60.0)


def horizontal_projection(roll, pitch) -> np.ndarray:
    """P: body [vx vy wz] along the surface -> [ẋ_h ẏ_h ψ̇] in the heading frame; (3, 3) for
    scalar roll and pitch, (N, 3, 3) for arrays of shape (N,) (the simulator's trials)."""
    roll, pitch = np.asarray(roll, dtype=float), np.asarray(pitch, dtype=float)
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    P = np.zeros(np.broadcast(roll, pitch).shape + (3, 3))
    P[..., 0, 0], P[..., 0, 1] = cp, sr * sp
    P[..., 1, 1] = cr
    P[..., 2, 2] = cr / cp
    return P


def projection_tilt_jacobian(v: np.ndarray, roll: float, pitch: float) -> np.ndarray:
    """(3, 2) ∂(P(r, p)·v)/∂(r, p) at the body twist ``v`` = [vx vy wz]."""
    vx, vy, wz = (float(c) for c in v)
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    return np.array([[cr * sp * vy, -sp * vx + sr * cp * vy],
                     [-sr * vy, 0.0],
                     [-sr / cp * wz, cr * sp / (cp * cp) * wz]])


def vertical_rate(vx_h: float, vy_h: float, roll: float, pitch: float) -> float:
    """ż (m/s) of the horizontal heading-frame velocity (ẋ_h, ẏ_h) on a surface tilted (r, p)."""
    return -vx_h * math.tan(pitch) + vy_h * math.tan(roll) / math.cos(pitch)


def project_twist(z: np.ndarray, R: np.ndarray, rows: np.ndarray, roll: float, pitch: float,
                  tilt_cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A measured body twist projected onto the horizontal plane, with its covariance.

    ``z`` (k,) and ``R`` (k, k) are the fused components ``rows`` (indices into [vx vy wz]);
    the components not fused count as 0 (e.g. vy of a tank drive). Returns
    ``(P z)[rows]`` and ``P_rr R P_rrᵀ + J Σ_tilt Jᵀ`` with J the tilt Jacobian.
    """
    v = np.zeros(3)
    v[rows] = z
    P = horizontal_projection(roll, pitch)[np.ix_(rows, rows)]
    J = projection_tilt_jacobian(v, roll, pitch)[rows]
    zp = (horizontal_projection(roll, pitch) @ v)[rows]
    Rp = P @ R @ P.T + J @ tilt_cov @ J.T
    return zp, symmetrise(Rp)


@dataclass(frozen=True)
class TiltSample:
    stamp_ns: int
    roll: float
    pitch: float
    covariance: np.ndarray  # (2, 2) roll, pitch (rad²)


class TiltHistory:
    """The IMU's recent roll/pitch samples, looked up at a measurement's stamp."""

    def __init__(self, keep_ns: int) -> None:
        self._keep_ns = max(int(keep_ns), 0)
        self.clear()

    def clear(self) -> None:
        self._stamps: list[int] = []
        self._samples: list[TiltSample] = []

    def __len__(self) -> int:
        return len(self._samples)

    def add(self, sample: TiltSample) -> None:
        """Insert in stamp order and drop samples older than ``keep_ns`` before the newest."""
        i = bisect_right(self._stamps, sample.stamp_ns)
        self._stamps.insert(i, sample.stamp_ns)
        self._samples.insert(i, sample)
        cutoff = self._stamps[-1] - self._keep_ns
        k = bisect_right(self._stamps, cutoff) - 1
        if k > 0:
            del self._stamps[:k]
            del self._samples[:k]

    def at(self, stamp_ns: int) -> TiltSample | None:
        """The newest sample at or before ``stamp_ns`` (the oldest one if all are later), or None."""
        if not self._samples:
            return None
        i = bisect_right(self._stamps, stamp_ns) - 1
        return self._samples[max(i, 0)]


class HeightIntegrator:
    """z of the published estimate: ż (:func:`vertical_rate`) integrated over the tilt samples.

    Nothing measures z: it is dead-reckoned from the estimated horizontal velocity and the
    IMU's tilt, starting at 0 where the filter started, and drifts. :meth:`update` advances it
    at each tilt sample's stamp with the velocity estimated at that stamp; the output is z as
    of the newest sample (:meth:`current`, at most one IMU period old when the IMU is on time).
    Its standard deviation grows by |∂ż/∂v|·σ_v·Δt (errors taken as fully correlated, a
    conservative bound).
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._t_ns: int | None = None
        self._z = 0.0
        self._std = 0.0

    def update(self, t_ns: int, vx_h: float, vy_h: float, velocity_cov: np.ndarray,
               roll: float, pitch: float) -> tuple[float, float]:
        """Advance to ``t_ns`` (an older time is ignored) and return (z, variance)."""
        z, std = self._advanced(t_ns, vx_h, vy_h, velocity_cov, roll, pitch)
        if self._t_ns is None or t_ns > self._t_ns:
            self._t_ns, self._z, self._std = int(t_ns), z, std
        return self._z, self._std * self._std

    def current(self) -> tuple[float, float]:
        """(z, variance) as of the newest update."""
        return self._z, self._std * self._std

    def _advanced(self, t_ns: int, vx_h: float, vy_h: float, velocity_cov: np.ndarray,
                  roll: float, pitch: float) -> tuple[float, float]:
        if self._t_ns is None or t_ns <= self._t_ns:
            return self._z, self._std
        dt = ns_to_seconds(t_ns - self._t_ns)
        g = np.array([-math.tan(pitch), math.tan(roll) / math.cos(pitch)])  # ∂ż/∂(ẋ_h, ẏ_h)
        return (self._z + vertical_rate(vx_h, vy_h, roll, pitch) * dt,
                self._std + math.sqrt(max(float(g @ velocity_cov @ g), 0.0)) * dt)
