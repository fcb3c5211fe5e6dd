"""What nt_bridge does with each NetworkTables value, without ROS or ntcore.

**Module states** (WPILib's ``SwerveModuleState[]``, each ``double speed`` m/s along the wheel
and ``Rotation2d angle`` rad, counter-clockwise from the robot's +x) become one joint-state
sample per value (intervals on the robot's clock), in the shape of the ``joint`` input's swerve
geometry: per module a steer joint ``<module><steer_suffix>`` (position = the angle, velocity =
the angle's wrapped change over the interval since the last value) and a drive joint
``<module><drive_suffix>`` (velocity = speed / wheel_radius, rad/s of the wheel; position = that
velocity integrated over the intervals, from 0 at start). A state is the wheel's own ground speed: the EKF's
input takes it with drive_gear_ratio 1 and coupling_ratio 0 and reads the velocities.

**Gyro**: a yaw (``double`` or ``float`` times ``gyro_scale``, ``struct:Rotation2d``) or a whole
orientation (``struct:Rotation3d``), and optionally a yaw rate (``double``/``float`` times
``gyro_rate_scale``) on a topic of its own. A yaw waits up to ``pair_window`` for the rate
sample stamped within ``pair_window`` of it, so one Imu message carries both.

Every value is counted: published, or refused with its reason (:data:`REASONS`).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ekf_localization.core.angles import quaternion_to_rpy, rpy_to_quaternion, wrap_angles, yaw_to_quaternion
from ekf_localization.core.units import NS_PER_S
from ekf_localization.frc.nt_time import NS_PER_US, US_PER_S
from ekf_localization.frc.wpilib_struct import (
    StructError,
    decode,
    float_field,
    struct_dtype,
    struct_name,
)

MODULE_STATE = "SwerveModuleState"
ROTATIONS = (("Rotation2d", False), ("Rotation3d", False))  # (struct, array?) a gyro topic may be
NO_TIME_SYNC = "no_time_sync"      # the client has not measured the server's clock offset yet
WRONG_TYPE = "wrong_type"          # the topic's type is not one the input reads
BAD_STRUCT = "bad_struct"          # the bytes do not decode by the schema (size, members)
WRONG_LENGTH = "wrong_length"      # not one state per configured module
NONFINITE = "nonfinite"            # NaN or infinity in a value
STAMP_NOT_INCREASING = "stamp_not_increasing"
STALE = "stale"                    # older than max_age when it arrived
IN_FUTURE = "in_future"            # stamped more than max_future after the ROS time it arrived at
REASONS = (NO_TIME_SYNC, WRONG_TYPE, BAD_STRUCT, WRONG_LENGTH, NONFINITE, STAMP_NOT_INCREASING, STALE,
           IN_FUTURE)


@dataclass(frozen=True)
class BridgeConfig:
    module_names: tuple[str, ...]
    wheel_radius: float
    steer_suffix: str = "_steer"
    drive_suffix: str = "_drive"
    max_age_ns: int = NS_PER_S // 2
    max_future_ns: int = NS_PER_S // 20
    gyro_scale: float = 1.0
    gyro_rate_scale: float = 1.0
    pair_window_ns: int = NS_PER_S // 50
    has_rate: bool = False


@dataclass(frozen=True)
class JointSample:
    stamp_ns: int
    names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray


@dataclass(frozen=True)
class GyroSample:
    stamp_ns: int
    quaternion: tuple[float, float, float, float]  # x, y, z, w
    yaw_rate: float | None  # rad/s; None: no rate sample within the pair window


@dataclass
class InputStats:
    """One NT input's counts (a reason per refused value)."""

    received: int = 0
    published: int = 0
    rejected: Counter = field(default_factory=Counter)
    last_server_us: int | None = None  # the robot's timestamp of the last value taken
    clock_restarts: int = 0  # the robot's clock started again (a rebooted roboRIO)

    def refuse(self, reason: str) -> None:
        self.rejected[reason] += 1


