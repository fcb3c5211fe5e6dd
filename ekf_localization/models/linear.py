"""A measurement that is a fixed linear function of the state: z = H x."""

from __future__ import annotations

import numpy as np


class LinearMeasurement:
    """z = H x with constant H; ``z_is_angle`` marks components whose residual is wrapped."""

    linear = True

    def __init__(self, H: np.ndarray, z_is_angle: np.ndarray | None = None) -> None:
        self.H = np.ascontiguousarray(np.asarray(H, dtype=float))
        self.m, self.n = self.H.shape
        self.z_is_angle = (np.zeros(self.m, dtype=np.bool_) if z_is_angle is None
                           else np.asarray(z_is_angle, dtype=np.bool_))
        self._HT = np.ascontiguousarray(self.H.T)
        self._H1 = self.H[None]

    def h(self, X: np.ndarray) -> np.ndarray:
        return X @ self._HT

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        """(1, m, n): the same H for every trial (the kernels broadcast a leading 1)."""
        return self._H1


def select_rows(n: int, rows: list[int], angle_rows: tuple[int, ...] = ()) -> LinearMeasurement:
    """A measurement that observes state components ``rows`` directly."""
    H = np.zeros((len(rows), n))
    for i, r in enumerate(rows):
        H[i, r] = 1.0
    return LinearMeasurement(H, np.array([r in angle_rows for r in rows], dtype=np.bool_))


def stack_measurements(*parts: LinearMeasurement) -> LinearMeasurement:
    """Several linear measurements of one state fused as one (e.g. seed 000 eq. 31 = 28 over 30)."""
    if not parts:
        raise ValueError("stack_measurements needs at least one measurement")
    return LinearMeasurement(np.vstack([p.H for p in parts]), np.concatenate([p.z_is_angle for p in parts]))
