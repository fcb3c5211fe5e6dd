"""A diagonal process noise whose entries are polynomials in the step (no ROS).

Q_ii = rate_i · dt (+ per_step_i) (+ accel_i · dt · dt), the form of the mecanum model's (seed 000 eq. 26)
and of the tank model's noise. Its array is one per instance and is rewritten in place when dt
changes: sensors' stamps jitter, so a message's step is seldom the last one, and a new array
for each would be a per-message allocation. The array returned by :meth:`DiagonalNoise.at`
therefore holds only until the next call with another dt: copy it to keep it.
"""

from __future__ import annotations

import numpy as np


class DiagonalNoise:
    """Q = diag(rate · dt + per_step + accel · dt · dt) for one trial, shaped (1, n, n)."""

    def __init__(self, rate: np.ndarray, per_step: np.ndarray | None = None,
                 accel: np.ndarray | None = None) -> None:
        self._rate = np.array(rate, dtype=float)
        n = self._rate.shape[0]
        self._per_step = None if per_step is None else np.array(per_step, dtype=float)
        self._accel = None if accel is None else np.array(accel, dtype=float)
        self._Q = np.zeros((1, n, n))
        self._diag = self._Q.reshape(-1)[::n + 1]  # a view of Q's diagonal
        self._dt: float | None = None

    def at(self, dt: float) -> np.ndarray:
        """Q for a step of dt seconds (the instance's own array: see the module docstring)."""
        if dt != self._dt:
            d = self._diag
            np.multiply(self._rate, dt, out=d)
            if self._per_step is not None:
                d += self._per_step
            if self._accel is not None:
                d += self._accel * dt * dt
            self._dt = dt
        return self._Q