def check_stamp(stats: InputStats, server_us: int, stamp_ns: int | None, now_ns: int,
                cfg: BridgeConfig) -> str | None:
    """The reason a value the robot stamped ``server_us``, ``stamp_ns`` in ROS time (None: no clock
    sync yet), arriving at ROS time ``now_ns`` is refused; None when it is taken."""
    if stamp_ns is None:
        return NO_TIME_SYNC
    if stamp_ns > now_ns + cfg.max_future_ns:
        return IN_FUTURE
    if stamp_ns < now_ns - cfg.max_age_ns:
        return STALE
    if stats.last_server_us is not None and server_us <= stats.last_server_us:
        if stats.last_server_us - server_us <= cfg.max_age_ns // NS_PER_US:
            return STAMP_NOT_INCREASING
        # further back than any repeat can be, and fresh in ROS time: the robot's clock restarted
        stats.clock_restarts += 1
        stats.last_server_us = None
    return None


class DtypeCache:
    """Struct dtypes by name from the schemas in force (the robot's, else WPILib's)."""

    def __init__(self, schemas: Mapping[str, str]) -> None:
        self.schemas = dict(schemas)
        self._dtypes: dict[str, np.dtype] = {}

    def update(self, name: str, schema: str) -> None:
        if self.schemas.get(name) != schema:
            self.schemas[name] = schema
            self._dtypes.clear()

    def dtype(self, name: str) -> np.dtype:
        if name not in self._dtypes:
            self._dtypes[name] = struct_dtype(name, self.schemas)
        return self._dtypes[name]


class ModuleStates:
    """``struct:SwerveModuleState[]`` values -> :class:`JointSample` (module docstring)."""

    def __init__(self, cfg: BridgeConfig) -> None:
        self.cfg = cfg
        self.stats = InputStats()
        self.names = tuple(f"{m}{s}" for m in cfg.module_names for s in (cfg.steer_suffix, cfg.drive_suffix))
        n = len(cfg.module_names)
        self._drive_positions = np.zeros(n)
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # angles, wheel rates

    def read(self, type_string: str, value: object, server_us: int, stamp_ns: int | None, now_ns: int,
             dtypes: DtypeCache) -> JointSample | None:
        """The sample of one value (robot time ``server_us``, ROS time ``stamp_ns``, arrived at
        ``now_ns``), or None with the reason counted."""
        self.stats.received += 1
        reason, sample = self._read(type_string, value, server_us, stamp_ns, now_ns, dtypes)
        if reason is not None:
            self.stats.refuse(reason)
            return None
        self.stats.published += 1
        return sample

    def _read(self, type_string: str, value: object, server_us: int, stamp_ns: int | None, now_ns: int,
              dtypes: DtypeCache) -> tuple[str | None, JointSample | None]:
        if struct_name(type_string) != (MODULE_STATE, True) or not isinstance(value, (bytes, bytearray)):
            return WRONG_TYPE, None
        try:
            states = decode(value, dtypes.dtype(MODULE_STATE))
            speeds, angles = float_field(states, "speed"), float_field(states, "angle.value")
        except StructError:
            return BAD_STRUCT, None
        if len(states) != len(self.cfg.module_names):
            return WRONG_LENGTH, None
        if not (np.all(np.isfinite(speeds)) and np.all(np.isfinite(angles))):
            return NONFINITE, None
        reason = check_stamp(self.stats, server_us, stamp_ns, now_ns, self.cfg)
        if reason is not None:
            return reason, None
        angles = wrap_angles(angles)
        wheel_rates = speeds / self.cfg.wheel_radius
        steer_rates = np.zeros_like(angles)
        if self._last is not None and self.stats.last_server_us is not None:  # not across a restart
            last_angles, last_rates = self._last
            dt = (server_us - self.stats.last_server_us) / US_PER_S
            steer_rates = wrap_angles(angles - last_angles) / dt
            self._drive_positions += 0.5 * (wheel_rates + last_rates) * dt  # trapezoid
        self._last = (angles, wheel_rates)
        self.stats.last_server_us = server_us
        positions = np.column_stack([angles, self._drive_positions]).ravel()
        velocities = np.column_stack([steer_rates, wheel_rates]).ravel()
        return None, JointSample(stamp_ns, self.names, positions, velocities)


