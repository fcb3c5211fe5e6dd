"""BatchedEKF (seed_experiments.batched.ekf): N independent trials stepped at once equal N
single-trial filters.

Each scenario runs the same random data through one BatchedEKF and through N separate
ExtendedKalmanFilter objects, with per-trial controls, per-trial R, per-trial masks,
gates that reject some trials and not others, and invalid measurements in some trials.
Statuses must be identical and states/covariances equal to 1e-12 (relative), bit for bit
where every step runs compiled code. Under adversarial inputs (ill-conditioned or huge
covariances, tiny, zero or correlated R) both keep every P symmetric positive definite and
accept the same updates; wrong shapes and float time are refused.
"""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.ekf import (
    STATUS_GATED,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_TEXT,
    ExtendedKalmanFilter,
)
from ekf_localization.core.linear import stack_measurements
from ekf_localization.models import differential
from ekf_localization.models.mecanum import MecanumKinematics, MecanumModel
from ekf_localization.models.sensors import dead_wheels
from ekf_localization.models.sensors.camera import pose_measurement
from seed_experiments.batched.ekf import BatchedEKF
from seed_experiments.models import linear_kf2d, unicycle
from seed_experiments.models.dead_reckoning import DeadReckoning, integrate

N = 12
STEPS = 60
DT_NS = 10_000_000


def random_spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.1 * np.eye(n))


def scenario(name: str):
    """(process model, control width or None, measurement models, measurement scale)."""
    geom = dead_wheels.DeadWheelGeometry(0.18, 0.1)
    if name == "mecanum-twist":
        return MecanumModel(), 3, [pose_measurement(), dead_wheels.encoder_measurement(geom)]
    if name == "mecanum-wheels":
        kin = MecanumKinematics(0.048, 0.17, 0.2)
        return (MecanumModel(control="wheels", kinematics=kin), 4,
                [dead_wheels.twist_measurement(), pose_measurement()])
    if name == "differential":
        target = (3.0, 1.0)
        return (differential.DifferentialModel(), 1,
                [differential.bearing_measurement(target), differential.range_squared_measurement(target),
                 differential.track_speed_measurement(0.3, 0.3), differential.heading_measurement()])
    if name == "unicycle":
        return (unicycle.UnicycleModel(0.033, 0.08), 2,
                [unicycle.pose_measurement(), unicycle.position_measurement()])
    if name == "kf2d":
        return linear_kf2d.motion_model(), 2, [linear_kf2d.position_measurement()]
    raise KeyError(name)


@pytest.mark.parametrize("name", ["mecanum-twist", "mecanum-wheels", "differential", "unicycle", "kf2d"])
def test_batched_equals_n_single_filters(name: str) -> None:
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    model, k, measurements = scenario(name)
    n = model.n
    X0 = rng.normal(size=(N, n))
    P0 = np.stack([random_spd(rng, n) for _ in range(N)])
    batch = BatchedEKF(model, X0, P0)
    singles = [ExtendedKalmanFilter(model, X0[i], P0[i]) for i in range(N)]
    truth = X0 + rng.normal(size=(N, n)) * 0.1
    seen = set()
    # The batched filter neutralises masked components, the single one drops them: the same
    # equations in another order. Each step's rounding is a few eps · cond(S) of the matrices'
    # scale, so the two agree to 1e-10 of that scale after STEPS steps (cond(S) <= ~1e3 here).
    for step in range(STEPS):
        U = None if (k is None or step % 5 == 4) else rng.normal(size=(N, k))
        ok = batch.predict(DT_NS, U)
        for i, f in enumerate(singles):
            assert f.predict(DT_NS, None if U is None else U[i]) == ok[i]
        meas = measurements[step % len(measurements)]
        m = meas.m
        with np.errstate(all="ignore"):
            Z = meas.h(truth) + rng.normal(size=(N, m)) * 0.05
        R = np.stack([random_spd(rng, m, 0.01) for _ in range(N)])
        mask = rng.random((N, m)) > 0.2
        Z[0, 0] = math.nan  # trial 0: invalid first component, fused only where masked out
        gate = 0.7 if step % 3 == 0 else math.inf  # rejects some trials, not all
        status, d2 = batch.update(meas, Z, R, mask=mask, gate_sigmas=gate)
        for i, f in enumerate(singles):
            res = f.update(meas, Z[i], R[i], mask=mask[i], gate_sigmas=gate)
            assert res.status == status[i], (step, i, res.reason)
            if math.isnan(d2[i]):
                assert math.isnan(res.mahalanobis)
            else:
                assert res.mahalanobis == pytest.approx(math.sqrt(d2[i]), rel=1e-12)
            np.testing.assert_allclose(batch.X[i], f.x, rtol=0, atol=1e-10 * np.abs(f.x).max())
            np.testing.assert_allclose(batch.P[i], f.P, rtol=0, atol=1e-10 * np.abs(f.P).max())
        seen.update(int(s) for s in status)
    assert {STATUS_OK, STATUS_GATED, STATUS_NONFINITE} <= seen  # the scenario exercised all paths


