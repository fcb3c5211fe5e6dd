"""Kidnapped-robot recovery: pose fixes that keep failing the gate while agreeing with each other.

A wrong start (a restarted filter, a robot carried elsewhere) makes every absolute pose fix
(a camera landmark pose) fail the Mahalanobis gate, so the filter never corrects itself.
:class:`GatedFixes` keeps the innovations (fix minus the filter's own estimate at the fix's
stamp, angles wrapped) of the consecutive gated fixes of one input. Dead reckoning keeps the
filter's *relative* motion right, so the innovations of a wrong start agree with each other,
while outliers do not. Once at least ``min_fixes`` of them, spanning ``min_duration``, lie
within ``agreement`` (position, m) and ``angle_agreement`` (rad) of their median, the median
is the correction to re-initialise the pose with. An accepted fix clears the run. When the
positions agree but the angles do not (a start with a wrong heading and a zero covariance
that another input, e.g. an IMU's yaw, is turning back: the angle innovations move while the
position ones stay), the position alone is re-initialised: otherwise such a run never agrees
and the estimate stays off by the start error (``python benchmarks/fuzz.py --seed 3``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.units import NS_PER_S


@dataclass(frozen=True)
class RecoveryConfig:
    enabled: bool = True
    min_fixes: int = 10
    min_duration_ns: int = NS_PER_S
    agreement: float = 0.2  # m
    angle_agreement: float = 0.3  # rad
    inlier_fraction: float = 0.8  # of the run's fixes within the agreement


class GatedFixes:
    """The run of consecutive gated fixes of one input (see the module docstring)."""

    def __init__(self, config: RecoveryConfig, is_angle: np.ndarray, keep_ns: int) -> None:
        self.config = config
        self._is_angle = np.asarray(is_angle, dtype=bool)
        self._keep_ns = keep_ns
        self._fixes: deque[tuple[int, np.ndarray]] = deque()

    def __len__(self) -> int:
        return len(self._fixes)

    def clear(self) -> None:
        self._fixes.clear()

    def add(self, stamp_ns: int, innovation: np.ndarray) -> np.ndarray | None:
        """Record a gated fix; returns the correction (median innovation) once the run agrees."""
        self._fixes.append((int(stamp_ns), np.asarray(innovation, dtype=float).copy()))
        newest = max(t for t, _ in self._fixes)
        while self._fixes and self._fixes[0][0] < newest - self._keep_ns:
            self._fixes.popleft()
        c = self.config
        if not c.enabled or len(self._fixes) < c.min_fixes:
            return None
        stamps = np.array([t for t, _ in self._fixes])
        v = np.array([d for _, d in self._fixes])
        out = self._correction(stamps, v)
        if out is None:  # the run's newest part alone (older fixes of a run that settled since)
            tail = stamps >= stamps.max() - 3 * c.min_duration_ns // 2
            if tail.sum() < len(v):
                out = self._correction(stamps[tail], v[tail])
        return out

    def _correction(self, stamps: np.ndarray, v: np.ndarray) -> np.ndarray | None:
        """The median innovation of ``v`` (the fixes at ``stamps``) if they agree, else None."""
        c = self.config
        if len(v) < c.min_fixes:
            return None
        median = np.median(v, axis=0)
        if self._is_angle.any():  # the circular median: around the first fix's angle
            ref = v[0, self._is_angle]
            median[self._is_angle] = ref + np.median(wrap_angles(v[:, self._is_angle] - ref), axis=0)
        dev = v - median
        dev[:, self._is_angle] = wrap_angles(dev[:, self._is_angle])
        lin = ~self._is_angle
        near = np.ones(len(v), dtype=bool)
        if lin.any():
            near = np.linalg.norm(dev[:, lin], axis=1) <= c.agreement
        ok = near & np.all(np.abs(dev[:, self._is_angle]) <= c.angle_agreement, axis=1)
        if self._agree(ok, stamps):
            inliers = v[ok]
            out = np.median(inliers, axis=0)
            if self._is_angle.any():
                ref = inliers[0, self._is_angle]
                turn = np.median(wrap_angles(inliers[:, self._is_angle] - ref), axis=0)
                out[self._is_angle] = wrap_angles(ref + turn)
            return out
        if lin.any() and self._is_angle.any() and self._agree(near, stamps):
            # the positions agree but the angle innovations move (another input, e.g. an IMU, is
            # turning a wrong heading back): re-initialise the position, keep the filter's angle
            out = np.median(v[near], axis=0)
            out[self._is_angle] = 0.0
            return out
        return None

    def _agree(self, ok: np.ndarray, stamps: np.ndarray) -> bool:
        """Enough of the run's fixes (``ok``) agree, over at least ``min_duration``."""
        c = self.config
        return bool(ok.sum() >= max(c.min_fixes, c.inlier_fraction * len(ok))
                    and stamps[ok].max() - stamps[ok].min() >= c.min_duration_ns)
