"""Dead reckoning: integrate any process model with its controls, no measurement update.

For the Euler-discretised models (seed 002 eq. 1, seed 000 eq. 22, seed 001's appendix)
this is x_{k+1} = f(x_k, u_k) with the model's own f: the baseline of seed 002's table.
Time is integer nanoseconds, as everywhere; angles in the state are wrapped to (-π, π].
"""

from __future__ import annotations

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.ekf import ProcessModel, dt_seconds


class DeadReckoning:
    """The state of one trial (n,) or N trials (N, n), propagated by ``model.f`` only."""

    def __init__(self, model: ProcessModel, x0: np.ndarray) -> None:
        x0 = np.array(x0, dtype=float)
        self._single = x0.ndim == 1
        X = x0[None] if self._single else x0
        if X.ndim != 2 or X.shape[1] != model.n or not np.all(np.isfinite(X)):
            raise ValueError(f"x0 must be {model.n} finite values per trial, got shape {x0.shape}")
        self.model = model
        self._is_angle = np.asarray(model.x_is_angle, dtype=bool)
        self._X = np.where(self._is_angle, wrap_angles(X), X)

    @property
    def x(self) -> np.ndarray:
        """Current state, (n,) or (N, n) as given to the constructor (a copy)."""
        return self._X[0].copy() if self._single else self._X.copy()

    def predict(self, dt_ns: int, u: np.ndarray | None = None) -> bool:
        """Advance by dt_ns nanoseconds with control u ((k,) or (N, k)). False (state kept) if
        the result is not finite."""
        dt = dt_seconds(dt_ns)
        if dt == 0.0:
            return True
        U = None
        if u is not None:
            U = np.atleast_2d(np.asarray(u, dtype=float))
            if U.shape[0] == 1 and self._X.shape[0] > 1:
                U = np.repeat(U, self._X.shape[0], axis=0)
        Xn = np.asarray(self.model.f(self._X, U, dt), dtype=float)
        if Xn.shape != self._X.shape or not np.all(np.isfinite(Xn)):
            return False
        self._X = np.where(self._is_angle, wrap_angles(Xn), Xn)
        return True


def integrate(model: ProcessModel, x0: np.ndarray, controls: np.ndarray | None, dt_ns: int,
              steps: int | None = None) -> np.ndarray:
    """Trajectory (K + 1, n) from x0 (n,) through K steps of dt_ns with controls (K, k).

    With controls None, ``steps`` gives K. Raises ValueError if the state stops being finite.
    """
    if controls is None:
        if steps is None:
            raise ValueError("give controls or steps")
        controls_iter = [None] * int(steps)
    else:
        controls_iter = list(np.asarray(controls, dtype=float))
    dr = DeadReckoning(model, x0)
    out = [dr.x]
    for k, u in enumerate(controls_iter):
        if not dr.predict(dt_ns, u):
            raise ValueError(f"dead reckoning left the finite range at step {k}")
        out.append(dr.x)
    return np.array(out)
