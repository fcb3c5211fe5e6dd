"""Speed of the EKF core: one predict + one 6-component update of the mecanum model.

Peers run in the same process on the same data (seed 000's model, eq. 22-27, with the
measurement of eq. 31: camera pose + three dead-wheel encoders, R of eq. 32):

* single trial: ours (``ExtendedKalmanFilter``) vs filterpy's ``ExtendedKalmanFilter`` and
  a plain-numpy EKF (``np.linalg.solve``, Joseph form), all three fed the same steps;
* batched, N = 100 trials: ours (``BatchedEKF``) vs the same filter written with numpy on
  stacked arrays (``np.matmul``, ``np.linalg.solve``).

Each figure is the minimum over interleaved repeats (the machine is shared and noisy);
the ratios are what to read. The filters' final estimates are compared too, so a fast
but wrong filter would show. Run: ``python benchmarks/bench_ekf_core.py [--steps 2000]``.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter as FilterpyEKF

from ekf_localization.core.angles import wrap_angle, wrap_angles
from ekf_localization.core.ekf import BatchedEKF, ExtendedKalmanFilter
from ekf_localization.core.linear import LinearMeasurement, stack_measurements
from ekf_localization.core.units import ns_to_seconds
from ekf_localization.models.mecanum import MecanumModel
from ekf_localization.models.sensors.camera import CameraNoise
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, EncoderNoise, encoder_measurement

DT_NS = 10_000_000  # the paper's EKF step, 10 ms
DT = ns_to_seconds(DT_NS)
IS_ANGLE = np.array([False, False, True, False, False, False])


def make_problem(steps: int, trials: int, seed: int = 0):
    """Seed-000 model in SI units and simulated controls / measurements for every trial."""
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


def run_numpy(model, meas, U, Q, Z, Rs) -> tuple[float, np.ndarray]:
    H = meas.H
    I6 = np.eye(6)
    x, P = np.zeros(6), np.eye(6)
    t0 = time.perf_counter()
    for k in range(len(U)):
        F = F_numpy(x)
        x = f_numpy(x, U[k])
        x[2] = wrap_angle(x[2])
        P = F @ P @ F.T + Q
        R = Rs[k, 0]
        PHt = P @ H.T
        S = H @ PHt + R
        K = np.linalg.solve(S, PHt.T).T
        x = x + K @ residual(Z[k, 0], H @ x)
        A = I6 - K @ H
        P = A @ P @ A.T + K @ R @ K.T
    return time.perf_counter() - t0, x


def run_ours(model, meas, U, Q, Z, Rs) -> tuple[float, np.ndarray]:
    ekf = ExtendedKalmanFilter(model, np.zeros(6), np.eye(6))
    t0 = time.perf_counter()
    for k in range(len(U)):
        ekf.predict(DT_NS, U[k])
        ekf.update(meas, Z[k, 0], Rs[k, 0])
    return time.perf_counter() - t0, ekf.x.copy()


def run_ours_batched(model, meas, U, Q, Z, Rs) -> tuple[float, np.ndarray]:
    N = Z.shape[1]
    ekf = BatchedEKF(model, np.zeros((N, 6)), np.eye(6))
    Ub = np.repeat(U[:, None, :], N, axis=1)
    t0 = time.perf_counter()
    for k in range(len(U)):
        ekf.predict(DT_NS, Ub[k])
        ekf.update(meas, Z[k], Rs[k])
    return time.perf_counter() - t0, ekf.X.copy()


def run_numpy_batched(model, meas, U, Q, Z, Rs) -> tuple[float, np.ndarray]:
    N = Z.shape[1]
    H = meas.H
    I6 = np.eye(6)
    X, P = np.zeros((N, 6)), np.tile(np.eye(6), (N, 1, 1))
    t0 = time.perf_counter()
    for k in range(len(U)):
        c, s = np.cos(X[:, 2]), np.sin(X[:, 2])
        F = np.zeros((N, 6, 6))
        F[:, 0, 0] = F[:, 1, 1] = F[:, 2, 2] = 1.0
        F[:, 0, 2] = DT * (-X[:, 3] * s - X[:, 4] * c)
        F[:, 0, 3], F[:, 0, 4] = DT * c, -DT * s
        F[:, 1, 2] = DT * (X[:, 3] * c - X[:, 4] * s)
        F[:, 1, 3], F[:, 1, 4] = DT * s, DT * c
        F[:, 2, 5] = DT
        Xn = np.empty_like(X)
        Xn[:, 0] = X[:, 0] + DT * (X[:, 3] * c - X[:, 4] * s)
        Xn[:, 1] = X[:, 1] + DT * (X[:, 3] * s + X[:, 4] * c)
        Xn[:, 2] = wrap_angles(X[:, 2] + DT * X[:, 5])
        Xn[:, 3:] = U[k]
        X = Xn
        P = F @ P @ F.transpose(0, 2, 1) + Q
        R = Rs[k]
        PHt = P @ H.T
        S = H @ PHt + R
        K = np.linalg.solve(S, PHt.transpose(0, 2, 1)).transpose(0, 2, 1)
        Y = Z[k] - X @ H.T
        Y[:, 2] = wrap_angles(Y[:, 2])
        X = X + (K @ Y[:, :, None])[:, :, 0]
        A = I6 - K @ H
        P = A @ P @ A.transpose(0, 2, 1) + K @ R @ K.transpose(0, 2, 1)
    return time.perf_counter() - t0, X


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()

    problem = make_problem(args.steps, args.trials)
    warm = tuple(a[:5] if isinstance(a, np.ndarray) and a.ndim >= 2 else a for a in problem)
    for fn in (run_ours, run_ours_batched):  # compile / load the numba kernels first
        fn(*warm)

    single = best_of({"ours": run_ours, "filterpy": run_filterpy, "numpy": run_numpy}, problem, args.repeats)
    us = {k: v[0] / args.steps * 1e6 for k, v in single.items()}
    print(f"single trial, predict + 6-component update, mecanum model, {args.steps} steps, "
          f"min of {args.repeats} interleaved repeats")
    print(f"  ours (ExtendedKalmanFilter)        {us['ours']:7.2f} us/step")
    print(f"  filterpy ExtendedKalmanFilter      {us['filterpy']:7.2f} us/step   "
          f"ratio filterpy/ours = {us['filterpy'] / us['ours']:.2f}x")
    print(f"  plain numpy (np.linalg.solve)      {us['numpy']:7.2f} us/step   "
          f"ratio numpy/ours    = {us['numpy'] / us['ours']:.2f}x")
    x_ours = single["ours"][1]
    print(f"  final-state agreement: |ours - filterpy| = {state_gap(x_ours, single['filterpy'][1]):.1e}, "
          f"|ours - numpy| = {state_gap(x_ours, single['numpy'][1]):.1e}")

    batched = best_of({"ours": run_ours_batched, "numpy": run_numpy_batched}, problem, args.repeats)
    per = {k: v[0] / (args.steps * args.trials) * 1e6 for k, v in batched.items()}
    print(f"batched, N = {args.trials} trials, {args.steps} steps")
    print(f"  ours (BatchedEKF)                  {per['ours']:7.3f} us/trial-step")
    print(f"  numpy stacked (matmul, solve)      {per['numpy']:7.3f} us/trial-step   "
          f"ratio numpy/ours = {per['numpy'] / per['ours']:.2f}x")
    print(f"  batched vs single ours: {us['ours'] / per['ours']:.1f}x cheaper per trial-step")
    gap = state_gap(batched["ours"][1], batched["numpy"][1])
    print(f"  final-state agreement: |ours - numpy| = {gap:.1e}")


if __name__ == "__main__":
    main()