def test_shared_and_per_trial_arguments_broadcast_alike() -> None:
    """R (m, m) vs (N, m, m) and mask (m,) vs (N, m) with equal rows give identical results."""
    rng = np.random.default_rng(21)
    model = MecanumModel()
    meas = pose_measurement()
    X0 = rng.normal(size=(N, 6))
    a = BatchedEKF(model, X0, np.eye(6))
    b = BatchedEKF(model, X0, np.eye(6))
    R = random_spd(rng, 3, 0.01)
    mask = np.array([True, False, True])
    for _ in range(10):
        U = rng.normal(size=(N, 3))
        a.predict(DT_NS, U)
        b.predict(DT_NS, U)
        Z = rng.normal(size=(N, 3))
        sa, _ = a.update(meas, Z, R, mask=mask)
        sa = sa.copy()
        sb, _ = b.update(meas, Z, np.broadcast_to(R, (N, 3, 3)), mask=np.broadcast_to(mask, (N, 3)))
        np.testing.assert_array_equal(sa, sb)
    np.testing.assert_array_equal(a.X, b.X)
    np.testing.assert_array_equal(a.P, b.P)


def test_rejected_trials_do_not_disturb_the_others() -> None:
    rng = np.random.default_rng(22)
    model = MecanumModel()
    meas = pose_measurement()
    X0 = rng.normal(size=(4, 6))
    batch = BatchedEKF(model, X0, np.eye(6))
    U = rng.normal(size=(4, 3))
    U[2, 0] = math.inf  # trial 2's prediction is not finite
    ok = batch.predict(DT_NS, U)
    np.testing.assert_array_equal(ok, [True, True, False, True])
    np.testing.assert_array_equal(batch.X[2], X0[2])
    Z = batch.X[:, :3].copy()
    Z[1, 1] = math.nan
    status, _ = batch.update(meas, Z, np.eye(3) * 0.01)
    np.testing.assert_array_equal(status, [STATUS_OK, STATUS_NONFINITE, STATUS_OK, STATUS_OK])


def test_dead_reckoning_batched_equals_single_and_matches_the_model() -> None:
    rng = np.random.default_rng(23)
    model = unicycle.UnicycleModel(0.033, 0.08)
    X0 = rng.normal(size=(5, 5))
    controls = rng.normal(size=(40, 5, 2)) * 3.0
    batch = DeadReckoning(model, X0)
    singles = [DeadReckoning(model, X0[i]) for i in range(5)]
    for u in controls:
        assert batch.predict(DT_NS, u)
        for i, s in enumerate(singles):
            assert s.predict(DT_NS, u[i])
    for i, s in enumerate(singles):
        np.testing.assert_array_equal(batch.x[i], s.x)
    # the trajectory helper is the same Euler steps (seed 002 eq. 1)
    traj = integrate(model, X0[0], controls[:, 0], DT_NS)
    assert traj.shape == (41, 5)
    np.testing.assert_allclose(traj[-1], singles[0].x, rtol=0, atol=1e-12)
    x = X0[0].copy()
    for u in controls[:, 0]:
        x = x + 0.01 * model.rates(x[None], u[None])[0]
    x[0] = math.remainder(x[0], 2 * math.pi)
    np.testing.assert_allclose(traj[-1], x, atol=1e-12)


@pytest.mark.parametrize("name", ["mecanum-wheels", "mecanum-no-command", "mecanum-drive", "differential",
                                  "unicycle"])
def test_predict_steps_equals_that_many_predicts(name: str) -> None:
    """``predict(dt, U, steps)`` (one compiled call, a trial's sub-steps in a row) is bit for bit
    ``steps`` calls of ``predict(dt, U)``, with the model's own noise at every step (a drive
    response's Q depends on the state: made per step), and ``ok`` is every step's."""
    from ekf_localization.models.drive_response import DriveResponse

    rng = np.random.default_rng(zlib.crc32(name.encode()))
    kin = MecanumKinematics(2.0, 7.0, 6.0)
    model, k = {
        "mecanum-wheels": (MecanumModel(control="wheels", kinematics=kin), 4),
        "mecanum-no-command": (MecanumModel(velocity_variance_rate=0.1), None),
        "mecanum-drive": (MecanumModel(drive=DriveResponse(time_constant_s=[0.04, 0.06, 0.03],
                                                           velocity_variance=[1e-3, 2e-3, 1e-2])), 3),
        "differential": (differential.DifferentialModel(), 1),
        "unicycle": (unicycle.UnicycleModel(0.033, 0.08), 2),  # no fused kernel: the Python path
    }[name]
    n = model.n
    X0 = rng.normal(size=(N, n))
    P0 = np.stack([random_spd(rng, n, 0.1) for _ in range(N)])
    many = BatchedEKF(model, X0, P0)
    one = BatchedEKF(model, X0, P0)
    for _ in range(4):
        U = None if k is None else rng.normal(size=(N, k))
        ok = many.predict(1_000_000, U, steps=7).copy()
        for _ in range(7):
            assert one.predict(1_000_000, U).all()
        assert ok.all()
        np.testing.assert_array_equal(many.X, one.X)
        np.testing.assert_array_equal(many.P, one.P)
    with pytest.raises(ValueError, match="steps"):
        many.predict(1_000_000, U, steps=0)


