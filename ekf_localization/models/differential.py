"""Tank / differential-drive model (seed 001): state [x y v φ ω], IMU acceleration as input.

Process (seed 001 eq. 2, discrete form of its appendix)::

    x' = x + v cos φ Δt      y' = y + v sin φ Δt      v' = v + a Δt
    φ' = φ + ω Δt            ω' = ω

with a the IMU's forward acceleration (control U, shape (N, 1)); without U, v is a random
walk. v is the forward speed of the robot centre (m/s), φ the yaw (rad, CCW from the map
x axis, REP-103) and ω the yaw rate (rad/s).

Measurements (seed 001 eq. 3, with the corrections listed in the seeds README):

* heading φ: the IMU's integrated yaw (sensor_msgs/Imu orientation), residual wrapped;
* yaw rate ω: the gyro (sensor_msgs/Imu angular_velocity.z);
* track speeds [v − R_l ω, v + R_r ω]: left/right tracks at R_l, R_r from the centre;
* range² to a known target: (x − x_t)² + (y − y_t)², Jacobian [2(x − x_t), 2(y − y_t), 0, 0, 0]
  (the seed prints [2x, 2y, 0, 0, 0], which is only right for a target at the origin);
* bearing of the target seen from the robot: atan2(y_t − y, x_t − x) − φ, residual wrapped
  (the seed's atan2(y − y_t, x − x_t) − φ points from the target to the robot: off by π);
* body twist [v, ω] (what a nav_msgs/Odometry twist carries for a tank drive).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.config import EkfConfig
from ekf_localization.core.linear import LinearMeasurement, nonnegative_variances, select_rows
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.process_noise import DiagonalNoise
from ekf_localization.models.drive_response import (
    DriveResponse,
    axis_noise,
    body_axes,
    pose_step,
    wheel_space,
)

N_STATE = 5
X_, Y, V, PHI, OMEGA = range(N_STATE)  # X_: X is a batch of states here
TANK_WHEELS = ("left", "right")  # the wheel order of a tank wheel command

def _f(X: np.ndarray, accel: np.ndarray | float, dt: float) -> np.ndarray:
    """Seed 001 appendix, discrete process, on a batch X (N, 5); accel (N,) or 0: ΔV = a Δt."""
    v, phi = X[:, V], X[:, PHI]
    out = np.empty_like(X)
    out[:, X_] = X[:, X_] + v * np.cos(phi) * dt
    out[:, Y] = X[:, Y] + v * np.sin(phi) * dt
    out[:, V] = v + accel * dt
    out[:, PHI] = phi + X[:, OMEGA] * dt
    out[:, OMEGA] = X[:, OMEGA]
    return out


def _jacobian(X: np.ndarray, dt: float) -> np.ndarray:
    """F_k of seed 001's appendix on a batch: (N, 5, 5)."""
    v, c, s = X[:, V], np.cos(X[:, PHI]), np.sin(X[:, PHI])
    F = np.broadcast_to(np.eye(N_STATE), (X.shape[0], N_STATE, N_STATE)).copy()
    F[:, X_, V] = c * dt
    F[:, X_, PHI] = -v * s * dt
    F[:, Y, V] = s * dt
    F[:, Y, PHI] = v * c * dt
    F[:, PHI, OMEGA] = dt
    return F


def _tank_row(x: np.ndarray, v_c: float, w_c: float, dt: float, dp: tuple[float, ...], out: np.ndarray,
              F: np.ndarray, r: list[list[float]]) -> None:
    """The tank in drive-response mode (drive_response.py), one trial: v and ω follow the
    commanded (v, ω) through the response (per axis, or in wheel space with the (2, 3) tank
    inverse kinematics); the pose integrates the exact displacement by the pose exponential.
    f into out, F (pre-zeroed) in place; r: scratch, 3 rows of 8 floats."""
    v3 = [float(x[V]), 0.0, float(x[OMEGA])]
    c3 = [v_c, 0.0, w_c]
    if dp[14] > 0.0:
        wheel_space(v3, c3, dt, dp, r)
    else:
        body_axes(v3, c3, dt, dp, r)
    G = [[0.0] * 4, [0.0] * 4]
    px, py = pose_step(x[PHI], r[0][1], r[1][1], r[2][1], G)
    out[X_] = x[X_] + px
    out[Y] = x[Y] + py
    out[V] = r[0][0]
    out[PHI] = x[PHI] + r[2][1]
    out[OMEGA] = r[2][0]
    F[X_, X_] = 1.0
    F[Y, Y] = 1.0
    F[X_, PHI] = G[0][0]
    F[Y, PHI] = G[1][0]
    F[PHI, PHI] = 1.0
    for m in (0, 2):  # body axes with a state: ẋ = v, θ̇ = ω (a tank has no ẏ)
        col = V if m == 0 else OMEGA
        F[X_, col] = G[0][1] * r[0][5 + m] + G[0][2] * r[1][5 + m] + G[0][3] * r[2][5 + m]
        F[Y, col] = G[1][1] * r[0][5 + m] + G[1][2] * r[1][5 + m] + G[1][3] * r[2][5 + m]
        F[PHI, col] = r[2][5 + m]
        F[V, col] = r[0][2 + m]
        F[OMEGA, col] = r[2][2 + m]


