"""A guard for a drive that does not follow its commands (blocked, stalled, lifted, browned out).

No ROS. The test: every velocity update (a dead-wheel twist, an IMU yaw rate) gives the
innovation ν = z - h(x⁻) and S = H P⁻ Hᵀ + R (seed 000 eq. 10). While commands drive the
prediction (seed 000 eq. 25, here the drive response) and the drive follows them, νᵀS⁻¹ν is
χ²(m) and the innovations are white, so the sum over a window of K updates is χ²(Σm)
(Bar-Shalom, Li, Kirubarajan, sec. 5.4). The guard:

* **trips** when that sum exceeds the χ² quantile 1 - ``false_alarm`` for Σm degrees of
  freedom, each NIS clipped at its own χ²(m) quantile 1 - ``false_alarm`` first (a single
  outlier does not trip it, and clipping only lowers the sum: the false-alarm rate stays
  below ``false_alarm``): the command is then dropped (the model predicts without it, with the process noise
  of ``process_noise_covariance``, as when no command is in effect) and ``followed`` is False;
* while tripped, tests the measured velocity against the velocity the command settles at
  (ν' = z - h(x_c), x_c the prior with the command's settled velocity; S as above) and
  **recovers** once a full window's sum is within the χ² quantile :data:`RECOVER_MASS`
  (hysteresis: a stricter bound than the trip's, over a full window);
* **unconfirmed**: no velocity measurement for ``confirm_ns``: the command is dropped from then
  on until one arrives and the velocity variance grows by c²/4 (:meth:`CommandGuard.screen`),
  so a command no sensor confirms never makes the filter confident.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from ekf_localization.core.chi2_bands import chi2_quantile
from ekf_localization.core.units import NS_PER_S

RECOVER_MASS = 0.95  # recover when a full window's NIS sum is within this χ² quantile
SETTLE_S = 10.0  # a prediction this long under a command reaches the velocity it settles at
_VELOCITY_FIELDS = range(6, 12)  # robot_localization's vx .. vyaw


class CommandGuard:
    """Whether the drive follows its commands (see the module docstring)."""

    def __init__(self, window_ns: int, false_alarm: float, confirm_ns: int,
                 state_fields: tuple[int, ...]) -> None:
        self.window_ns = int(window_ns)
        self.false_alarm = float(false_alarm)
        self.confirm_ns = int(confirm_ns)
        self._velocity_rows = {i for i, f in enumerate(state_fields) if f in _VELOCITY_FIELDS}
        rows = {f: i for i, f in enumerate(state_fields)}
        self._planar = [rows[f] for f in (0, 1, 5, 6, 7)] if all(f in rows for f in (0, 1, 5, 6, 7)) else None
        self.trips = 0
        self.recoveries = 0
        self.reset()

    @classmethod
    def of(cls, config, state_fields: tuple[int, ...], used: bool) -> CommandGuard | None:
        """The guard of an EkfConfig (None without ``control_guard`` or commands)."""
        if not (config.control_guard and used):
            return None
        return cls(config.control_guard_window_ns, config.control_guard_false_alarm,
                   config.control_guard_confirm_ns,
                   state_fields)

    def reset(self) -> None:
        """Followed, no samples (a filter reset)."""
        self.followed = True
        self.last_velocity_ns: int | None = None
        self._samples: deque[tuple[int, float, int]] = deque()
        self._sums = [0.0, 0]  # the window's NIS sum and dof, kept as samples come and go
        self._since_ns: int | None = None  # when the current state began
        self.statistic = (math.nan, 0, math.nan)  # the last window's (NIS sum, dof, bound)

    @property
    def trusted_until(self) -> float:
        """The time (ns) up to which a drive command acts: -inf when not followed, inf before
        the first velocity measurement."""
        if not self.followed:
            return -math.inf
        if self.last_velocity_ns is None:
            return math.inf
        return self.last_velocity_ns + self.confirm_ns

    def screen(self, u: np.ndarray, change: float, t_ns: int, ekf) -> tuple[np.ndarray | None, float]:
        """A drive command ``u`` acting from ``t_ns`` until ``change``: None where it is not trusted.
        Where a followed command becomes unconfirmed, ``ekf``'s velocity variance grows by c²/4
        per axis (c the velocity the command settles at, body frame) and the position's by dd/4
        (d = c x confirm, rotated into the field: the robot may have stopped at the last
        measurement; rest is 2σ away); the model then predicts without the command, its
        random walk growing P."""
        until = self.trusted_until
        if t_ns < until:
            return u, min(change, until)
        if t_ns == until:
            vel = sorted(self._velocity_rows)
            c = ekf.model.f(ekf.x[None], np.asarray(u, dtype=float)[None], SETTLE_S)[0, vel]
            P = ekf.P.copy()
            P[vel, vel] += 0.25 * c * c
            if self._planar is not None:  # and the pose by the displacement since the last measurement
                (x, y, yaw), (vx, vy) = self._planar[:3], self._planar[3:]
                th = ekf.x[yaw]
                d = np.array([math.cos(th) * c[vel.index(vx)] - math.sin(th) * c[vel.index(vy)],
                              math.sin(th) * c[vel.index(vx)] + math.cos(th) * c[vel.index(vy)]])
                d *= self.confirm_ns / NS_PER_S
                P[np.ix_([x, y], [x, y])] += 0.25 * np.outer(d, d)
            ekf.set_state(ekf.x.copy(), P)
        return None, change

    def watches(self, rows) -> bool:
        """Whether an update of state ``rows`` is evidence: it measures velocities only."""
        return rows is not None and self._velocity_rows.issuperset(int(r) for r in rows)

    def observe(self, t_ns: int, rows, prior: np.ndarray, y: np.ndarray | None, S: np.ndarray | None,
                nis: float, u: np.ndarray | None, model, meas_model) -> bool:
        """One update of state ``rows`` at ``t_ns`` (prior state ``prior``, innovation y, S, its NIS)
        with drive command ``u`` in effect (None: none), for ``rows`` it :meth:`watches`.
        Returns whether ``followed`` changed."""
        if S is None:  # (the caller passes only the updates it watches)
            return False
        commanded = self.followed and t_ns <= self.trusted_until  # the prediction was command-driven
        self.last_velocity_ns = t_ns if self.last_velocity_ns is None else max(t_ns, self.last_velocity_ns)
        if u is None:
            return False
        if not commanded:  # against the velocity the command settles at
            vel = sorted(self._velocity_rows)
            x_c = prior.copy()
            x_c[vel] = model.f(prior[None], np.asarray(u, dtype=float)[None], SETTLE_S)[0, vel]
            nu = y + meas_model.h(prior[None])[0] - meas_model.h(x_c[None])[0]
            nis = float(nu @ np.linalg.solve(S, nu))
        if not math.isfinite(nis):
            return False
        if self.followed:  # one outlier alone does not trip: each NIS counts at most its own bound
            nis = min(nis, chi2_quantile(1.0 - self.false_alarm, len(rows)))
        samples, sums = self._samples, self._sums
        samples.append((t_ns, nis, len(rows)))
        sums[0] += nis
        sums[1] += len(rows)
        while samples[0][0] < t_ns - self.window_ns:
            _, old_nis, old_dof = samples.popleft()
            sums[0] -= old_nis
            sums[1] -= old_dof
        if self._since_ns is None:
            self._since_ns = t_ns
        total, dof = max(sums[0], 0.0), sums[1]
        if self.followed:
            bound = chi2_quantile(1.0 - self.false_alarm, dof)
            self.statistic = (total, dof, bound)
            if total > bound:
                self._switch(False, t_ns)
                self.trips += 1
                return True
            return False
        bound = chi2_quantile(RECOVER_MASS, dof)
        self.statistic = (total, dof, bound)
        if t_ns - self._since_ns >= self.window_ns and total <= bound:
            self._switch(True, t_ns)
            self.recoveries += 1
            return True
        return False

    def _switch(self, followed: bool, t_ns: int) -> None:
        self.followed = followed
        self._samples.clear()
        self._sums = [0.0, 0]
        self._since_ns = t_ns
