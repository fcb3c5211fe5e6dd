"""Mecanum-drive process model (seed 000, eq. 19-27).

State ``[x y θ ẋ ẏ θ̇]``: field-frame pose, body-frame velocities (REP-103: x forward,
y left, θ CCW). Control: either a body twist ``[ẋ ẏ θ̇]`` or the four wheel speeds
``[m1 m2 m3 m4]`` (rad/s), converted with eq. 23-24.

Wheel numbering follows the signs of eq. 24 (positive wheel speed drives the robot
forward): m1 and m3 are on the left (they slow down for a CCW turn), m2 and m4 on the
right; strafing left (+ẏ) spins m1 and m4 forward and m2, m3 backward, so with the
usual X roller pattern (seen from above) m1 = rear-left, m2 = rear-right,
m3 = front-left, m4 = front-right. L and l are the half wheelbase and half track (eq. 23).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ekf_localization.core import measurements, message_step
from ekf_localization.core.config import MECANUM_WHEELS, EkfConfig
from ekf_localization.core.kernels import (
    cholesky_rows,
    clearly_pd3,
    commanded_tail_is_pd,
    commit_prediction,
    njit,
    source_stamp,
    wrap,
)
from ekf_localization.core.linear import LinearMeasurement, select_rows
from ekf_localization.core.message_step import fuse_lanes, snapshot_into, update_lanes
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.process_noise import DiagonalNoise
from ekf_localization.models import drive_response
from ekf_localization.models.drive_response import (
    DriveResponse,
    planar_f_and_jacobian,
    planar_noise,
    planar_row,
)
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, encoder_measurement

N_STATE = 6
X, Y, THETA, VX, VY, VTH = range(N_STATE)


@dataclass(frozen=True)
class MecanumKinematics:
    """Wheel radius r, half wheelbase L and half track l (eq. 23), metres (or inches, consistently)."""

    wheel_radius: float
    half_length: float
    half_width: float

    def __post_init__(self) -> None:
        for name in ("wheel_radius", "half_length", "half_width"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name} must be a positive finite number, got {v!r}")

    @property
    def forward_matrix(self) -> np.ndarray:
        """(3, 4) wheels -> body twist, eq. 23."""
        k = 1.0 / (self.half_length + self.half_width)
        return (self.wheel_radius / 4.0) * np.array(
            [[1.0, 1.0, 1.0, 1.0], [1.0, -1.0, -1.0, 1.0], [-k, k, -k, k]])

    @property
    def inverse_matrix(self) -> np.ndarray:
        """(4, 3) body twist -> wheels, the exact inverse of eq. 23 on its range."""
        k = self.half_length + self.half_width
        return (1.0 / self.wheel_radius) * np.array(
            [[1.0, 1.0, -k], [1.0, -1.0, k], [1.0, -1.0, -k], [1.0, 1.0, k]])

    def wheels_to_twist(self, wheels: np.ndarray) -> np.ndarray:
        """Eq. 24: (..., 4) wheel speeds -> (..., 3) body twist."""
        return np.asarray(wheels, dtype=float) @ self.forward_matrix.T

    def twist_to_wheels(self, twist: np.ndarray) -> np.ndarray:
        """(..., 3) body twist -> (..., 4) wheel speeds."""
        return np.asarray(twist, dtype=float) @ self.inverse_matrix.T


@njit(cache=True, inline="always")
def f_row(x: np.ndarray, vx_n: float, vy_n: float, w_n: float, dt: float, out: np.ndarray) -> None:
    """Eq. 25 for one trial: pose by eq. 22, body velocity (vx_n, vy_n, w_n) from eq. 24.
    ``out`` may be ``x`` itself: each entry of x is read before its own is written."""
    th = x[2]
    c = math.cos(th)
    s = math.sin(th)
    vx = x[3]
    vy = x[4]
    out[0] = x[0] + dt * (vx * c - vy * s)  # eq. 22
    out[1] = x[1] + dt * (vx * s + vy * c)
    out[2] = th + dt * x[5]
    out[3] = vx_n
    out[4] = vy_n
    out[5] = w_n


@njit(cache=True, inline="always")
def _jacobian_row(x: np.ndarray, dt: float, has_control: bool, F: np.ndarray) -> None:
    """Eq. 27 for one trial (velocity rows: 0 with a command, identity without). F pre-zeroed."""
    th = x[2]
    c = math.cos(th)
    s = math.sin(th)
    vx = x[3]
    vy = x[4]
    F[0, 0] = 1.0
    F[0, 2] = dt * (-vx * s - vy * c)
    F[0, 3] = dt * c
    F[0, 4] = -dt * s
    F[1, 1] = 1.0
    F[1, 2] = dt * (vx * c - vy * s)
    F[1, 3] = dt * s
    F[1, 4] = dt * c
    F[2, 2] = 1.0
    F[2, 5] = dt
    v = 0.0 if has_control else 1.0
    F[3, 3] = v
    F[4, 4] = v
    F[5, 5] = v


@njit(cache=True)
def _f(Xs: np.ndarray, V: np.ndarray, dt: float, has_control: bool) -> np.ndarray:
    """Batched eq. 25; V (N, 3) is the commanded body twist (ignored without control)."""
    N = Xs.shape[0]
    out = np.empty((N, 6))
    for b in range(N):
        x = Xs[b]
        if has_control:  # eq. 24-25: velocities from the command
            f_row(x, V[b, 0], V[b, 1], V[b, 2], dt, out[b])
        else:  # no command: constant body velocity
            f_row(x, x[3], x[4], x[5], dt, out[b])
    return out


@njit(cache=True)
def _jacobian(Xs: np.ndarray, dt: float, has_control: bool) -> np.ndarray:
    F = np.zeros((Xs.shape[0], 6, 6))
    for b in range(Xs.shape[0]):
        _jacobian_row(Xs[b], dt, has_control, F[b])
    return F


def _f_and_jacobian(Xs: np.ndarray, V: np.ndarray, dt: float,
                    has_control: bool) -> tuple[np.ndarray, np.ndarray]:
    return _f(Xs, V, dt, has_control), _jacobian(Xs, dt, has_control)


@njit(cache=True, inline="always", error_model="numpy")
def _fp_position_row(Pb: np.ndarray, i: int, q0: float, q1: float, q2: float, p20: float, p21: float,
                     p22: float, f2: float, f3: float, f4: float) -> tuple:
    """Row ``i`` (x or y) of F P for :func:`_commanded_steps`: F's row i is 1 at i and f2, f3, f4
    in columns 2-4 (eq. 27); q0-q2 and p20-p22 are P's pose-block rows i and 2 (in registers),
    the rest is read from Pb. Each sum in ``commit_prediction``'s order, its zeros left out."""
    return (0.0 + q0 + f2 * p20 + f3 * Pb[3, 0] + f4 * Pb[4, 0],
            0.0 + q1 + f2 * p21 + f3 * Pb[3, 1] + f4 * Pb[4, 1],
            0.0 + q2 + f2 * p22 + f3 * Pb[3, 2] + f4 * Pb[4, 2],
            0.0 + Pb[i, 3] + f2 * Pb[2, 3] + f3 * Pb[3, 3] + f4 * Pb[4, 3],
            0.0 + Pb[i, 4] + f2 * Pb[2, 4] + f3 * Pb[3, 4] + f4 * Pb[4, 4],
            0.0 + Pb[i, 5] + f2 * Pb[2, 5] + f3 * Pb[3, 5] + f4 * Pb[4, 5])