def spd(rng: np.random.Generator, n: int, cond: float = 10.0) -> np.ndarray:
    """A random symmetric positive definite matrix with the given condition number."""
    Qm, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (Qm * np.geomspace(1.0, 1.0 / cond, n)) @ Qm.T


def assert_spd(P: np.ndarray) -> None:
    assert np.all(np.isfinite(P))
    np.testing.assert_array_equal(P, np.swapaxes(P, -1, -2))
    np.linalg.cholesky(P)  # raises if not positive definite


@pytest.mark.parametrize("case", ["ill-conditioned", "huge-variances", "tiny-R", "exact-measurement",
                                  "correlated-R"])
def test_covariance_stays_symmetric_positive_definite(case: str) -> None:
    """test_ekf_engine's test of the single filter, on a batch and on N single filters fed alike:
    the same statuses, every P symmetric positive definite."""
    geom = dead_wheels.DeadWheelGeometry(half_track=0.18, lateral_offset=0.1)
    full = stack_measurements(pose_measurement(), dead_wheels.encoder_measurement(geom))
    rng = np.random.default_rng(9)
    N = 64
    model = MecanumModel(pose_variance_rate=0.0, velocity_variance_per_step=0.0)  # Q = 0: nothing helps P
    cond = {"ill-conditioned": 1e12}.get(case, 100.0)
    scale = {"huge-variances": 1e12}.get(case, 1.0)
    P0 = np.stack([spd(rng, 6, cond) * scale for _ in range(N)])
    ekf = BatchedEKF(model, rng.normal(size=(N, 6)), P0)
    singles = [ExtendedKalmanFilter(model, ekf.X[i], P0[i]) for i in range(N)]
    for _ in range(40):
        U = rng.normal(size=(N, 3))
        ok = ekf.predict(DT_NS, U)
        assert ok.all()
        assert_spd(ekf.P)
        assert [f.predict(DT_NS, U[i]) for i, f in enumerate(singles)] == ok.tolist()
        if case == "tiny-R":
            R = np.eye(6) * 1e-15
        elif case == "exact-measurement":
            R = np.zeros((6, 6))
        elif case == "correlated-R":
            R = np.stack([spd(rng, 6, 1e6) * 1e-3 for _ in range(N)])
        else:
            R = np.diag(rng.uniform(1e-4, 1e-1, 6))
        Z = full.h(ekf.X) + rng.normal(size=(N, 6)) * 0.01
        status, d2 = ekf.update(full, Z, R)
        assert np.all(status == STATUS_OK), [STATUS_TEXT[s] for s in status]
        assert np.all(np.isfinite(d2)) and np.all(np.isfinite(ekf.X))
        assert_spd(ekf.P)
        results = [f.update(full, Z[i], R if R.ndim == 2 else R[i]) for i, f in enumerate(singles)]
        assert [r.status for r in results] == status.tolist()
        assert_spd(np.stack([f.P for f in singles]))
    if case == "exact-measurement":  # the measured components are now known (up to min_variance lifts)
        np.testing.assert_allclose(full.h(ekf.X), np.where(full.z_is_angle, wrap_angles(Z), Z), atol=1e-6)


def test_float_time_and_wrong_shapes_are_refused() -> None:
    model = MecanumModel()
    full = stack_measurements(pose_measurement(), dead_wheels.encoder_measurement(
        dead_wheels.DeadWheelGeometry(half_track=0.18, lateral_offset=0.1)))
    batch = BatchedEKF(model, np.zeros((3, 6)), np.eye(6))
    single = ExtendedKalmanFilter(model, np.zeros(6), np.eye(6))
    for f in (batch, single):
        with pytest.raises(TypeError):
            f.predict(0.01)  # type: ignore[arg-type]
    batch = BatchedEKF(model, np.zeros((4, 6)), np.eye(6))
    with pytest.raises(ValueError, match="control"):
        batch.predict(DT_NS, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="Z must be"):
        batch.update(full, np.zeros((3, 6)), np.eye(6))
    with pytest.raises(ValueError, match="R must be"):
        batch.update(full, np.zeros((4, 6)), np.zeros((3, 6, 6)))