def _scalar(type_string: str, value: object) -> float | None:
    """A ``double``/``float`` topic's value, else None."""
    if type_string in ("double", "float") and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    return None


class Gyro:
    """Yaw (or orientation) and yaw-rate values -> :class:`GyroSample` (module docstring)."""

    def __init__(self, cfg: BridgeConfig) -> None:
        self.cfg = cfg
        self.stats = InputStats()
        self.rate_stats = InputStats()
        self._rates: deque[tuple[int, float]] = deque(maxlen=64)
        # (arrival, stamp, quaternion) of the orientations waiting for their rate
        self._pending: deque[tuple[int, int, tuple[float, float, float, float]]] = deque()

    def orientation(self, type_string: str, value: object, dtypes: DtypeCache,
                    ) -> tuple[tuple[float, float, float, float] | None, str | None]:
        """(x, y, z, w) of one yaw/orientation value, or (None, reason)."""
        yaw = _scalar(type_string, value)
        if yaw is not None:
            yaw *= self.cfg.gyro_scale
        else:
            name = struct_name(type_string)
            if name not in ROTATIONS or not isinstance(value, (bytes, bytearray)):
                return None, WRONG_TYPE
            try:
                rot = decode(value, dtypes.dtype(name[0]))
                if len(rot) != 1:
                    return None, BAD_STRUCT
                if name[0] == "Rotation2d":
                    yaw = float(float_field(rot, "value")[0])
                else:
                    w, x, y, z = (float(float_field(rot, f"q.{c}")[0]) for c in "wxyz")
                    rpy = quaternion_to_rpy(x, y, z, w)  # nan: not finite, or all zero
                    if not all(math.isfinite(a) for a in rpy):
                        return None, NONFINITE if not all(map(math.isfinite, (w, x, y, z))) else BAD_STRUCT
                    return rpy_to_quaternion(*rpy), None
            except StructError:
                return None, BAD_STRUCT
        if not math.isfinite(yaw):
            return None, NONFINITE
        return yaw_to_quaternion(yaw), None

    def add_orientation(self, type_string: str, value: object, server_us: int, stamp_ns: int | None,
                        now_ns: int, dtypes: DtypeCache) -> None:
        self.stats.received += 1
        q, reason = self.orientation(type_string, value, dtypes)
        if reason is None:
            reason = check_stamp(self.stats, server_us, stamp_ns, now_ns, self.cfg)
        if reason is not None:
            self.stats.refuse(reason)
            return
        self.stats.last_server_us = server_us
        self._pending.append((now_ns, stamp_ns, q))

    def add_rate(self, type_string: str, value: object, server_us: int, stamp_ns: int | None,
                 now_ns: int) -> None:
        self.rate_stats.received += 1
        rate = _scalar(type_string, value)
        reason = WRONG_TYPE if rate is None else None if math.isfinite(rate) else NONFINITE
        if reason is None:
            reason = check_stamp(self.rate_stats, server_us, stamp_ns, now_ns, self.cfg)
        if reason is not None:
            self.rate_stats.refuse(reason)
            return
        self.rate_stats.last_server_us = server_us
        self.rate_stats.published += 1
        self._rates.append((stamp_ns, rate * self.cfg.gyro_rate_scale))

    def ready(self, now_ns: int) -> list[GyroSample]:
        """The orientations that have their rate, or have waited ``pair_window`` for it, in order."""
        out = []
        window = self.cfg.pair_window_ns
        while self._pending:
            arrived, stamp, q = self._pending[0]
            rate = min(((abs(t - stamp), r) for t, r in self._rates if abs(t - stamp) <= window),
                       default=None)
            if rate is None and self.cfg.has_rate and now_ns - arrived < window:
                break  # its rate may still come
            self._pending.popleft()
            self.stats.published += 1
            out.append(GyroSample(stamp, q, None if rate is None else rate[1]))
        return out
