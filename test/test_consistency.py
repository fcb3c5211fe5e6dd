"""Filter consistency: on data simulated from the filter's own model with its own noise,
NEES and NIS follow their chi-square distributions (Bar-Shalom, Li, Kirubarajan, ch. 5.4).

M Monte Carlo trials, one ExtendedKalmanFilter each. Checked, at the 95% level:
* NIS: the average over every trial and update (innovations are white, so all samples are
  independent) lies inside the two-sided chi-square bound for count·m degrees of freedom,
  and the M-trial average at each update time lies inside its band at >= 90% of the times;
* NEES: the M-trial average at each time lies inside the band for M·n degrees of freedom
  at >= 90% of the times, and at the final time.
A filter told a 100x smaller process noise must fail the NEES check (the test has power).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.ekf import ExtendedKalmanFilter
from ekf_localization.models import differential
from ekf_localization.models.mecanum import MecanumModel
from ekf_localization.models.sensors import dead_wheels
from ekf_localization.models.sensors.camera import pose_measurement

M = 200  # Monte Carlo trials
DT_NS = 10_000_000
DT = DT_NS / 1e9


def band(dof_per_sample: int, samples: int) -> tuple[float, float]:
    """Two-sided 95% bounds on the average of `samples` chi-square(dof_per_sample) values."""
    dof = dof_per_sample * samples
    return chi2.ppf(0.025, dof) / samples, chi2.ppf(0.975, dof) / samples


class Trials:
    """M single filters fed trial by trial; stacked states, covariances and results."""

    def __init__(self, model, x0: np.ndarray, P0: np.ndarray) -> None:
        self.filters = [ExtendedKalmanFilter(model, x0, P0) for _ in range(M)]

    @property
    def X(self) -> np.ndarray:  # noqa: N802 - the usual symbol
        return np.stack([f.x for f in self.filters])

    @property
    def P(self) -> np.ndarray:  # noqa: N802 - the usual symbol
        return np.stack([f.P for f in self.filters])

    def predict(self, dt_ns: int, U: np.ndarray) -> np.ndarray:
        return np.array([f.predict(dt_ns, u) for f, u in zip(self.filters, U, strict=True)])

    def update(self, meas, Z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(status (M,), squared Mahalanobis distance (M,))."""
        results = [f.update(meas, z, R) for f, z in zip(self.filters, Z, strict=True)]
        return (np.array([r.status for r in results]),
                np.array([r.mahalanobis for r in results]) ** 2)


def nees(X_true: np.ndarray, ekf: Trials, is_angle: np.ndarray) -> np.ndarray:
    e = X_true - ekf.X
    e[:, is_angle] = wrap_angles(e[:, is_angle])
    return np.einsum("bi,bi->b", e, np.linalg.solve(ekf.P, e[:, :, None])[:, :, 0])


class Record:
    def __init__(self) -> None:
        self.nees: list[float] = []  # M-trial average per time step
        self.nis: dict[str, list[np.ndarray]] = {}  # per measurement: (M,) squared distances per update

    def add_nis(self, name: str, d2: np.ndarray) -> None:
        self.nis.setdefault(name, []).append(d2.copy())


def check(record: Record, n: int, m_of: dict[str, int]) -> None:
    lo, hi = band(n, M)
    avg = np.array(record.nees)
    inside = np.mean((avg >= lo) & (avg <= hi))
    assert inside >= 0.9, f"NEES average inside [{lo:.2f}, {hi:.2f}] at only {inside:.0%} of the steps"
    assert lo <= avg[-1] <= hi, f"final NEES average {avg[-1]:.2f} outside [{lo:.2f}, {hi:.2f}]"
    for name, values in record.nis.items():
        d2 = np.array(values)  # (updates, M)
        m = m_of[name]
        lo_all, hi_all = band(m, d2.size)
        mean = d2.mean()
        assert lo_all <= mean <= hi_all, f"{name}: NIS mean {mean:.3f} outside [{lo_all:.3f}, {hi_all:.3f}]"
        lo_t, hi_t = band(m, M)
        per_time = d2.mean(axis=1)
        inside = np.mean((per_time >= lo_t) & (per_time <= hi_t))
        assert inside >= 0.9, f"{name}: NIS average inside its band at only {inside:.0%} of the updates"


