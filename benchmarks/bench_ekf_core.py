"""The EKF engine Localizer runs on, against filterpy: one predict + one 6-component update.

    python benchmarks/bench_ekf_core.py [--steps 2000] [--repeats 7] [--doc]

ours: ``core.ekf.ExtendedKalmanFilter`` (the filter inside every Localizer, so inside
ekf_node) with the mecanum model of seed 000 (eq. 22-27) and the measurement of eq. 31
(camera pose + three dead-wheel encoders, R of eq. 32). The peer: filterpy's
``ExtendedKalmanFilter`` with the same model written out in numpy (f, F, the same Q, Joseph
form as ours), fed the same steps. Each figure is the minimum over interleaved repeats (the
machine is shared); the final estimates are compared, so a fast but wrong filter would show.
The shipped stream (every input of config/ekf.yaml, cmd_vel, lags) is bench_localizer.py's.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter as FilterpyEKF

from ekf_localization.core.angles import wrap_angle, wrap_angles
from ekf_localization.core.ekf import ExtendedKalmanFilter
from ekf_localization.core.linear import LinearMeasurement, stack_measurements
from ekf_localization.core.units import ns_to_seconds
from ekf_localization.models.mecanum import MecanumModel
from ekf_localization.models.sensors.camera import CameraNoise
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, EncoderNoise, encoder_measurement

DT_NS = 10_000_000  # the paper's EKF step, 10 ms
DT = ns_to_seconds(DT_NS)
IS_ANGLE = np.array([False, False, True, False, False, False])


def make_problem(steps: int, seed: int = 0, trials: int = 1):
    """Seed-000 model in SI units and simulated controls / measurements (one trial)."""
    rng = np.random.default_rng(seed)
    model = MecanumModel(pose_variance_rate=[1e-4, 1e-4, 1e-3], velocity_variance_per_step=[0.01, 0.01, 0.04])
    geometry = DeadWheelGeometry(half_track=0.18, lateral_offset=0.10)
    meas = stack_measurements(LinearMeasurement(np.eye(6)[:3], IS_ANGLE[:3]), encoder_measurement(geometry))
    camera, encoders = CameraNoise(0.0004, 0.0004), EncoderNoise(0.002, 1e-4)
    t = np.arange(steps) * DT
    U = np.stack([0.6 + 0.3 * np.sin(0.5 * t), 0.3 * np.cos(0.3 * t), 0.8 * np.sin(0.2 * t)], axis=1)
    Q = model.noise(None, U[:1], DT)[0]
    x = np.zeros((trials, 6))
    Z = np.empty((steps, trials, 6))
    Rs = np.empty((steps, trials, 6, 6))
    for k in range(steps):
        x = model.f(x, np.repeat(U[k:k + 1], trials, axis=0), DT)
        x += rng.multivariate_normal(np.zeros(6), Q, size=trials)
        z_true = meas.h(x)
        var = np.concatenate([np.repeat(camera.variance(2.0 + np.hypot(x[:, :1], x[:, 1:2])), 3, axis=1),
                              encoders.variances(z_true[:, 3:])], axis=1)
        Z[k] = z_true + rng.standard_normal((trials, 6)) * np.sqrt(var)
        Z[k, :, 2] = wrap_angles(Z[k, :, 2])
        Rs[k] = var[:, :, None] * np.eye(6)
    return model, meas, U, Q, Z, Rs


# --- peers ------------------------------------------------------------------------------------
def f_numpy(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Eq. 25 for one state, plain numpy."""
    c, s = math.cos(x[2]), math.sin(x[2])
    return np.array([x[0] + DT * (x[3] * c - x[4] * s), x[1] + DT * (x[3] * s + x[4] * c),
                     x[2] + DT * x[5], u[0], u[1], u[2]])


