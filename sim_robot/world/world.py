"""The simulated world: true robot motion at 1 kHz and the sensors, for N trials at once.

No ROS, no unit conversions: every length, speed and noise comes from ``WorldConfig`` in
one consistent length unit (``WorldConfig()`` is SI, ``WorldConfig.seed000_inches()``
is seed 000's inch model with the paper's exact constants). Angles are radians, time is
integer nanoseconds at every interface (seconds only inside a tick).

API::

    world = World(config: WorldConfig, n_trials: int = 1, seed: int = 0)
    world.reset(pose)               # (3,) or (N, 3) [x y θ] in the field frame; velocities,
                                    # wheel speeds and clock to 0; sensor schedules restart
    world.set_command(twist, stamp_ns=None)  # (3,) or (N, 3) body twist [vx vy wz]; tank ignores vy;
                                    # acts from stamp_ns (default: now) + command_latency_ns
    world.set_wheel_command(wheels, stamp_ns=None)  # (k,) or (N, k) wheel speeds (rad/s), k = 4
                                    # mecanum, 2 tank; the same timing
    readings = world.step()         # one physics tick; readings that became due, time order
    readings = world.advance(duration_ns)  # many ticks (duration a multiple of the tick)
    world.t_ns                      # int clock (ns), exact: ticks · physics_period_ns
    world.truth                     # (N, 6) [x y θ vx vy wz], body-frame velocities (tank: vy = 0)
    world.truth_accel               # (N, 2) body-frame acceleration of the drive
    world.wheel_speeds              # (N, k) actual wheel speeds after the limits

Readings (dataclasses of batched arrays, integer-ns stamps): ``TruthReading``,
``ImuReading`` (``sim_robot.world.imu_sensor``), ``DeadWheelReading``
(``sim_robot.world.dead_wheel_sensor``), ``CameraReading`` (``sim_robot.world.camera_sensor``),
``WheelEncoderReading`` (the drive's own wheels, ``sim_robot.world.wheel_encoder_sensor``: a
jittered schedule of its own, off by default). A second camera (``camera1``, off by default: the
same sensor at another mount, its own noise stream) gives ``CameraReading``s with ``camera`` 1.
Each sensor samples at the multiples of its own period (the first sample one period
after ``reset``); a camera capture is delivered ``latency_ns`` after its stamp, at the
first tick at or after ``arrival_ns``. Readings delivered on the same tick come in the
order truth, IMU, dead wheels, camera (the first, then the second), wheel encoders.

Commands: a command acts from its stamp plus ``command_latency_ns`` (the drive's response
time), from the first tick at or after that time, or at once when that time has passed (a
late command; ``late_commands`` counts them). Later-stamped commands replace earlier ones.

Truth model, one tick of Δt = ``physics_period_ns`` (seed 000):

1. pose: eq. 22 with the previous body velocity, plus position noise
   ``N(0, pose_variance_rate·Δt)`` per component (eq. 26); θ wrapped to (-π, π]. On a
   ramp (``sim_robot.world.ramp``) the body velocity is along the surface and its
   horizontal part, ``core.tilt``'s P(roll, pitch)·[vx vy wz], takes its place;
2. wheels: the commanded wheel speeds (inverse kinematics of the command, scaled
   together to the speed limit) are approached by at most
   ``wheel_acceleration_limit·Δt`` (``sim_robot.world.drives``; both limits default to off);
3. velocity: eq. 24 from the wheel speeds (mecanum's vy times ``strafe_scale``), plus
   ``N(0, velocity_variance_per_step)`` per component (eq. 26; tank: no vy noise, vy = 0);
4. a push (``WorldConfig.bump``, ``sim_robot.world.bump``): its field velocity, rotated into
   the body frame, is added to the body velocity and its acceleration to ``truth_accel``; the
   wheels keep their speeds, so their encoders do not see it, the dead wheels and the IMU do.

A swerve drive (``drive="swerve"``, ``sim_robot.world.swerve_drive``) replaces steps 2-3: its
modules steer and drive toward the command within their limits and the floor's grip gives the
body twist, plus the same noise; its wheel encoders read the drive joints (gear and coupling
ratios) and the steer angles.

``truth_accel`` is the body-frame acceleration of the noise-free drive velocity
``v_d`` (step 3 without noise): ``[v̇x − wz·vy, v̇y + wz·vx]`` with v̇ the change of v_d
over the tick; the white velocity noise of eq. 26 has no finite derivative and is
left out. The IMU gets its mean over the IMU's sample period (an accelerometer's low-pass
filter), not one tick's value. The random streams (truth, dead wheels, camera, IMU) are independent children
of ``seed``; the truth stream gives 6 normals per trial and tick, so the truth does not
depend on which sensors are enabled or how ``step``/``advance`` calls are split, and it
continues across ``reset``. Trials share the streams, so a batched run differs from
separate single-trial runs with noise on; with the noise variances set to zero it agrees
with them to rounding (numpy's matrix products may round one row and many differently).
"""