@njit(cache=True, inline="always", error_model="numpy")
def _commanded_steps(x: np.ndarray, Pb: np.ndarray, vx: float, vy: float, w: float, dt: float, count: int,
                     Qs: np.ndarray, x_is_angle: np.ndarray, ws: np.ndarray) -> int:
    """Up to ``count`` steps of eq. 25-27 with a command (F's velocity rows 0) for one trial,
    in place, with P's pose block in registers; Qs is (Q + Qᵀ)/2, accepted by
    ``commanded_tail_is_pd``. Stops before a step whose f(x) is not finite or whose pose block
    fails the Cholesky test (``commit_prediction`` takes that one: it lifts). Returns how many
    steps ran.

    Each step is ``commit_prediction``'s p = 3 arithmetic in its order, F's structural zeros
    left out of F P (its sums start at +0.0 and P is finite: adding ±0 changes nothing), every
    term kept in F P Fᵀ: bit for bit its result. After a step P's rows and columns 3-5 are Qs's.
    """
    n = N_STATE
    xn = ws[3 * n]  # the predict kernel's rows: f(x), F; [2n, 3n) Cholesky scratch
    F = ws[3 * n + 1:4 * n + 1]
    rW = 2 * n
    p00, p01, p02 = Pb[0, 0], Pb[0, 1], Pb[0, 2]
    p10, p11, p12 = Pb[1, 0], Pb[1, 1], Pb[1, 2]
    p20, p21, p22 = Pb[2, 0], Pb[2, 1], Pb[2, 2]
    done = 0
    while done < count:
        f_row(x, vx, vy, w, dt, xn)
        _jacobian_row(x, dt, True, F)
        finite = True
        for i in range(n):
            finite &= math.isfinite(xn[i])
        if not finite:
            break
        f02, f03, f04 = F[0, 2], F[0, 3], F[0, 4]
        f12, f13, f14 = F[1, 2], F[1, 3], F[1, 4]
        f25 = F[2, 5]
        # F P, rows 0-2 (F's rows: 1 at the diagonal; eq. 27's terms in columns 2-5)
        a00, a01, a02, a03, a04, a05 = _fp_position_row(Pb, 0, p00, p01, p02, p20, p21, p22, f02, f03, f04)
        a10, a11, a12, a13, a14, a15 = _fp_position_row(Pb, 1, p10, p11, p12, p20, p21, p22, f12, f13, f14)
        a20 = 0.0 + p20 + f25 * Pb[5, 0]
        a21 = 0.0 + p21 + f25 * Pb[5, 1]
        a22 = 0.0 + p22 + f25 * Pb[5, 2]
        a23 = 0.0 + Pb[2, 3] + f25 * Pb[5, 3]
        a24 = 0.0 + Pb[2, 4] + f25 * Pb[5, 4]
        a25 = 0.0 + Pb[2, 5] + f25 * Pb[5, 5]
        # the pose block of F P Fᵀ + Qs (seed 000 eq. 9), upper triangle, every term of the sum
        n00 = Qs[0, 0] + a00 + a01 * 0.0 + a02 * f02 + a03 * f03 + a04 * f04 + a05 * 0.0
        n01 = Qs[0, 1] + a00 * 0.0 + a01 + a02 * f12 + a03 * f13 + a04 * f14 + a05 * 0.0
        n02 = Qs[0, 2] + a00 * 0.0 + a01 * 0.0 + a02 + a03 * 0.0 + a04 * 0.0 + a05 * f25
        n11 = Qs[1, 1] + a10 * 0.0 + a11 + a12 * f12 + a13 * f13 + a14 * f14 + a15 * 0.0
        n12 = Qs[1, 2] + a10 * 0.0 + a11 * 0.0 + a12 + a13 * 0.0 + a14 * 0.0 + a15 * f25
        n22 = Qs[2, 2] + a20 * 0.0 + a21 * 0.0 + a22 + a23 * 0.0 + a24 * 0.0 + a25 * f25
        if not clearly_pd3(n00, n01, n02, n11, n12, n22):  # the Cholesky test only near the edge
            ws[rW, 0] = n00
            ws[rW + 1, 0] = n01
            ws[rW + 1, 1] = n11
            ws[rW + 2, 0] = n02
            ws[rW + 2, 1] = n12
            ws[rW + 2, 2] = n22
            if not cholesky_rows(ws, rW, 3):
                break
        for i in range(n):
            v = xn[i]
            if x_is_angle[i]:
                v = wrap(v)
            x[i] = v
        if done == 0:  # the other blocks of the new P are Qs's
            for i in range(n):
                for j in range(3, n):
                    Pb[i, j] = Qs[i, j]
                    Pb[j, i] = Qs[j, i]
        p00, p01, p02 = n00, n01, n02
        p10, p11, p12 = n01, n11, n12
        p20, p21, p22 = n02, n12, n22
        done += 1
    Pb[0, 0], Pb[0, 1], Pb[0, 2] = p00, p01, p02
    Pb[1, 0], Pb[1, 1], Pb[1, 2] = p10, p11, p12
    Pb[2, 0], Pb[2, 1], Pb[2, 2] = p20, p21, p22
    return done