def F_numpy(x: np.ndarray) -> np.ndarray:  # noqa: N802 - the usual symbol
    """Eq. 27 for one state, plain numpy."""
    c, s = math.cos(x[2]), math.sin(x[2])
    F = np.zeros((6, 6))
    F[0, 0] = F[1, 1] = F[2, 2] = 1.0
    F[0, 2], F[0, 3], F[0, 4] = DT * (-x[3] * s - x[4] * c), DT * c, -DT * s
    F[1, 2], F[1, 3], F[1, 4] = DT * (x[3] * c - x[4] * s), DT * s, DT * c
    F[2, 5] = DT
    return F


def residual(z: np.ndarray, zhat: np.ndarray) -> np.ndarray:
    y = z - zhat
    y[2] = wrap_angle(y[2])
    return y


class _MecanumFilterpy(FilterpyEKF):
    def predict_x(self, u=0):
        self.x = f_numpy(self.x, u)


def run_filterpy(model, meas, U, Q, Z, Rs) -> tuple[float, np.ndarray]:
    H = meas.H
    ekf = _MecanumFilterpy(dim_x=6, dim_z=6)
    ekf.x = np.zeros(6)
    ekf.P = np.eye(6)
    ekf.Q = Q

    def hjac(x):
        return H

    def hx(x):
        return H @ x

    t0 = time.perf_counter()
    for k in range(len(U)):
        ekf.F = F_numpy(ekf.x)
        ekf.predict(U[k])
        ekf.update(Z[k, 0], hjac, hx, R=Rs[k, 0], residual=residual)
    return time.perf_counter() - t0, np.asarray(ekf.x).ravel()


def run_ours(model, meas, U, Q, Z, Rs) -> tuple[float, np.ndarray]:
    ekf = ExtendedKalmanFilter(model, np.zeros(6), np.eye(6))
    t0 = time.perf_counter()
    for k in range(len(U)):
        ekf.predict(DT_NS, U[k])
        ekf.update(meas, Z[k, 0], Rs[k, 0])
    return time.perf_counter() - t0, ekf.x.copy()


def state_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference between two estimates, θ compared as an angle (filterpy does not wrap)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    d[..., 2] = wrap_angles(d[..., 2])
    return float(np.max(np.abs(d)))


def best_of(runs: dict, args, repeats: int) -> dict[str, tuple[float, np.ndarray]]:
    """Interleave the peers' repeats; keep each one's fastest run."""
    best: dict[str, tuple[float, np.ndarray]] = {}
    for _ in range(repeats):
        for name, fn in runs.items():
            t, x = fn(*args)
            if name not in best or t < best[name][0]:
                best[name] = (t, x)
    return best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--doc", action="store_true", help="write the figure into docs/performance.md")
    args = ap.parse_args(argv)

    problem = make_problem(args.steps)
    best = best_of({"ours": run_ours, "filterpy": run_filterpy}, problem, args.repeats)
    us = {k: v[0] / args.steps * 1e6 for k, v in best.items()}
    gap = state_gap(best["ours"][1], best["filterpy"][1])
    print(f"predict + 6-component update, mecanum model, {args.steps} steps, "
          f"min of {args.repeats} interleaved repeats")
    print(f"  ours (core.ekf.ExtendedKalmanFilter)  {us['ours']:7.1f} us/step")
    print(f"  filterpy ExtendedKalmanFilter         {us['filterpy']:7.1f} us/step   "
          f"ours/filterpy = {us['ours'] / us['filterpy']:.2f}x")
    print(f"  final-state agreement |ours - filterpy| = {gap:.1e}")
    if args.doc:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from perf_doc import write_row

        path = write_row("EKF engine, predict + 6-component update (seed 000 model)",
                         f"{us['ours']:.1f} µs/step",
                         f"filterpy EKF {us['filterpy']:.1f} µs/step (same steps; states agree to {gap:.0e})")
        print(f"wrote {path}")
    return 0 if gap < 1e-9 else 1


if __name__ == "__main__":
    sys.exit(main())