def run_mecanum(q_scale: float, seed: int = 1) -> tuple[Record, int, dict[str, int]]:
    """Seed 000's system in SI units: twist command, three dead wheels every step, camera
    pose every 10th step. Truth follows eq. 25 plus noise drawn from the model's own Q."""
    rng = np.random.default_rng(seed)
    truth_model = MecanumModel(pose_variance_rate=[2e-3, 2e-3, 2e-3],
                               velocity_variance_per_step=[0.01, 0.01, 0.03])
    filter_model = MecanumModel(pose_variance_rate=truth_model.pose_variance_rate * q_scale,
                                velocity_variance_per_step=truth_model.velocity_variance_per_step * q_scale)
    geom = dead_wheels.DeadWheelGeometry(half_track=0.18, lateral_offset=0.1)
    enc, cam = dead_wheels.encoder_measurement(geom), pose_measurement()
    enc_noise = dead_wheels.EncoderNoise(speed_variance_coeff=0.002, variance_floor=1e-4)
    R_cam = np.diag([4e-4, 4e-4, 1e-3])
    is_angle = truth_model.x_is_angle
    x0 = np.array([0.0, 0.0, math.pi - 0.2, 0.0, 0.0, 0.0])  # heading crosses ±π during the run
    P0 = np.diag([0.01, 0.01, 0.005, 0.01, 0.01, 0.01])
    X = x0 + rng.multivariate_normal(np.zeros(6), P0, size=M)
    ekf = Trials(filter_model, x0, P0)
    rec = Record()
    for k in range(300):
        t = k * DT
        u = np.array([0.8 + 0.4 * math.sin(0.7 * t), 0.3 * math.cos(0.5 * t), 1.2 * math.sin(0.4 * t)])
        U = np.tile(u, (M, 1))
        Q = truth_model.noise(None, U, DT)[0]
        X = truth_model.f(X, U, DT) + rng.multivariate_normal(np.zeros(6), Q, size=M)
        assert ekf.predict(DT_NS, U).all()
        # encoders: variance of eq. 32 at the commanded speeds (known to simulator and filter)
        R_enc = enc_noise.covariance(geom.encoders_from_twist @ u)
        Z = enc.h(X) + rng.multivariate_normal(np.zeros(3), R_enc, size=M)
        status, d2 = ekf.update(enc, Z, R_enc)
        assert (status == 0).all()
        rec.add_nis("encoders", d2)
        if k % 10 == 9:
            Z = cam.h(X) + rng.multivariate_normal(np.zeros(3), R_cam, size=M)
            Z[:, 2] = wrap_angles(Z[:, 2])
            status, d2 = ekf.update(cam, Z, R_cam)
            assert (status == 0).all()
            rec.add_nis("camera", d2)
        rec.nees.append(float(nees(X, ekf, is_angle).mean()))
    return rec, 6, {"encoders": 3, "camera": 3}


def run_differential(seed: int = 2) -> tuple[Record, int, dict[str, int]]:
    """Seed 001's tank drive: IMU acceleration input, track speeds and gyro every step,
    IMU heading every 5th, range² and bearing to a known target alternately every 10th."""
    rng = np.random.default_rng(seed)
    model = differential.DifferentialModel(pose_variance_rate=[1e-3, 1e-3], speed_variance_rate=0.05,
                                           heading_variance_rate=1e-4, yaw_rate_variance_rate=0.5,
                                           acceleration_variance=0.2)
    target = (6.0, 3.0)
    tracks, gyro = differential.track_speed_measurement(0.3, 0.32), differential.yaw_rate_measurement()
    heading = differential.heading_measurement()
    rng2, bearing = differential.range_squared_measurement(target), differential.bearing_measurement(target)
    R = {"tracks": np.diag([4e-4, 4e-4]), "gyro": np.array([[1e-4]]), "heading": np.array([[4e-4]]),
         "range2": np.array([[0.05]]), "bearing": np.array([[2e-4]])}
    models = {"tracks": tracks, "gyro": gyro, "heading": heading, "range2": rng2, "bearing": bearing}
    is_angle = model.x_is_angle
    x0 = np.array([0.0, 0.0, 0.5, 0.3, 0.1])
    P0 = np.diag([0.01, 0.01, 0.01, 0.002, 0.01])
    X = x0 + rng.multivariate_normal(np.zeros(5), P0, size=M)
    ekf = Trials(model, x0, P0)
    rec = Record()
    for k in range(300):
        a = np.full((M, 1), 0.6 * math.sin(0.5 * k * DT))
        Q = model.noise(None, a, DT)[0]
        X = model.f(X, a, DT) + rng.multivariate_normal(np.zeros(5), Q, size=M)
        assert ekf.predict(DT_NS, a).all()
        names = ["tracks", "gyro"] + (["heading"] if k % 5 == 4 else [])
        if k % 10 == 9:
            names.append("range2" if k % 20 == 9 else "bearing")
        for name in names:
            meas = models[name]
            Z = meas.h(X) + rng.multivariate_normal(np.zeros(meas.m), R[name], size=M)
            if meas.z_is_angle.any():
                Z = wrap_angles(Z)
            status, d2 = ekf.update(meas, Z, R[name])
            assert (status == 0).all()
            rec.add_nis(name, d2)
        rec.nees.append(float(nees(X, ekf, is_angle).mean()))
    return rec, 5, {name: models[name].m for name in models}


def test_mecanum_filter_is_consistent() -> None:
    check(*run_mecanum(q_scale=1.0))


def test_differential_filter_with_range_and_bearing_is_consistent() -> None:
    check(*run_differential())


def test_an_overconfident_filter_fails_the_nees_check() -> None:
    rec, n, m_of = run_mecanum(q_scale=0.01)
    lo, hi = band(n, M)
    assert np.mean(np.array(rec.nees) > hi) > 0.5
    with pytest.raises(AssertionError):
        check(rec, n, m_of)