def _make_predict_kernel(stamp: str):
    """The fused predict kernel, keyed in numba's cache by ``stamp`` (see kernels.source_stamp)."""

    @njit(cache=True, error_model="numpy")
    def predict(X, P, U, has_control, dt, steps, Q, params, x_is_angle, min_variance, ok, work):
        """f (eq. 25), F (eq. 27) and F P Fᵀ + Q for every trial, ``steps`` times, in place.

        params is the (3, k) control -> body twist matrix, row-major: identity for a
        twist command, eq. 23 for wheel speeds; with a drive response its 12 parameters
        follow (the commanded twist is then the response's target, drive_response.py).
        """
        if len(stamp) < 0:  # never true: references the stamp so that it keys the cache
            return
        k = U.shape[1]
        nq = Q.shape[0]
        n = N_STATE
        xn = work[3 * n]  # work: rows [0, 3n) commit scratch, 3n: f(x), then F, then Qs
        F = work[3 * n + 1:4 * n + 1]
        F[:, :] = 0.0
        drive = params.shape[0] > 3 * k  # the drive response's parameters follow
        dp = params[3 * k:]
        r = np.empty((3, 8))
        # a command without a drive response sets the velocity (F's velocity rows are 0)
        commanded = has_control and not drive and nq == 1 and commanded_tail_is_pd(Q[0], work, 2 * n, n, 3)
        Qs = work[4 * n + 1:5 * n + 1]  # (Q + Qᵀ)/2 of the shared Q, once per call
        if commanded:
            for i in range(n):
                for j in range(n):
                    Qs[i, j] = 0.5 * (Q[0, i, j] + Q[0, j, i])
        for b in range(X.shape[0]):
            x = X[b]
            Pb = P[b]
            Qb = Q[b if nq > 1 else 0]
            vx = 0.0
            vy = 0.0
            w = 0.0
            if has_control:
                for j in range(k):
                    u = U[b, j]
                    vx += params[j] * u
                    vy += params[k + j] * u
                    w += params[2 * k + j] * u
            good = True
            done = 0
            while done < steps:  # a trial's sub-steps in a row (trials are independent)
                if commanded:
                    done += _commanded_steps(x, Pb, vx, vy, w, dt, steps - done, Qs, x_is_angle, work)
                    if done == steps:
                        break
                if has_control and drive:
                    planar_row(x, vx, vy, w, dt, dp, xn, F, r)
                else:
                    if has_control:
                        f_row(x, vx, vy, w, dt, xn)
                    else:
                        f_row(x, x[3], x[4], x[5], dt, xn)
                    _jacobian_row(x, dt, has_control, F)
                if commanded:  # a step _commanded_steps left: not finite, or its pose block lifts
                    good &= commit_prediction(x, Pb, xn, F, Qb, x_is_angle, min_variance, work, N_STATE, 3)
                else:
                    good &= commit_prediction(x, Pb, xn, F, Qb, x_is_angle, min_variance, work, N_STATE,
                                              N_STATE)
                done += 1
            ok[b] = good

    return predict


