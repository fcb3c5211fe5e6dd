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

from ekf_localization.core.config import MECANUM_WHEELS, EkfConfig
from ekf_localization.core.linear import LinearMeasurement, select_rows
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.process_noise import DiagonalNoise
from ekf_localization.models.differential import tank_kinematics
from ekf_localization.models.drive_response import DriveResponse, planar_f_and_jacobian, planar_noise
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, encoder_measurement

N_STATE = 6
X_, Y, THETA, VX, VY, VTH = range(N_STATE)  # X_: X is a batch of states here


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


def _f(X: np.ndarray, V: np.ndarray | None, dt: float) -> np.ndarray:
    """Eq. 22 and 25 on a batch X (N, 6): the pose moves with the current body velocity (eq. 22),
    which becomes the commanded twist V (N, 3) (eq. 24-25), or is held without a command."""
    if X.shape[0] == 1:  # the single filter: the same equations on floats, one array built
        x, y, th, vx, vy, w = X[0].tolist()
        c, s = math.cos(th), math.sin(th)
        v = (vx, vy, w) if V is None else V[0].tolist()
        return np.array([[x + dt * (vx * c - vy * s), y + dt * (vx * s + vy * c), th + dt * w, *v]])
    th, vx, vy = X[:, THETA], X[:, VX], X[:, VY]
    c, s = np.cos(th), np.sin(th)
    out = np.empty_like(X)
    out[:, X_] = X[:, X_] + dt * (vx * c - vy * s)  # eq. 22
    out[:, Y] = X[:, Y] + dt * (vx * s + vy * c)
    out[:, THETA] = th + dt * X[:, VTH]
    out[:, VX:] = X[:, VX:] if V is None else V  # eq. 25
    return out


def _constant_jacobian(has_control: bool) -> np.ndarray:
    """(1, 6, 6) the entries of eq. 27 that do not depend on the state or the step (read-only)."""
    F = np.eye(N_STATE)[None]
    if has_control:
        F[0, VX, VX] = F[0, VY, VY] = F[0, VTH, VTH] = 0.0
    F.setflags(write=False)
    return F


_F_COMMANDED, _F_HELD = _constant_jacobian(True), _constant_jacobian(False)


def _jacobian(X: np.ndarray, dt: float, has_control: bool) -> np.ndarray:
    """Eq. 27 on a batch: (N, 6, 6). The velocity rows are 0 with a command (it sets the
    velocity), the identity without one."""
    if X.shape[0] == 1:  # the single filter: the same entries on floats
        _, _, th, vx, vy, _ = X[0].tolist()
        return _jacobian_one(math.cos(th), math.sin(th), vx, vy, dt, has_control)
    th, vx, vy = X[:, THETA], X[:, VX], X[:, VY]
    c, s = np.cos(th), np.sin(th)
    F = np.zeros((X.shape[0], N_STATE, N_STATE))
    F[:, X_, X_] = F[:, Y, Y] = F[:, THETA, THETA] = 1.0
    F[:, X_, THETA] = dt * (-vx * s - vy * c)
    F[:, X_, VX] = dt * c
    F[:, X_, VY] = -dt * s
    F[:, Y, THETA] = dt * (vx * c - vy * s)
    F[:, Y, VX] = dt * s
    F[:, Y, VY] = dt * c
    F[:, THETA, VTH] = dt
    if not has_control:
        F[:, VX, VX] = F[:, VY, VY] = F[:, VTH, VTH] = 1.0
    return F


def _jacobian_one(c: float, s: float, vx: float, vy: float, dt: float, has_control: bool) -> np.ndarray:
    """Eq. 27 of one state (cos θ, sin θ, vx, vy as floats) into a copy of the constant part: (1, 6, 6)."""
    F = (_F_COMMANDED if has_control else _F_HELD).copy()
    F0 = F[0]
    F0[0, 2] = dt * (-vx * s - vy * c)
    F0[0, 3] = dt * c
    F0[0, 4] = -dt * s
    F0[1, 2] = dt * (vx * c - vy * s)
    F0[1, 3] = dt * s
    F0[1, 4] = dt * c
    F0[2, 5] = dt
    return F


