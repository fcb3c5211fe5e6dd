"""Accuracy of an estimated trajectory against ground truth (RMSE, seed 000 sec. VI A)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ekf_localization.core.angles import wrap_angles

COLUMNS = ("x", "y", "xy", "theta", "vx", "vy", "vtheta")


@dataclass
class Trajectory:
    """Stamped planar states: t_ns (K,) int64 and states (K, 6) [x y θ vx vy ω], body velocities."""

    t_ns: np.ndarray
    states: np.ndarray
    covariances: np.ndarray | None = None  # (K, 3, 3) pose covariance, optional

    def __post_init__(self) -> None:
        self.t_ns = np.asarray(self.t_ns, dtype=np.int64)
        self.states = np.asarray(self.states, dtype=float)
        if self.states.ndim != 2 or self.states.shape[0] != self.t_ns.shape[0]:
            raise ValueError("states must be (K, n) with K stamps")
        if self.t_ns.size > 1 and np.any(np.diff(self.t_ns) < 0):
            order = np.argsort(self.t_ns, kind="stable")
            self.t_ns, self.states = self.t_ns[order], self.states[order]
            if self.covariances is not None:
                self.covariances = np.asarray(self.covariances)[order]

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


def interpolate(traj: Trajectory, t_ns: np.ndarray) -> np.ndarray:
    """States of ``traj`` at ``t_ns`` (linear; the heading is unwrapped first, then rewrapped)."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    base = traj.t_ns[0]
    tq = (t_ns - base).astype(float)
    tt = (traj.t_ns - base).astype(float)
    out = np.empty((t_ns.shape[0], traj.states.shape[1]))
    for j in range(traj.states.shape[1]):
        col = np.unwrap(traj.states[:, j]) if j == 2 else traj.states[:, j]
        out[:, j] = np.interp(tq, tt, col)
    out[:, 2] = wrap_angles(out[:, 2])
    return out


def errors(estimate: Trajectory, truth: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """(t_ns, error (K, 6)) of the estimate against truth, over their common time span.

    Samples with a non-finite value (in the estimate or the truth: a recorded topic can carry
    the rejected data itself) are left out; :func:`nonfinite_samples` counts them.
    """
    if len(truth) == 0 or len(estimate) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 6))
    good = np.all(np.isfinite(truth.states[:, :6]), axis=1)
    truth = Trajectory(truth.t_ns[good], truth.states[good])
    if len(truth) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 6))
    lo, hi = truth.t_ns[0], truth.t_ns[-1]
    keep = (estimate.t_ns >= lo) & (estimate.t_ns <= hi) & np.all(np.isfinite(estimate.states[:, :6]), axis=1)
    t = estimate.t_ns[keep]
    ref = interpolate(truth, t)
    err = estimate.states[keep, :6] - ref
    err[:, 2] = wrap_angles(err[:, 2])
    return t, err


def nonfinite_samples(traj: Trajectory) -> int:
    """How many samples of ``traj`` have a non-finite value (left out of :func:`errors`)."""
    return int(np.count_nonzero(~np.all(np.isfinite(traj.states[:, :6]), axis=1)))


def rmse_from_errors(err: np.ndarray) -> dict[str, float]:
    """RMSE per column of seed 000 sec. VI A from an error array (..., 6)."""
    e = np.asarray(err, dtype=float).reshape(-1, err.shape[-1])
    if e.shape[0] == 0:
        return {c: float("nan") for c in COLUMNS}
    r = np.sqrt(np.mean(e * e, axis=0))
    return {"x": r[0], "y": r[1], "xy": float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))),
            "theta": r[2], "vx": r[3], "vy": r[4], "vtheta": r[5]}


def rmse(estimate: Trajectory, truth: Trajectory) -> dict[str, float]:
    """RMSE of x, y, (x, y), θ, ẋ, ẏ, θ̇ against truth; ``excluded`` counts the non-finite
    samples of the estimate left out (nan RMSEs: no sample left to compare)."""
    return rmse_from_errors(errors(estimate, truth)[1]) | {"excluded": nonfinite_samples(estimate)}