def _make_message_kernel(stamp: str):
    """The one-message kernel (core.message_step, with this model's prediction and no command)."""

    @njit(cache=True, error_model="numpy")
    def message_step(X, P, buf, dt, Q, ints, floats, work, nis, v0, c0, v1, c1, fuse):
        """core.message_step: checks, snapshot, predict (eq. 25-27, no command), updates."""
        if len(stamp) < 0:  # never true: references the stamp so that it keys the cache
            return 0
        if fuse and not fuse_lanes(buf, ints, floats, v0, c0, v1, c1, N_STATE):
            return -1
        snapshot_into(X[0], P[0], buf, N_STATE)
        ok = True
        if dt > 0.0:  # the predict kernel's step with no command
            n = N_STATE
            x = X[0]
            xn = work[3 * n]
            F = work[3 * n + 1:4 * n + 1]
            F[:, :] = 0.0  # the updates use these rows too
            f_row(x, x[3], x[4], x[5], dt, xn)
            _jacobian_row(x, dt, False, F)
            ok = commit_prediction(x, P[0], xn, F, Q[0], ints[:n], floats[0], work, n, n)
        return update_lanes(X[0], P[0], buf, ints, floats, work, nis, N_STATE, ok)

    return message_step


_predict_fused = _make_predict_kernel(source_stamp(__file__, drive_response.__file__))
_message_step = _make_message_kernel(source_stamp(__file__, drive_response.__file__, measurements.__file__,
                                                  message_step.__file__))