def _f_and_jacobian_one(x: list[float], v: list[float] | None, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_f` and :func:`_jacobian` of one state (as floats), velocity ``v`` commanded or held."""
    px, py, th, vx, vy, w = x
    c, s = math.cos(th), math.sin(th)
    f = np.array([[px + dt * (vx * c - vy * s), py + dt * (vx * s + vy * c), th + dt * w,
                   *((vx, vy, w) if v is None else v)]])
    return f, _jacobian_one(c, s, vx, vy, dt, v is not None)


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
            return planar_f_and_jacobian(X, self._twist(U, X.shape[0]), float(dt), self.drive.params)
        V = None if U is None else self._twist(U, X.shape[0])
        if X.shape[0] == 1:  # the single filter: both from one read of the state
            return _f_and_jacobian_one(X[0].tolist(), None if V is None else V[0].tolist(), float(dt))
        return _f(X, V, float(dt)), _jacobian(X, float(dt), U is not None)

    def noise(self, X: np.ndarray, U: np.ndarray | None, dt: float) -> np.ndarray:
        """Eq. 26, shared by every trial: (1, 6, 6), the model's own array until the next call
        with another dt (core.process_noise); with a drive response and a command, per trial
        (N, 6, 6) (its pose-velocity terms turn with θ)."""
        if U is None:
            return self._noise.at(dt)
        if self.drive is not None:
            return planar_noise(np.ascontiguousarray(X, dtype=float), float(dt), self.drive.params,
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
    elif config.control_steer_rate_limit > 0.0:  # the swerve response (models/swerve_response.py)
        wheels = dict(steer_rate_limit=config.control_steer_rate_limit,
                      module_positions=np.reshape(config.control_module_positions, (-1, 2)))
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
            and drive.module_positions is None \
            and np.all(np.isinf(drive.acceleration_limit)) and np.all(np.isinf(drive.deceleration_limit)):
        drive = None  # seed 000 itself: eq. 22 with the current velocity, then eq. 25
    return MecanumModel(
        pose_variance_rate=np.array([Q[0, 0], Q[1, 1], Q[5, 5]]),
        velocity_variance_rate=np.array([Q[6, 6], Q[7, 7], Q[11, 11]]),
        velocity_variance_per_step=cv if config.use_control and drive is None else np.zeros(3),
        control="twist", drive=drive)


def driven_wheel_rows(geometry: str, wheel_radius: float, half_wheelbase: float,
                      half_track: float) -> np.ndarray:
    """(k, 6) the driven wheels' speeds (rad/s) on the state: eq. 23's inverse on [ẋ ẏ θ̇] for the
    four mecanum wheels m1..m4, or a differential pair [left right] (ẏ not seen)."""
    if geometry == "mecanum":
        G = MecanumKinematics(wheel_radius, half_wheelbase, half_track).inverse_matrix
    elif geometry == "differential":
        G = tank_kinematics(wheel_radius, half_track)[0]
    else:
        raise ValueError(f"no driven-wheel geometry '{geometry}' (mecanum, differential)")
    H = np.zeros((G.shape[0], N_STATE))
    H[:, VX:] = G
    return H


def twist_to_control(twist: np.ndarray) -> np.ndarray:
    """cmd_vel twist [vx vy vz wx wy wz] -> the model's input [ẋ ẏ θ̇] (eq. 25)."""
    return np.asarray(twist, dtype=float)[_PLANAR_TWIST].copy()


SPEC = MotionModelSpec(
    name="mecanum", state_fields=(0, 1, 5, 6, 7, 11),  # [x y θ ẋ ẏ θ̇], body-frame velocities (eq. 19)
    build=from_config, process_input="the cmd_vel twist (vx vy vyaw)", control_from_twist=twist_to_control,
    dead_wheel_rows=lambda W, D: encoder_measurement(DeadWheelGeometry(W, D)).H,  # eq. 33
    driven_wheel_rows=driven_wheel_rows,  # eq. 23's inverse
    twist_from_wheels=lambda c: (MECANUM_WHEELS, MecanumKinematics(
        c.wheel_radius, c.half_wheelbase, c.half_track).forward_matrix))  # eq. 23-24, wheels m1..m4