from __future__ import annotations

import bisect
import dataclasses
from collections import deque
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.tilt import horizontal_projection
from ekf_localization.core.units import METRES_PER_INCH, ns_to_seconds
from ekf_localization.models.mecanum import MecanumKinematics
from ekf_localization.models.sensors.camera import CameraNoise
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, EncoderNoise
from sim_robot.world.bump import Bump
from sim_robot.world.camera_sensor import CameraConfig, CameraReading, CameraSensor
from sim_robot.world.dead_wheel_sensor import DeadWheelConfig, DeadWheelReading, DeadWheelSensor
from sim_robot.world.drives import DRIVES, DriveLimits, TankKinematics, make_drive, scale_to_speed_limit
from sim_robot.world.field import Field
from sim_robot.world.imu_sensor import ImuConfig, ImuReading, ImuSensor
from sim_robot.world.ramp import Ramp
from sim_robot.world.swerve_drive import SwerveDrive, SwerveDriveConfig
from sim_robot.world.wheel_encoder_sensor import WheelEncoderConfig, WheelEncoderReading, WheelEncoderSensor

_IN2 = METRES_PER_INCH**2

# Robot geometry in metres (the paper gives none; plausible FTC values, docs/simulator.md).
WHEEL_RADIUS_M = 0.048  # 96 mm mecanum wheels
HALF_WHEELBASE_M = 0.168  # L: centre to front/rear axle
HALF_TRACK_M = 0.18  # l: centre line to wheel centre
DEAD_WHEEL_HALF_SPACING_M = 0.17  # W
DEAD_WHEEL_LATERAL_OFFSET_M = 0.1  # D: lateral pod 10 cm behind the centre
DEAD_WHEEL_RADIUS_M = 0.024  # 48 mm odometry pod wheels
TANK_HALF_TRACK_M = 0.2
IMU_ACCEL_VARIANCE_SI = 0.01  # (m/s²)²
OUTLIER_POSITION_STD_M = 0.5


@dataclass(frozen=True)
class TruthReading:
    """Ground truth for N trials (evaluation only)."""

    stamp_ns: int
    truth: np.ndarray  # (N, 6) [x y θ vx vy wz]
    accel: np.ndarray  # (N, 2) body frame
    attitude: np.ndarray | None = None  # (N, 3) [z roll pitch] on the surface (0 on level ground)


Reading = TruthReading | ImuReading | DeadWheelReading | CameraReading | WheelEncoderReading


def _triple(v) -> tuple[float, float, float]:
    t = tuple(float(x) for x in np.broadcast_to(np.asarray(v, dtype=float), (3,)))
    return t  # type: ignore[return-value]