def _tank_f_and_jacobian(Xs: np.ndarray, C: np.ndarray, dt: float,
                         dp: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    N = Xs.shape[0]
    out = np.empty((N, N_STATE))
    F = np.zeros((N, N_STATE, N_STATE))
    r = [[0.0] * 8 for _ in range(3)]
    for b in range(N):
        _tank_row(Xs[b], *C[b].tolist(), dt, dp, out[b], F[b], r)
    return out, F


def _tank_noise(Xs: np.ndarray, dt: float, dp: tuple[float, ...], rates: np.ndarray) -> np.ndarray:
    """Per trial: the drive's exact OU noise of v and ω (axis_noise), the displacement's turned
    into the field frame, plus rates · dt on [x y v φ ω]."""
    N = Xs.shape[0]
    Q = np.zeros((N, N_STATE, N_STATE))
    qv = [0.0] * 3
    qw = [0.0] * 3
    axis_noise(dt, dp[0], dp[9], qv)
    axis_noise(dt, dp[2], dp[11], qw)
    for b in range(N):
        c = math.cos(Xs[b, PHI])
        s = math.sin(Xs[b, PHI])
        Qb = Q[b]
        Qb[X_, X_] = c * c * qv[0] + rates[0] * dt
        Qb[Y, Y] = s * s * qv[0] + rates[1] * dt
        Qb[X_, Y] = Qb[Y, X_] = c * s * qv[0]
        Qb[X_, V] = Qb[V, X_] = c * qv[1]
        Qb[Y, V] = Qb[V, Y] = s * qv[1]
        Qb[V, V] = qv[2] + rates[2] * dt
        Qb[PHI, PHI] = qw[0] + rates[3] * dt
        Qb[PHI, OMEGA] = Qb[OMEGA, PHI] = qw[1]
        Qb[OMEGA, OMEGA] = qw[2] + rates[4] * dt
    return Q


@dataclass
class DifferentialModel:
    """Process model of seed 001 with a diagonal, parameterised Q.

    Q = diag(pose_variance_rate·Δt (x, y), speed_variance_rate·Δt + acceleration_variance·Δt²
    (v; the Δt² term only with an IMU input), heading_variance_rate·Δt, yaw_rate_variance_rate·Δt).
    Units: m²/s, (m/s)²/s, (m/s²)², rad²/s, (rad/s)²/s. Control U: (N, 1) forward
    acceleration in m/s² (sensor_msgs/Imu linear_acceleration.x), or None.

    Drive-response mode (``drive`` set, the tank's cmd_vel; as the mecanum model's): U is the
    commanded (N, 2) ``[v ω]`` (``control="twist"``) or the (N, 2) wheel speeds ``[left right]``
    in rad/s (``control="wheels"``, through ``wheels_to_twist`` (2, 2)); v and ω follow it
    through :class:`~ekf_localization.models.drive_response.DriveResponse` (exact for any step),
    the pose integrates the exact displacement by the pose exponential, and the noise is the
    response's OU integral plus the rates · Δt (``acceleration_variance`` unused).
    """

    pose_variance_rate: np.ndarray = field(default_factory=lambda: np.full(2, 1e-4))
    speed_variance_rate: float = 0.5
    heading_variance_rate: float = 1e-4
    yaw_rate_variance_rate: float = 2.0
    acceleration_variance: float = 0.1
    drive: DriveResponse | None = None
    control: str = "twist"
    wheels_to_twist: np.ndarray | None = None  # (2, 2) [left right] -> [v ω], control="wheels"
    n: int = N_STATE
    x_is_angle: np.ndarray = field(default_factory=lambda: np.array([0, 0, 0, 1, 0], dtype=np.bool_))

    def __post_init__(self) -> None:
        self.pose_variance_rate = nonnegative_variances("pose_variance_rate", self.pose_variance_rate, 2)
        for name in ("speed_variance_rate", "heading_variance_rate", "yaw_rate_variance_rate",
                     "acceleration_variance"):
            setattr(self, name, float(nonnegative_variances(name, getattr(self, name), 1)[0]))
        if self.control not in ("twist", "wheels"):
            raise ValueError(f"control must be 'twist' or 'wheels', got {self.control!r}")
        if self.control == "wheels":
            M = np.asarray(self.wheels_to_twist, dtype=float) if self.wheels_to_twist is not None else None
            if M is None or M.shape != (2, 2) or not np.all(np.isfinite(M)):
                raise ValueError("control='wheels' needs wheels_to_twist, a finite (2, 2) matrix")
            self.wheels_to_twist = M
        self._rates = np.array([*self.pose_variance_rate, self.speed_variance_rate,
                                self.heading_variance_rate, self.yaw_rate_variance_rate])
        self._noise = DiagonalNoise(self._rates)  # without an input, or in drive-response mode
        accel = np.zeros(5)
        accel[2] = self.acceleration_variance
        self._noise_accel = DiagonalNoise(self._rates, accel=accel)  # with an IMU's acceleration input

    @property
    def control_dim(self) -> int:
        """1 (an IMU's forward acceleration) or, in drive-response mode, 2 ([v ω] or wheel speeds)."""
        return 1 if self.drive is None else 2

    @property
    def control_matrix(self) -> np.ndarray:
        """(2, 2) control -> [v ω] in drive-response mode: identity, or the wheel kinematics."""
        return np.eye(2) if self.control == "twist" else self.wheels_to_twist  # type: ignore[return-value]

    def _control(self, U: np.ndarray | None, N: int) -> np.ndarray:
        k = self.control_dim
        if U is None:
            return np.zeros((N, k))
        U = np.ascontiguousarray(U, dtype=float)
        if U.shape != (N, k):
            what = "forward acceleration" if self.drive is None else "commanded [v ω] or wheel speeds"
            raise ValueError(f"control must be shaped ({N}, {k}) ({what}), got {U.shape}")
        return U

    def f_and_jacobian(self, X: np.ndarray, U: np.ndarray | None,
                       dt: float) -> tuple[np.ndarray, np.ndarray]:
        X = np.ascontiguousarray(X, dtype=float)
        if self.drive is not None and U is not None:
            C = np.ascontiguousarray(self._control(U, X.shape[0]) @ self.control_matrix.T)
            return _tank_f_and_jacobian(X, C, float(dt), self.drive.params)
        return self.f(X, U, dt), self.jacobian(X, U, dt)

    def f(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        X = np.ascontiguousarray(X, dtype=float)
        if self.drive is not None:
            if U is not None:
                return self.f_and_jacobian(X, U, dt)[0]
            return _f(X, 0.0, float(dt))
        return _f(X, 0.0 if U is None else self._control(U, X.shape[0])[:, 0], float(dt))

    def jacobian(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        if self.drive is not None and U is not None:
            return self.f_and_jacobian(X, U, dt)[1]
        return _jacobian(np.ascontiguousarray(X, dtype=float), float(dt))

    def noise(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        if U is None:
            return self._noise.at(dt)
        if self.drive is not None:
            return _tank_noise(np.ascontiguousarray(X, dtype=float), float(dt), self.drive.params,
                               self._rates)
        return self._noise_accel.at(dt)


# --- measurements ------------------------------------------------------------------------------
def heading_measurement() -> LinearMeasurement:
    """IMU yaw: h = φ (seed 001 eq. 3 row 1), residual wrapped."""
    return select_rows(N_STATE, [PHI], angle_rows=(PHI,))


def yaw_rate_measurement() -> LinearMeasurement:
    """Gyro yaw rate: h = ω."""
    return select_rows(N_STATE, [OMEGA])


def twist_measurement() -> LinearMeasurement:
    """Body twist [v, ω] (nav_msgs/Odometry twist.linear.x, twist.angular.z)."""
    return select_rows(N_STATE, [V, OMEGA])


def pose_measurement() -> LinearMeasurement:
    """Field pose [x, y, φ] (e.g. a camera landmark fix), φ residual wrapped."""
    return select_rows(N_STATE, [X_, Y, PHI], angle_rows=(PHI,))


def track_speed_measurement(left_offset: float, right_offset: float) -> LinearMeasurement:
    """Track speeds [v − R_l ω, v + R_r ω] (seed 001 eq. 3 rows 2-3), m/s.

    left_offset R_l and right_offset R_r are the tracks' distances from the centre (m, > 0).
    """
    for name, value in (("left_offset", left_offset), ("right_offset", right_offset)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} must be a positive distance in metres, got {value!r}")
    H = np.zeros((2, N_STATE))
    H[0, V], H[0, OMEGA] = 1.0, -float(left_offset)
    H[1, V], H[1, OMEGA] = 1.0, float(right_offset)
    return LinearMeasurement(H)


def _target(target_xy) -> np.ndarray:
    t = np.asarray(target_xy, dtype=float)
    if t.shape != (2,) or not np.all(np.isfinite(t)):
        raise ValueError(f"target_xy must be two finite coordinates (m), got {target_xy!r}")
    return t


class RangeSquaredMeasurement:
    """Squared distance to a known target, (x − x_t)² + (y − y_t)² in m² (seed 001 eq. 3 row 4)."""

    m = 1
    z_is_angle = np.zeros(1, dtype=np.bool_)

    def __init__(self, target_xy) -> None:
        self.target = _target(target_xy)

    def h(self, X: np.ndarray) -> np.ndarray:
        d = X[:, :2] - self.target
        return np.sum(d * d, axis=1, keepdims=True)

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        """[2(x − x_t), 2(y − y_t), 0, 0, 0] (corrected row 4)."""
        J = np.zeros((X.shape[0], 1, N_STATE))
        J[:, 0, :2] = 2.0 * (X[:, :2] - self.target)
        return J


class BearingMeasurement:
    """Bearing of a known target seen from the robot, atan2(y_t − y, x_t − x) − φ (rad, CCW).

    h is returned wrapped to (-π, π] and the residual is wrapped too. Undefined when the
    robot is on the target (h and its Jacobian are then nan and the update is rejected).
    """

    m = 1
    z_is_angle = np.ones(1, dtype=np.bool_)

    def __init__(self, target_xy) -> None:
        self.target = _target(target_xy)

    def h(self, X: np.ndarray) -> np.ndarray:
        dx = self.target[0] - X[:, 0]
        dy = self.target[1] - X[:, 1]
        b = np.where((dx == 0.0) & (dy == 0.0), np.nan, np.arctan2(dy, dx))
        return wrap_angles(b - X[:, PHI])[:, None]

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        """[(y_t − y)/r², −(x_t − x)/r², 0, −1, 0] (seed 001 row 5, with the φ entry −1)."""
        dx = self.target[0] - X[:, 0]
        dy = self.target[1] - X[:, 1]
        r2 = dx * dx + dy * dy
        J = np.zeros((X.shape[0], 1, N_STATE))
        with np.errstate(divide="ignore", invalid="ignore"):
            J[:, 0, 0] = dy / r2  # ∂/∂x
            J[:, 0, 1] = -dx / r2  # ∂/∂y
        J[:, 0, PHI] = -1.0
        return J


def range_squared_measurement(target_xy) -> RangeSquaredMeasurement:
    """Range² to the target at target_xy (m, map frame)."""
    return RangeSquaredMeasurement(target_xy)


def bearing_measurement(target_xy) -> BearingMeasurement:
    """Bearing of the target at target_xy (m, map frame) relative to the robot's heading."""
    return BearingMeasurement(target_xy)


# --- as ekf_node's model "differential" ----------------------------------------------------------

def from_config(config: EkfConfig) -> DifferentialModel:
    """Q from ``process_noise_covariance`` (per second); its ``ax`` entry is the variance
    (m/s²)² of the IMU acceleration input."""
    Q = config.process_noise_covariance
    return DifferentialModel(
        pose_variance_rate=np.array([Q[0, 0], Q[1, 1]]),
        speed_variance_rate=float(Q[6, 6]), heading_variance_rate=float(Q[5, 5]),
        yaw_rate_variance_rate=float(Q[11, 11]), acceleration_variance=float(Q[12, 12]))


def tank_kinematics(wheel_radius: float, half_track: float) -> tuple[np.ndarray, np.ndarray]:
    """(2, 3) body twist [ẋ ẏ θ̇] -> wheels [left right] and (2, 2) wheels -> [v ω] of a tank with
    wheel radius r and half track b (m): w_l = (v - bω)/r, w_r = (v + bω)/r (ẏ ignored)."""
    r, b = float(wheel_radius), float(half_track)
    if not (math.isfinite(r) and r > 0.0 and math.isfinite(b) and b > 0.0):
        raise ValueError(f"wheel_radius and half_track must be positive lengths in m, got {r!r}, {b!r}")
    inverse = np.array([[1.0 / r, 0.0, -b / r], [1.0 / r, 0.0, b / r]])
    forward = np.array([[0.5 * r, 0.5 * r], [-0.5 * r / b, 0.5 * r / b]])
    return inverse, forward


_TANK_TWIST = [0, 5]  # vx, vyaw of a 6-vector (vx vy vz vroll vpitch vyaw)


def tank_drive_from_config(config: EkfConfig) -> DriveResponse:
    """The tank drive's response to cmd_vel from the control parameters (as mecanum's; the wheel
    mode uses ``wheel_radius`` and ``half_track`` b, the centre line to a wheel)."""

    def per_axis(v, limits: bool) -> np.ndarray:
        a = np.asarray(v, dtype=float)[[0, 1, 5]]
        return np.where(a > 0.0, a, math.inf) if limits else a

    wheels = {}
    if config.wheel_acceleration_limit > 0.0 or config.wheel_speed_limit > 0.0:
        wheels = dict(wheels_from_twist=tank_kinematics(config.wheel_radius, config.half_track)[0],
                      wheel_acceleration_limit=config.wheel_acceleration_limit or math.inf,
                      wheel_speed_limit=config.wheel_speed_limit or math.inf)
    return DriveResponse(
        time_constant_s=per_axis(config.control_time_constant, False),
        acceleration_limit=per_axis(config.acceleration_limits, True),
        deceleration_limit=per_axis(config.deceleration_limits, True),
        velocity_variance=per_axis(config.control_velocity_variance, False),
        latency_ns=config.control_latency_ns, **wheels)


def tank_from_config(config: EkfConfig) -> DifferentialModel:
    """The tank model: seed 001's state, cmd_vel [v ω] through the drive response with
    ``use_control`` (constant velocity, Q's rates, without a command)."""
    model = from_config(config)
    if config.use_control:
        model = DifferentialModel(
            pose_variance_rate=model.pose_variance_rate, speed_variance_rate=model.speed_variance_rate,
            heading_variance_rate=model.heading_variance_rate,
            yaw_rate_variance_rate=model.yaw_rate_variance_rate, drive=tank_drive_from_config(config))
    return model


def twist_to_tank_control(twist: np.ndarray) -> np.ndarray:
    """cmd_vel twist [vx vy vz wx wy wz] -> the tank's commanded [v ω] (vy ignored)."""
    return np.asarray(twist, dtype=float)[_TANK_TWIST].copy()


def _tank_twist_from_wheels(config: EkfConfig) -> tuple[tuple[str, ...], np.ndarray]:
    """Wheel commands [left right] (rad/s) -> the body twist [vx vy vyaw]."""
    _, fwd = tank_kinematics(config.wheel_radius, config.half_track)
    return TANK_WHEELS, np.array([fwd[0], [0.0, 0.0], fwd[1]])


def driven_wheel_rows(geometry: str, wheel_radius: float, half_wheelbase: float,
                      half_track: float) -> np.ndarray:
    """(2, 5) the wheels [left right] (rad/s) on the state: ``tank_kinematics``' inverse on [v ω]."""
    if geometry != "differential":
        raise ValueError(f"the state [x y v φ ω] has no lateral velocity: geometry '{geometry}' needs the "
                         "mecanum model; this model takes 'differential'")
    G = tank_kinematics(wheel_radius, half_track)[0]
    H = np.zeros((2, N_STATE))
    H[:, V], H[:, OMEGA] = G[:, 0], G[:, 2]
    return H


TANK_SPEC = MotionModelSpec(
    name="tank", state_fields=(0, 1, 6, 5, 11),  # [x y v φ ω], as "differential"
    build=tank_from_config, process_input="the cmd_vel twist (vx vyaw) through the drive response",
    control_from_twist=twist_to_tank_control, twist_from_wheels=_tank_twist_from_wheels,
    dead_wheel_rows=lambda W, D: track_speed_measurement(W, W).H, driven_wheel_rows=driven_wheel_rows)

SPEC = MotionModelSpec(
    name="differential", state_fields=(0, 1, 6, 5, 11),  # [x y v φ ω] (eq. 1)
    build=from_config, process_input="an IMU's forward acceleration (fuse ax in an imuN_config)",
    input_fields=(12,),
    # the tracks: rows E_L, E_R of seed 000 eq. 30
    dead_wheel_rows=lambda W, D: track_speed_measurement(W, W).H, driven_wheel_rows=driven_wheel_rows)