@dataclass
class MecanumModel:
    """Process model of eq. 22-27 with a parameterised Q (eq. 26).

    Q = diag(pose_variance_rate · dt, velocity_variance_per_step + velocity_variance_rate · dt)
    with a command, diag(pose_variance_rate · dt, velocity_variance_rate · dt) without one.
    Units: pose_variance_rate in m²/s (x, y) and rad²/s (θ); velocity_variance_per_step in
    (m/s)² and (rad/s)² per prediction (the error of the commanded velocity, eq. 26);
    velocity_variance_rate in (m/s)²/s and (rad/s)²/s (a random walk of the velocity).
    Seed 000 (inch units) uses pose_variance_rate = 0.002, velocity_variance_per_step = 0.45,
    velocity_variance_rate = 0.
    ``control`` is "twist" (U is (N, 3) body twist [ẋ ẏ θ̇]) or "wheels" (U is (N, 4) wheel
    speeds in rad/s, needs ``kinematics``). With U = None the body velocity is held constant
    and only ``velocity_variance_rate`` lets it change: set it > 0 when predicting without
    a command.

    ``drive``: with a :class:`~ekf_localization.models.drive_response.DriveResponse`, a
    command is the target the body velocity responds to (lag, acceleration limits) instead
    of the next velocity (eq. 25), and its noise is the response's exact OU integral
    plus ``pose_variance_rate · dt`` (``velocity_variance_per_step`` and
    ``velocity_variance_rate`` apply only without a command).
    """

    pose_variance_rate: np.ndarray = field(default_factory=lambda: np.full(3, 0.002))
    velocity_variance_per_step: np.ndarray = field(default_factory=lambda: np.full(3, 0.45))
    velocity_variance_rate: np.ndarray = field(default_factory=lambda: np.zeros(3))
    control: str = "twist"
    kinematics: MecanumKinematics | None = None
    drive: DriveResponse | None = None
    n: int = N_STATE
    x_is_angle: np.ndarray = field(default_factory=lambda: np.array([0, 0, 1, 0, 0, 0], dtype=np.bool_))

    def __post_init__(self) -> None:
        for name in ("pose_variance_rate", "velocity_variance_per_step", "velocity_variance_rate"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape == ():
                v = np.full(3, float(v))
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v < 0.0):
                raise ValueError(f"{name} must be 3 finite non-negative variances, got {v!r}")
            setattr(self, name, v)
        if self.control not in ("twist", "wheels"):
            raise ValueError(f"control must be 'twist' or 'wheels', got {self.control!r}")
        if self.control == "wheels" and self.kinematics is None:
            raise ValueError("control='wheels' needs kinematics")
        rates = np.concatenate([self.pose_variance_rate, self.velocity_variance_rate])
        self._noise = DiagonalNoise(rates)  # eq. 26 without a command, and with one
        per_step = np.concatenate([np.zeros(3), self.velocity_variance_per_step])
        self._noise_commanded = DiagonalNoise(rates, per_step)

    @property
    def control_dim(self) -> int:
        """Length of one control vector: 3 (twist) or 4 (wheel speeds)."""
        return 3 if self.control == "twist" else 4

    @property
    def control_matrix(self) -> np.ndarray:
        """(3, k) control -> body twist: identity, or eq. 23 for wheel speeds."""
        if self.control == "twist":
            return np.eye(3)
        return self.kinematics.forward_matrix  # type: ignore[union-attr]

    @property
    def kernel_params(self) -> np.ndarray:
        m = self.control_matrix.ravel()
        if self.drive is not None:
            m = np.concatenate([m, self.drive.kernel_params])
        return np.ascontiguousarray(m)

    @property
    def predict_kernel(self):
        return _predict_fused

    @property
    def message_kernel(self):
        """core.message_step's one-message kernel (no command acting)."""
        return _message_step

    def _twist(self, U: np.ndarray | None, N: int) -> np.ndarray:
        if U is None:
            return np.zeros((N, 3))
        U = np.asarray(U, dtype=float)
        if U.shape != (N, self.control_dim):
            raise ValueError(f"control must be shaped ({N}, {self.control_dim}), got {U.shape}")
        if self.control == "wheels":
            return np.ascontiguousarray(self.kinematics.wheels_to_twist(U))  # type: ignore[union-attr]
        return np.ascontiguousarray(U)

    def f(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        """Eq. 25 (or the drive response) on a batch X (N, 6)."""
        return self.f_and_jacobian(X, U, dt)[0]

    def jacobian(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        """Eq. 27 (or the drive response's) on a batch: (N, 6, 6)."""
        if self.drive is None or U is None:
            return _jacobian(np.ascontiguousarray(X, dtype=float), float(dt), U is not None)
        return self.f_and_jacobian(X, U, dt)[1]

    def f_and_jacobian(self, X: np.ndarray, U: np.ndarray | None,
                       dt: float) -> tuple[np.ndarray, np.ndarray]:
        X = np.ascontiguousarray(X, dtype=float)
        if self.drive is not None and U is not None:
            return planar_f_and_jacobian(X, self._twist(U, X.shape[0]), float(dt), self.drive.kernel_params)
        return _f_and_jacobian(X, self._twist(U, X.shape[0]), float(dt), U is not None)

    def noise(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        """Eq. 26, shared by every trial: (1, 6, 6), the model's own array until the next call
        with another dt (core.process_noise); with a drive response and a command, per trial
        (N, 6, 6) (its pose-velocity terms turn with θ)."""
        if U is None:
            return self._noise.at(dt)
        if self.drive is not None:
            return planar_noise(np.ascontiguousarray(X, dtype=float), float(dt), self.drive.kernel_params,
                                self.pose_variance_rate)
        return self._noise_commanded.at(dt)


def heading_measurement() -> LinearMeasurement:
    """IMU yaw (sensor_msgs/Imu orientation) on the mecanum state: h(s) = θ, wrapped residual."""
    return select_rows(N_STATE, [THETA], angle_rows=(THETA,))


def yaw_rate_measurement() -> LinearMeasurement:
    """Gyro yaw rate (sensor_msgs/Imu angular_velocity.z) on the mecanum state: h(s) = θ̇."""
    return select_rows(N_STATE, [VTH])


# --- as ekf_node's model "mecanum" ---------------------------------------------------------------

_PLANAR_TWIST = [0, 1, 5]  # vx vy vyaw of a 6-vector (vx vy vz vroll vpitch vyaw)


def drive_response_from_config(config: EkfConfig) -> DriveResponse:
    """The drive's response to cmd_vel (drive_response.py) from the control parameters."""

    def limits(v) -> np.ndarray:
        a = np.asarray(v, dtype=float)[_PLANAR_TWIST]
        return np.where(a > 0.0, a, math.inf)

    wheels = {}
    if config.wheel_acceleration_limit > 0.0 or config.wheel_speed_limit > 0.0:
        kin = MecanumKinematics(config.wheel_radius, config.half_wheelbase, config.half_track)
        wheels = dict(wheels_from_twist=kin.inverse_matrix,
                      wheel_acceleration_limit=config.wheel_acceleration_limit or math.inf,
                      wheel_speed_limit=config.wheel_speed_limit or math.inf)
    return DriveResponse(
        time_constant_s=np.asarray(config.control_time_constant, dtype=float)[_PLANAR_TWIST],
        acceleration_limit=limits(config.acceleration_limits),
        deceleration_limit=limits(config.deceleration_limits),
        velocity_variance=np.asarray(config.control_velocity_variance, dtype=float)[_PLANAR_TWIST],
        latency_ns=config.control_latency_ns, **wheels)


def from_config(config: EkfConfig) -> MecanumModel:
    """Q from ``process_noise_covariance`` (per second, multiplied by dt).

    With ``use_control`` a command drives the velocity through the drive response (lag,
    acceleration limits, ``control_velocity_variance`` its stationary deviation); with all
    time constants and limits 0 that is eq. 25-26 (the command is the next velocity, with
    ``control_velocity_variance`` added at every step).
    """
    Q = config.process_noise_covariance
    cv = np.asarray(config.control_velocity_variance, dtype=float)[_PLANAR_TWIST]
    drive = drive_response_from_config(config) if config.use_control else None
    if drive is not None and not np.any(drive.time_constant_s) and drive.wheels_from_twist is None \
            and np.all(np.isinf(drive.acceleration_limit)) and np.all(np.isinf(drive.deceleration_limit)):
        drive = None  # seed 000 itself: eq. 22 with the current velocity, then eq. 25
    return MecanumModel(
        pose_variance_rate=np.array([Q[0, 0], Q[1, 1], Q[5, 5]]),
        velocity_variance_rate=np.array([Q[6, 6], Q[7, 7], Q[11, 11]]),
        velocity_variance_per_step=cv if config.use_control and drive is None else np.zeros(3),
        control="twist", drive=drive)


def twist_to_control(twist: np.ndarray) -> np.ndarray:
    """cmd_vel twist [vx vy vz wx wy wz] -> the model's input [ẋ ẏ θ̇] (eq. 25)."""
    return np.asarray(twist, dtype=float)[_PLANAR_TWIST].copy()


SPEC = MotionModelSpec(
    name="mecanum", state_fields=(0, 1, 5, 6, 7, 11),  # [x y θ ẋ ẏ θ̇], body-frame velocities (eq. 19)
    build=from_config, process_input="the cmd_vel twist (vx vy vyaw)", control_from_twist=twist_to_control,
    dead_wheel_rows=lambda W, D: encoder_measurement(DeadWheelGeometry(W, D)).H,  # eq. 33
    twist_from_wheels=lambda c: (MECANUM_WHEELS, MecanumKinematics(
        c.wheel_radius, c.half_wheelbase, c.half_track).forward_matrix))  # eq. 23-24, wheels m1..m4