@dataclass(frozen=True)
class WorldConfig:
    """Everything the world needs, in one length unit. Defaults: seed 000's robot in SI.

    ``pose_variance_rate`` (L², L², rad² per second) and ``velocity_variance_per_step``
    ((L/s)², (L/s)², (rad/s)² per physics tick) are eq. 26's Q: the seed's
    0.002·Δt in² and 0.45 (in/s)² converted exactly (θ components unchanged).
    """

    drive: str = "mecanum"
    mecanum: MecanumKinematics = dataclasses.field(default_factory=lambda: MecanumKinematics(
        WHEEL_RADIUS_M, HALF_WHEELBASE_M, HALF_TRACK_M))
    tank: TankKinematics = dataclasses.field(
        default_factory=lambda: TankKinematics(WHEEL_RADIUS_M, TANK_HALF_TRACK_M))
    strafe_scale: float = 1.0  # mecanum: the robot's vy per eq. 24's (rollers slip sideways: < 1)
    limits: DriveLimits = dataclasses.field(default_factory=DriveLimits)
    swerve: SwerveDriveConfig = dataclasses.field(default_factory=SwerveDriveConfig)
    physics_period_ns: int = 1_000_000
    pose_variance_rate: tuple[float, float, float] = (0.002 * _IN2, 0.002 * _IN2, 0.002)
    velocity_variance_per_step: tuple[float, float, float] = (0.45 * _IN2, 0.45 * _IN2, 0.45)
    field: Field = dataclasses.field(default_factory=lambda: Field.preset("seed000", METRES_PER_INCH))
    dead_wheels: DeadWheelConfig = dataclasses.field(default_factory=DeadWheelConfig)
    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)
    camera1: CameraConfig = dataclasses.field(default_factory=lambda: CameraConfig(enabled=False))
    imu: ImuConfig = dataclasses.field(default_factory=ImuConfig)
    wheel_encoders: WheelEncoderConfig = dataclasses.field(default_factory=WheelEncoderConfig)
    truth_period_ns: int = 10_000_000
    ramp: Ramp = dataclasses.field(default_factory=Ramp)
    command_latency_ns: int = 0  # a command acts this long after its stamp
    bump: Bump | None = None  # a push by the world (sim_robot.world.bump); None: none

    def __post_init__(self) -> None:
        if self.drive not in DRIVES:
            raise ValueError(f"drive must be one of {DRIVES}, got {self.drive!r}")
        if not (np.isfinite(self.strafe_scale) and self.strafe_scale > 0.0):
            raise ValueError(f"strafe_scale must be finite and > 0, got {self.strafe_scale!r}")
        if isinstance(self.command_latency_ns, bool) or not isinstance(self.command_latency_ns, int) \
                or self.command_latency_ns < 0:
            raise ValueError(f"command_latency_ns must be an int >= 0, got {self.command_latency_ns!r}")
        if not (isinstance(self.physics_period_ns, int) and self.physics_period_ns > 0):
            raise ValueError(f"physics_period_ns must be a positive int, got {self.physics_period_ns!r}")
        for name in ("pose_variance_rate", "velocity_variance_per_step"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v < 0.0):
                raise ValueError(f"{name} must be 3 finite variances >= 0, got {getattr(self, name)!r}")
            object.__setattr__(self, name, _triple(v))
        for name, period in self.sensor_periods_ns().items():
            if not (isinstance(period, int) and period > 0 and period % self.physics_period_ns == 0):
                raise ValueError(f"{name} ({period!r} ns) must be a positive whole multiple of "
                                 f"physics_period_ns ({self.physics_period_ns} ns)")

    def sensor_periods_ns(self) -> dict[str, int]:
        return {"truth_period_ns": self.truth_period_ns,
                "dead_wheels.period_ns": self.dead_wheels.period_ns,
                "camera.period_ns": self.camera.period_ns,
                "camera1.period_ns": self.camera1.period_ns,
                "imu.period_ns": self.imu.period_ns}

    @classmethod
    def seed000(cls, metres_per_unit: float = 1.0, **overrides) -> WorldConfig:
        """Seed 000's robot in the length unit of ``metres_per_unit`` metres (1.0 = SI).

        The paper's constants are in inches; they are converted exactly, so the model in
        any unit equals the inch model (eq. 32 is not unit-invariant: the coefficients of
        d² and E² and the floors scale differently, and yaw variances do not scale).
        """
        k = METRES_PER_INCH / metres_per_unit  # length units per inch (exactly 1.0 for inches)
        s = 1.0 / metres_per_unit  # length units per metre
        k2 = k * k
        base = dict(
            mecanum=MecanumKinematics(WHEEL_RADIUS_M * s, HALF_WHEELBASE_M * s, HALF_TRACK_M * s),
            tank=TankKinematics(WHEEL_RADIUS_M * s, TANK_HALF_TRACK_M * s),
            pose_variance_rate=(0.002 * k2, 0.002 * k2, 0.002),  # eq. 26
            velocity_variance_per_step=(0.45 * k2, 0.45 * k2, 0.45),
            field=Field.preset("seed000", k),
            dead_wheels=DeadWheelConfig(
                geometry=DeadWheelGeometry(DEAD_WHEEL_HALF_SPACING_M * s, DEAD_WHEEL_LATERAL_OFFSET_M * s),
                noise=EncoderNoise(0.002, 0.001 * k2),  # eq. 32: 0.002·E² + 0.001 in²/s²
                wheel_radius=DEAD_WHEEL_RADIUS_M * s),
            camera=CameraConfig(
                position_noise=CameraNoise(0.001, 0.001 * k2),  # eq. 32: 0.001·d² + 0.001 in²
                yaw_noise=CameraNoise(0.001 / k2, 0.001),  # same formula, d in inches, rad²
                outlier_position_std=OUTLIER_POSITION_STD_M * s),
            imu=ImuConfig(accel_variance=IMU_ACCEL_VARIANCE_SI * s * s),
        )
        base.update(overrides)
        return cls(**base)

    @classmethod
    def seed000_inches(cls, **overrides) -> WorldConfig:
        """Seed 000 in the paper's units (in, in/s, rad) with its exact Q and R constants."""
        return cls.seed000(METRES_PER_INCH, **overrides)


class World:
    """N independent simulated robots stepped together (module docstring)."""

    def __init__(self, config: WorldConfig, n_trials: int = 1, seed: int = 0) -> None:
        if isinstance(n_trials, bool) or not isinstance(n_trials, int | np.integer) or n_trials < 1:
            raise ValueError(f"n_trials must be an int >= 1, got {n_trials!r}")
        self.config = config
        self.n_trials = int(n_trials)
        self.physics_period_ns = config.physics_period_ns
        # a fifth child for the IMU's tilt noise, a sixth for the wheel encoders' schedule, a seventh
        # for the second camera: the first streams are those of spawn(4)
        truth_ss, dw_ss, cam_ss, imu_ss, tilt_ss, enc_ss, cam1_ss = np.random.SeedSequence(seed).spawn(7)
        self._truth_rng = np.random.default_rng(truth_ss)
        self._swerve = SwerveDrive(config.swerve, n_trials) if config.drive == "swerve" else None
        if self._swerve is None:
            drive = make_drive(config.drive, config.mecanum, config.tank)
            self._F = np.array(drive.forward_matrix, dtype=float)  # eq. 24 (tank: its own)
            if config.drive == "mecanum":
                self._F[1] *= config.strafe_scale  # the rollers' sideways slip; the wheels turn as told
            self._inverse = np.array(drive.inverse_matrix, dtype=float)
        self.n_wheels = config.swerve.n_modules if self._swerve is not None else self._F.shape[1]
        self._dt = ns_to_seconds(config.physics_period_ns)
        vel_var = np.array(config.velocity_variance_per_step)
        if config.drive == "tank":
            vel_var[1] = 0.0
        self._q_std = np.sqrt(np.concatenate([np.array(config.pose_variance_rate) * self._dt, vel_var]))
        self._max_dw = config.limits.wheel_acceleration_limit * self._dt
        self._dead_wheels = DeadWheelSensor(config.dead_wheels, n_trials, np.random.default_rng(dw_ss))
        self._camera = CameraSensor(config.camera, config.field, n_trials, np.random.default_rng(cam_ss))
        self._camera1 = CameraSensor(config.camera1, config.field, n_trials, np.random.default_rng(cam1_ss),
                                     index=1)
        self._imu = ImuSensor(config.imu, n_trials, np.random.default_rng(imu_ss),
                              np.random.default_rng(tilt_ss))
        self._encoders = WheelEncoderSensor(config.wheel_encoders, n_trials, self.n_wheels,
                                            config.physics_period_ns, np.random.default_rng(enc_ss))
        self._ramp = config.ramp
        self.reset(np.zeros(3))

    # -- state ---------------------------------------------------------------------------
    def _batch(self, a, width: int, name: str) -> np.ndarray:
        a = np.asarray(a, dtype=float)
        if a.shape not in ((width,), (self.n_trials, width)):
            raise ValueError(f"{name} must have shape ({width},) or ({self.n_trials}, {width}), "
                             f"got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be finite, got {a!r}")
        return np.ascontiguousarray(np.broadcast_to(a, (self.n_trials, width)), dtype=float).copy()

    def reset(self, pose) -> None:
        """Place every trial at ``pose`` at rest; clock to 0; sensor schedules restart."""
        N, k = self.n_trials, self.n_wheels
        p = self._batch(pose, 3, "pose")
        p[:, 2] = wrap_angles(p[:, 2])
        self._pose = p
        self._vel = np.zeros((N, 3))
        self._wheels = np.zeros((N, k))
        self._drive_vel = np.zeros((N, 3))
        self._accel = np.zeros((N, 2))
        self._accel_sum = np.zeros((N, 2))  # truth_accel summed since the last IMU sample
        self._accel_ticks = 0
        self._disp = np.zeros((N, 3))
        self._target = np.zeros((N, 3 if self._swerve is not None else k))  # swerve: the twist
        if self._swerve is not None:
            self._swerve.reset()
        self._attitude = np.zeros((N, 3))
        self._update_attitude()
        self._t = 0
        cfg = self.config
        self._due = {
            "truth": cfg.truth_period_ns,
            "imu": cfg.imu.period_ns if cfg.imu.enabled else None,
            "dead_wheels": cfg.dead_wheels.period_ns if cfg.dead_wheels.enabled else None,
            "camera": cfg.camera.period_ns if cfg.camera.enabled else None,
            "camera1": cfg.camera1.period_ns if cfg.camera1.enabled else None,
            "wheel_encoders": self._encoders.reset(0) if cfg.wheel_encoders.enabled else None,
        }
        self._pending: deque[CameraReading] = deque()
        self._commands: list[tuple[int, np.ndarray]] = []  # (acts at ns, wheel targets), time order
        self.late_commands = 0
        self._dead_wheels.reset(self._pose, self._disp, 0)

    def set_command(self, twist, stamp_ns: int | None = None) -> bool:
        """Commanded body twist [vx vy wz] -> wheel targets (inverse kinematics, speed limit),
        acting from ``stamp_ns`` (default: now) + ``command_latency_ns``. False if that has passed.
        A swerve drive keeps the twist (its modules' targets depend on their steer angles)."""
        if self._swerve is not None:
            return self._schedule(self._batch(twist, 3, "twist"), stamp_ns)
        wheels = self._batch(twist, 3, "twist") @ self._inverse.T
        return self._schedule(scale_to_speed_limit(wheels, self.config.limits.wheel_speed_limit), stamp_ns)

    def set_wheel_command(self, wheels, stamp_ns: int | None = None) -> bool:
        """Commanded wheel speeds (rad/s), scaled together to the speed limit; timing as set_command."""
        if self._swerve is not None:
            raise ValueError("a swerve drive takes twist commands (set_command), not wheel speeds")
        w = self._batch(wheels, self.n_wheels, "wheels")
        return self._schedule(scale_to_speed_limit(w, self.config.limits.wheel_speed_limit), stamp_ns)

    def _schedule(self, target: np.ndarray, stamp_ns: int | None) -> bool:
        at = (self._t if stamp_ns is None else int(stamp_ns)) + self.config.command_latency_ns
        target = np.ascontiguousarray(target)
        if at <= self._t:  # due (or late): from the next tick on; queued later-stamped ones still follow
            self.late_commands += at < self._t
            self._target = target
            return at == self._t
        i = bisect.bisect_right([c[0] for c in self._commands], at)
        self._commands.insert(i, (at, target))
        return True

    @property
    def t_ns(self) -> int:
        return self._t

    @property
    def truth(self) -> np.ndarray:
        return np.concatenate([self._pose, self._vel], axis=1)

    @property
    def attitude(self) -> np.ndarray:
        """(N, 3) [z roll pitch] of the robot on the field surface (a ramp; 0 on level ground)."""
        return self._attitude.copy()

    @property
    def truth_accel(self) -> np.ndarray:
        return self._accel.copy()

    @property
    def wheel_speeds(self) -> np.ndarray:
        """(N, k) wheel rad/s (swerve: each module's wheel)."""
        return self._swerve.wheel_rates.copy() if self._swerve is not None else self._wheels.copy()

    @property
    def swerve(self) -> SwerveDrive | None:
        """The swerve drive's modules (steer angles, wheel rates, slip), or None."""
        return self._swerve

    # -- time ----------------------------------------------------------------------------
    def step(self) -> list[Reading]:
        return self.advance(self.physics_period_ns)

    def advance(self, duration_ns: int) -> list[Reading]:
        """Run ``duration_ns`` (a whole number of ticks); return the readings in time order."""
        P = self.physics_period_ns
        if isinstance(duration_ns, bool) or not isinstance(duration_ns, int | np.integer):
            raise TypeError(f"duration_ns must be an int, got {type(duration_ns).__name__}")
        duration_ns = int(duration_ns)
        if duration_ns < 0 or duration_ns % P:
            raise ValueError(f"duration_ns must be a non-negative multiple of {P} ns, got {duration_ns}")
        end = self._t + duration_ns
        out: list[Reading] = []
        while self._t < end:
            self._apply_commands()
            events = [d for d in self._due.values() if d is not None]
            if self._pending:
                events.append(self._pending[0].arrival_ns)
            if self._commands:
                events.append(self._commands[0][0])
            nxt = min([end, *events])
            self._run_ticks(max(1, -(-(nxt - self._t) // P)))
            self._collect(out)
        self._apply_commands()
        return out

    def _apply_commands(self) -> None:
        while self._commands and self._commands[0][0] <= self._t:
            self._target = self._commands.pop(0)[1]

    def _run_ticks(self, n: int) -> None:
        for i in range(n):
            self._tick(self._truth_rng.standard_normal((self.n_trials, 6)),
                       self._t + i * self.physics_period_ns)
        self._t += n * self.physics_period_ns

    def _tick(self, z: np.ndarray, t_ns: int = 0) -> None:
        """One physics tick of every trial (module docstring, steps 1-3) from ``t_ns``; z: (N, 6)
        N(0, 1) draws."""
        dt, q = self._dt, self._q_std
        pose, vel = self._pose, self._vel
        # 1. eq. 22 with the previous body velocity + eq. 26's noise; on a ramp the body velocity
        #    is along the surface and its horizontal part (core.tilt's P(roll, pitch)) moves the pose
        h = self._horizontal(vel) if self._ramp.enabled else vel
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        pose[:, 0] += dt * (h[:, 0] * c - h[:, 1] * s) + q[0] * z[:, 0]
        pose[:, 1] += dt * (h[:, 0] * s + h[:, 1] * c) + q[1] * z[:, 1]
        pose[:, 2] = wrap_angles(pose[:, 2] + dt * h[:, 2] + q[2] * z[:, 2])
        self._update_attitude()
        self._disp += dt * vel  # the body-frame distance the dead wheels see
        if self._due["wheel_encoders"] is not None:
            self._encoders.integrate(self._wheels if self._swerve is None else self._swerve.joint_rates(), dt)
        if self._swerve is not None:  # 2-3. the modules steer and drive, the floor's grip (swerve_drive)
            v = self._swerve.step(self._target, dt)
        else:
            # 2. the wheels approach the command, the change of all scaled together to max_dw
            self._wheels += scale_to_speed_limit(self._target - self._wheels, self._max_dw)
            # 3. eq. 24 (the drive's forward matrix; tank: its own) + eq. 26's noise
            v = self._wheels @ self._F.T
        dv = (v - self._drive_vel) / dt
        self._accel[:, 0] = dv[:, 0] - v[:, 2] * v[:, 1]  # body frame: v̇ + ω × v
        self._accel[:, 1] = dv[:, 1] + v[:, 2] * v[:, 0]
        self._drive_vel = v
        self._vel = v + q[3:] * z[:, 3:]
        bump = self.config.bump
        if bump is not None and bump.active(t_ns + self.physics_period_ns):  # 4. a push (wheels unchanged)
            pv, pa = bump.velocity_acceleration(t_ns + self.physics_period_ns)
            c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
            self._vel[:, 0] += c * pv[0] + s * pv[1]  # field -> body
            self._vel[:, 1] += -s * pv[0] + c * pv[1]
            self._accel[:, 0] += c * pa[0] + s * pa[1]
            self._accel[:, 1] += -s * pa[0] + c * pa[1]
        self._accel_sum += self._accel
        self._accel_ticks += 1

    def _horizontal(self, vel: np.ndarray) -> np.ndarray:
        """[ẋ_h ẏ_h ψ̇] = P(roll, pitch)·[vx vy wz] per trial (``core.tilt.horizontal_projection``)."""
        P = horizontal_projection(self._attitude[:, 1], self._attitude[:, 2])
        return np.einsum("nij,nj->ni", P, vel)

    def _update_attitude(self) -> None:
        """[z roll pitch] at the current poses (stays 0 on level ground)."""
        if self._ramp.enabled:
            self._attitude = self._ramp.attitude(self._pose)

    def _queue(self, reading: CameraReading) -> None:
        """Hold a capture until its arrival; the queue stays in arrival order (the two cameras'
        latencies may differ)."""
        self._pending.append(reading)
        if len(self._pending) > 1 and self._pending[-2].arrival_ns > reading.arrival_ns:
            self._pending = deque(sorted(self._pending, key=lambda r: r.arrival_ns))

    def _collect(self, out: list[Reading]) -> None:
        t, due, cfg = self._t, self._due, self.config
        if due["truth"] <= t:
            out.append(TruthReading(t, self.truth, self._accel.copy(), self._attitude.copy()))
            due["truth"] += cfg.truth_period_ns
        if due["imu"] is not None and due["imu"] <= t:
            mean_accel = self._accel_sum / max(self._accel_ticks, 1)  # over its period: no aliasing
            self._accel_sum[:] = 0.0
            self._accel_ticks = 0
            out.append(self._imu.sample(t, self._pose[:, 2].copy(), self._vel[:, 2].copy(), mean_accel,
                                        self._attitude[:, 1:3]))
            due["imu"] += cfg.imu.period_ns
        if due["dead_wheels"] is not None and due["dead_wheels"] <= t:
            out.append(self._dead_wheels.sample(t, self._vel, self._disp))
            due["dead_wheels"] += cfg.dead_wheels.period_ns
        for name, camera in (("camera", self._camera), ("camera1", self._camera1)):
            if due[name] is not None and due[name] <= t:
                self._queue(camera.capture(t, self._pose))
                due[name] += camera.config.period_ns
        while self._pending and self._pending[0].arrival_ns <= t:
            out.append(self._pending.popleft())
        if due["wheel_encoders"] is not None and due["wheel_encoders"] <= t:
            if self._swerve is None:
                out.append(self._encoders.sample(t, self._wheels))
            else:
                sw = self._swerve
                out.append(self._encoders.sample(t, sw.joint_rates(), wrap_angles(sw.angles), sw.steer_rates))
            due["wheel_encoders"] += self._encoders.next_interval_ns()
