"""ekf_node parameters: parsing and validation into a plain :class:`EkfConfig` (no ROS imports).

The same parser serves the node (values read from rclpy after the parameter file is loaded)
and the offline tools (:func:`load_ekf_config` reads the YAML directly). A bad value raises
:class:`ParameterError` naming the parameter and the expected form. Names follow
robot_localization (RL) where the concept is the same; docs/ekf_node.md lists every
parameter, its unit and default, and every difference from RL.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from ekf_localization.core.joint_states import EncoderInputConfig, validate_encoder_config
from ekf_localization.core.linalg import is_positive_definite, is_symmetric
from ekf_localization.core.measurements import FIELD_NAMES, N_FIELDS
from ekf_localization.core.recovery import RecoveryConfig
from ekf_localization.core.units import METRES_PER_INCH, seconds_to_ns

if TYPE_CHECKING:
    from ekf_localization.core.motion_model import MotionModelSpec

INPUT_KINDS = ("odom", "pose", "twist", "imu", "joint")
# Fields each message type can carry.
KIND_FIELDS: dict[str, frozenset[int]] = {
    "odom": frozenset(range(12)),
    "pose": frozenset(range(6)),
    "twist": frozenset(range(6, 12)),
    "imu": frozenset((3, 4, 5, 9, 10, 11, 12, 13, 14)),
    "joint": frozenset(),  # sensor_msgs/JointState: encoder speeds, not RL fields
}
TILT_FIELDS = (3, 4)  # an imuN fusing roll and pitch supplies the tilt (core.tilt)
# jointN settings (besides the topic): suffix -> (EncoderInputConfig field, unit, description).
JOINT_SUFFIXES: dict[str, tuple[str, str, str]] = {
    "_names": ("names", "-", "joint names of the left, right[, lateral] dead wheels"),
    "_wheel_radius": ("wheel_radius", "m", "dead-wheel radius: joint rad -> m along the surface"),
    "_half_spacing": ("half_spacing", "m", "W: the parallel wheels sit at ±W from the centre line"),
    "_lateral_offset": ("lateral_offset", "m", "D: lateral wheel this far behind the centre "
                        "(negative: in front), E_a = vy - D·vyaw (seed 000 eq. 30)"),
    "_speed_variance_coeff": ("speed_variance_coeff", "-", "a of the per-wheel speed variance a·E² + b "
                              "(seed 000 eq. 32)"),
    "_speed_variance_floor": ("speed_variance_floor", "(m/s)²", "b of the per-wheel speed variance "
                              "a·E² + b"),
    "_use_velocities": ("use_velocities", "-", "use the message's velocities when present "
                        "(false: speeds from position differences)"),
    "_max_speed": ("max_speed", "m/s", "a position step faster than this is an encoder jump "
                   "(reset, wrap) and is rejected"),
    "_tilt_compensation": ("tilt_compensation", "-", "project the speeds onto the horizontal plane "
                           "with an IMU's roll and pitch"),
}
# Rejection-threshold parameter suffix -> the message part it gates, per kind (RL names).
THRESHOLD_SUFFIXES: dict[str, dict[str, str]] = {
    "odom": {"_pose_rejection_threshold": "pose", "_twist_rejection_threshold": "twist"},
    "pose": {"_rejection_threshold": "pose"},
    "twist": {"_rejection_threshold": "twist"},
    "joint": {"_rejection_threshold": "encoders"},
    "imu": {"_pose_rejection_threshold": "orientation",
            "_twist_rejection_threshold": "angular_velocity",
            "_angular_velocity_rejection_threshold": "angular_velocity",
            "_linear_acceleration_rejection_threshold": "linear_acceleration"},
}

# RL parameters this node does not implement: accepted and ignored with a warning.
RL_IGNORED = frozenset((
    "transform_time_offset", "transform_timeout", "debug", "debug_out_file", "publish_acceleration",
    "control_config", "acceleration_gains", "deceleration_gains", "dynamic_process_noise_covariance",
    "use_dynamic_process_noise_covariance", "permit_corrected_publication", "disabled_at_startup",
    "gravitational_acceleration", "reset_on_time_jump", "two_d_mode",
    # launch / node options and outputs that do not apply (docs/ekf_node.md, robot_localization table)
    "clear_params", "filter_type", "tf_prefix", "base_link_frame_output"))
RL_INPUT_IGNORED = ("_nodelay", "_remove_gravitational_acceleration")
RL_INPUT_MODES = ("_differential", "_relative")  # pose inputs: robot_localization's modes (core.pose_modes)
ROS_BUILTIN = frozenset(("use_sim_time", "start_type_description_service"))

# Timer rates a node can run (a period of at most 1000 s, at least 0.1 ms).
MIN_FREQUENCY_HZ = 1e-3
MAX_FREQUENCY_HZ = 1e4

MECANUM_WHEELS = ("rear_left", "rear_right", "front_left", "front_right")  # eq. 24's m1..m4
# Seed 000 (eq. 26) in SI: 0.002 in²/s = 1.2903e-6 m²/s, 0.45 (in/s)² = 2.9032e-4 (m/s)².
_IN2 = METRES_PER_INCH ** 2


def _diag15(values: dict[int, float], rest: float) -> np.ndarray:
    d = np.full(N_FIELDS, rest)
    for i, v in values.items():
        d[i] = v
    return np.diag(d)


DEFAULT_PROCESS_NOISE = np.diag([0.05, 0.05, 0.06, 0.03, 0.03, 0.06, 0.025, 0.025, 0.04,
                                 0.01, 0.01, 0.02, 0.01, 0.01, 0.015])  # RL's default
DEFAULT_INITIAL_COVARIANCE = _diag15({0: 1.0, 1: 1.0, 5: 1.0, 6: 1.0, 7: 1.0, 11: 1.0}, 1e-9)
DEFAULT_CONTROL_VELOCITY_VARIANCE = (0.45 * _IN2, 0.45 * _IN2, 0.0, 0.0, 0.0, 0.45)


# name -> (unit, description); defaults are in EkfConfig / InputConfig. docs/ekf_node.md mirrors this.
PARAMETERS: dict[str, tuple[str, str]] = {
    "model": ("-", "motion model: 'mecanum' (state x y yaw vx vy vyaw) or 'differential' (x y v yaw vyaw)"),
    "frequency": ("Hz", "rate of /odometry/filtered"),
    "sensor_timeout": ("s", "an input silent this long is reported stale; with predict_to_current_time "
                            "false, the output is predicted to now after this long without measurements"),
    "map_frame": ("-", "REP-105 map frame"),
    "odom_frame": ("-", "REP-105 odom frame"),
    "base_link_frame": ("-", "robot body frame"),
    "world_frame": ("-", "frame of the estimate: map_frame or odom_frame"),
    "publish_tf": ("-", "broadcast world_frame->base_link_frame (odom) or map->odom (map) when tf2 exists"),
    "print_diagnostics": ("-", "publish diagnostic_msgs/DiagnosticArray on /diagnostics"),
    "predict_to_current_time": ("-", "predict the published estimate to the current time"),
    "smooth_lagged_data": ("-", "apply lagged measurements at their stamp by rewinding the filter"),
    "history_length": ("s", "how far back the filter can rewind"),
    "max_measurement_age": ("s", "measurements stamped older than now minus this are rejected (stale)"),
    "future_stamp_tolerance": ("s", "measurements stamped later than now plus this are rejected"),
    "max_prediction_step": ("s", "longest single prediction step (longer gaps are sub-stepped)"),
    "use_control": ("-", "use cmd_vel (geometry_msgs/Twist) as the process input"),
    "stamped_control": ("-", "cmd_vel is geometry_msgs/TwistStamped and applies at its header stamp "
                        "(false: Twist, applied at its receive time)"),
    "control_timeout": ("s", "a command older than this stops being used"),
    "control_velocity_variance": ("(m/s)², (rad/s)²", "variance of the velocity a command produces, "
                                  "vx vy vz vroll vpitch vyaw (seed 000 eq. 26)"),
    "control_tilt_compensation": ("-", "project cmd_vel onto the horizontal plane with an IMU's "
                                  "roll and pitch"),
    "control_time_constant": ("s", "time constant of the drive's first-order response to a command, "
                              "vx vy vz vroll vpitch vyaw (0 = none: the command is the next velocity, "
                              "seed 000 eq. 25)"),
    "acceleration_limits": ("m/s², rad/s²", "the drive's largest acceleration toward a command while the "
                            "speed grows, vx vy vz vroll vpitch vyaw (0 = no limit)"),
    "deceleration_limits": ("m/s², rad/s²", "the same while the speed shrinks (0 = no limit)"),
    "control_latency": ("s", "the drive responds this long after a command's stamp"),
    "control_velocity_limits": ("m/s, rad/s", "a command beyond these magnitudes is rejected, "
                                "vx vy vz vroll vpitch vyaw (0 = no check)"),
    "wheel_radius": ("m", "mecanum wheel radius r (seed 000 eq. 23); 0 = no wheel geometry"),
    "half_wheelbase": ("m", "L, centre to the front/rear axle (eq. 23)"),
    "half_track": ("m", "l, centre line to a wheel centre (eq. 23)"),
    "wheel_acceleration_limit": ("rad/s²", "the drive response in wheel space: every wheel ramps toward "
                                 "its commanded speed together, at most this fast (0 = per-axis "
                                 "acceleration_limits instead); needs wheel_radius"),
    "wheel_speed_limit": ("rad/s", "commanded wheel speeds are scaled together below this (0 = none)"),
    "wheel_command_topic": ("-", "std_msgs/Float64MultiArray of commanded wheel speeds (rad/s, seed 000 "
                            "eq. 20), a process input besides cmd_vel, stamped on receipt; '' = none"),
    "wheel_order": ("-", "the wheel of each entry of a wheel command: rear_left, rear_right, front_left, "
                    "front_right (eq. 24's m1..m4)"),
    "process_noise_covariance": ("per s", "15x15 process noise Q, RL field order, multiplied by dt"),
    "initial_estimate_covariance": ("SI²", "15x15 initial P, RL field order"),
    "initial_state": ("SI", "15 initial values, RL field order"),
    "max_plausible_speed": ("m/s", "a fused linear velocity (twist, odometry, cmd_vel) beyond this is "
                            "rejected as implausible_value; .inf = no limit"),
    "max_plausible_angular_speed": ("rad/s", "a fused angular velocity (twist, IMU, cmd_vel) beyond this is "
                                    "rejected (a MEMS gyro's range is about 35 rad/s); .inf = no limit"),
    "max_plausible_acceleration": ("m/s²", "a fused linear acceleration beyond this is rejected; "
                                   ".inf = no limit"),
    "max_plausible_position": ("m", "a fused or set_pose position coordinate beyond this is rejected; "
                               ".inf = no limit"),
    "pose_recovery": ("-", "kidnapped-robot recovery: re-initialise the pose from absolute pose fixes "
                      "(world-frame x, y, yaw) that keep failing the gate while agreeing with each other"),
    "pose_recovery_min_fixes": ("-", "at least this many agreeing gated fixes in a row"),
    "pose_recovery_min_duration": ("s", "spanning at least this long"),
    "pose_recovery_agreement": ("m", "within this of their median position correction"),
    "pose_recovery_angle_agreement": ("rad", "and within this of their median heading correction"),
    "static_transforms": ("m, rad", "fixed transforms, each 'x y z yaw pitch roll parent child' "
                          "(static_transform_publisher's arguments), besides /tf_static"),
    "zero_variance_floor": ("SI²", "a zero variance on a fused field is replaced by this (RL: 1e-9)"),
}
# Plausibility limits (PARAMETERS above): above any FTC/FRC drive (about 5 m/s, 15 rad/s) with margin.
DEFAULT_MAX_PLAUSIBLE_SPEED = 10.0
DEFAULT_MAX_PLAUSIBLE_ANGULAR_SPEED = 35.0
DEFAULT_MAX_PLAUSIBLE_ACCELERATION = 100.0
DEFAULT_MAX_PLAUSIBLE_POSITION = 1000.0


class ParameterError(ValueError):
    """A parameter has a bad value; ``name`` is the parameter, the message says what is expected."""

    def __init__(self, name: str, expected: str, got: Any = None, *, has_value: bool = True,
                 what: str = "parameter") -> None:
        self.name = name
        text = repr(got)
        if len(text) > 160:
            text = text[:150] + " ... " + text[-5:]
        detail = f", got {text}" if has_value else ""
        super().__init__(f"{what} '{name}': expected {expected}{detail}")


@dataclass(frozen=True)
class InputConfig:
    """One sensor input (odomN, poseN, twistN, imuN, jointN)."""

    name: str  # "odom0"
    kind: str  # "odom" | "pose" | "twist" | "imu" | "joint"
    topic: str
    config: tuple[bool, ...]  # 15 flags: which fields to fuse (all false for a joint input)
    queue_size: int = 10
    rejection_thresholds: tuple[tuple[str, float], ...] = ()  # (part name, Mahalanobis sigmas)
    encoders: EncoderInputConfig | None = None  # joint inputs
    tilt_compensation: bool = False  # odom/twist: project the twist with an IMU's roll/pitch
    pose_frame: str = ""  # the frame whose pose a pose part gives ("": base_link_frame)
    pose_use_child_frame: bool = False  # odometry: the pose is of its child_frame_id (RL)
    differential: bool = False  # successive poses become a body velocity (RL's _differential)
    relative: bool = False  # poses relative to the first one (RL's _relative)
    variance_scale: float = 1.0  # every message covariance is multiplied by this (ekf_tune fits it)

    @property
    def tilt_source(self) -> bool:
        """An IMU fusing roll and pitch: its orientation supplies the tilt."""
        return self.kind == "imu" and all(self.config[f] for f in TILT_FIELDS)

    def threshold(self, part: str) -> float:
        return dict(self.rejection_thresholds).get(part, math.inf)


@dataclass(frozen=True)
class EkfConfig:
    """Everything ekf_node and the offline replay need, validated. Times in seconds and ns."""

    model: str = "mecanum"
    frequency: float = 30.0
    sensor_timeout: float = 1.0 / 30.0
    map_frame: str = "map"
    odom_frame: str = "odom"
    base_link_frame: str = "base_link"
    world_frame: str = "odom"
    publish_tf: bool = True
    print_diagnostics: bool = True
    predict_to_current_time: bool = True
    smooth_lagged_data: bool = True
    history_length: float = 1.0
    max_measurement_age: float = 2.0
    future_stamp_tolerance: float = 0.5
    max_prediction_step: float = 0.01
    use_control: bool = False
    stamped_control: bool = False
    control_timeout: float = 0.2
    control_velocity_variance: tuple[float, ...] = DEFAULT_CONTROL_VELOCITY_VARIANCE
    control_tilt_compensation: bool = False
    control_time_constant: tuple[float, ...] = (0.0,) * 6
    acceleration_limits: tuple[float, ...] = (0.0,) * 6  # 0 = no limit
    deceleration_limits: tuple[float, ...] = (0.0,) * 6
    control_latency: float = 0.0
    control_velocity_limits: tuple[float, ...] = (0.0,) * 6  # 0 = no check
    wheel_radius: float = 0.0  # 0 = no wheel geometry
    half_wheelbase: float = 0.0
    half_track: float = 0.0
    wheel_acceleration_limit: float = 0.0  # 0 = per-axis limits
    wheel_speed_limit: float = 0.0  # 0 = none
    wheel_command_topic: str = ""  # "" = no wheel-speed command input
    wheel_order: tuple[str, ...] = MECANUM_WHEELS  # the wheel of each array entry
    process_noise_covariance: np.ndarray = field(default_factory=DEFAULT_PROCESS_NOISE.copy)  # (15, 15)
    initial_estimate_covariance: np.ndarray = field(
        default_factory=DEFAULT_INITIAL_COVARIANCE.copy)  # (15, 15)
    initial_state: np.ndarray = field(default_factory=lambda: np.zeros(N_FIELDS))
    inputs: tuple[InputConfig, ...] = ()
    # (parent, child, (x, y, z, yaw, pitch, roll)): static_transform_publisher's meaning
    static_transforms: tuple[tuple[str, str, tuple[float, ...]], ...] = ()
    zero_variance_floor: float = 1e-9  # a zero variance on a fused field is replaced by this
    max_plausible_speed: float = DEFAULT_MAX_PLAUSIBLE_SPEED
    max_plausible_angular_speed: float = DEFAULT_MAX_PLAUSIBLE_ANGULAR_SPEED
    max_plausible_acceleration: float = DEFAULT_MAX_PLAUSIBLE_ACCELERATION
    max_plausible_position: float = DEFAULT_MAX_PLAUSIBLE_POSITION
    pose_recovery: bool = True
    pose_recovery_min_fixes: int = 10
    pose_recovery_min_duration: float = 1.0
    pose_recovery_agreement: float = 0.2
    pose_recovery_angle_agreement: float = 0.3
    warnings: tuple[str, ...] = ()  # start-up warnings for the node to log

    @property
    def recovery(self) -> RecoveryConfig:
        return RecoveryConfig(self.pose_recovery, self.pose_recovery_min_fixes,
                              seconds_to_ns(self.pose_recovery_min_duration), self.pose_recovery_agreement,
                              self.pose_recovery_angle_agreement)

    @property
    def plausible_bounds(self) -> np.ndarray:
        """(15,) largest plausible |value| per RL field (angles: unbounded, they are wrapped)."""
        p, v, w, a = (self.max_plausible_position, self.max_plausible_speed, self.max_plausible_angular_speed,
                      self.max_plausible_acceleration)
        return np.array([p, p, p, math.inf, math.inf, math.inf, v, v, v, w, w, w, a, a, a])

    @property
    def history_length_ns(self) -> int:
        return seconds_to_ns(self.history_length)

    @property
    def max_measurement_age_ns(self) -> int:
        return seconds_to_ns(self.max_measurement_age)

    @property
    def future_stamp_tolerance_ns(self) -> int:
        return seconds_to_ns(self.future_stamp_tolerance)

    @property
    def max_prediction_step_ns(self) -> int:
        return seconds_to_ns(self.max_prediction_step)

    @property
    def control_timeout_ns(self) -> int:
        return seconds_to_ns(self.control_timeout)

    @property
    def control_latency_ns(self) -> int:
        return seconds_to_ns(self.control_latency)

    @property
    def sensor_timeout_ns(self) -> int:
        return seconds_to_ns(self.sensor_timeout)

    @property
    def publish_period_ns(self) -> int:
        return seconds_to_ns(1.0 / self.frequency)


# --- value readers: each names the parameter on failure ---------------------------------------

def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _float(values: Mapping[str, Any], name: str, default: float, *, minimum: float | None = None,
           strict_minimum: bool = False, maximum: float | None = None, allow_inf: bool = False,
           what: str = "a number") -> float:
    if name not in values:
        return default
    v = values[name]
    if not _is_number(v) or math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise ParameterError(name, what, v)
    v = float(v)
    if minimum is not None and (v < minimum or (strict_minimum and v == minimum)):
        raise ParameterError(name, what, v)
    if maximum is not None and v > maximum:
        raise ParameterError(name, what, v)
    return v


def _int(values: Mapping[str, Any], name: str, default: int, minimum: int) -> int:
    if name not in values:
        return default
    v = values[name]
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < minimum:
        raise ParameterError(name, f"an integer >= {minimum}", v)
    return int(v)


def _bool(values: Mapping[str, Any], name: str, default: bool) -> bool:
    if name not in values:
        return default
    v = values[name]
    if not isinstance(v, (bool, np.bool_)):
        raise ParameterError(name, "true or false", v)
    return bool(v)


def _str(values: Mapping[str, Any], name: str, default: str, choices: Sequence[str] | None = None) -> str:
    if name not in values:
        return default
    v = values[name]
    if choices is not None:
        if v not in choices:
            raise ParameterError(name, "one of " + ", ".join(repr(c) for c in choices), v)
        return str(v)
    if not isinstance(v, str) or not v.strip("/ "):
        raise ParameterError(name, "a non-empty name", v)
    return v.strip("/ ") if name.endswith("_frame") else v


def _seq(v: Any) -> list | None:
    if isinstance(v, (str, bytes, Mapping)):
        return None
    try:
        return list(v)
    except TypeError:
        return None


def _vector(values: Mapping[str, Any], name: str, default: Sequence[float], length: int,
            what: str, nonnegative: bool = False) -> np.ndarray:
    if name not in values:
        return np.array(default, dtype=float)
    v = _seq(values[name])
    if v is None or len(v) != length or not all(_is_number(e) and math.isfinite(e) for e in v) \
            or (nonnegative and any(e < 0 for e in v)):
        raise ParameterError(name, what, values[name])
    return np.array(v, dtype=float)


def _bool_vector(values: Mapping[str, Any], name: str, length: int, what: str) -> tuple[bool, ...]:
    v = _seq(values.get(name))
    if name not in values:
        raise ParameterError(name, what + " (required)", has_value=False)
    if v is None or len(v) != length or not all(isinstance(e, (bool, np.bool_)) for e in v):
        raise ParameterError(name, what, values[name])
    return tuple(bool(e) for e in v)


_FIELDS_TEXT = " ".join(FIELD_NAMES)


def _matrix15(values: Mapping[str, Any], name: str, default: np.ndarray, rows: tuple[int, ...],
              positive_definite: bool, diagonal: bool, model: str) -> np.ndarray:
    what = (f"225 numbers (a symmetric 15x15 matrix, row-major) or 15 (its diagonal), field order "
            f"{_FIELDS_TEXT}")
    given = _seq(values.get(name))
    if given is not None and len(given) == N_FIELDS:  # robot_localization's diagonal form
        M = np.diag(_vector(values, name, np.diag(default), N_FIELDS, what))
    else:
        M = _vector(values, name, default.ravel(), N_FIELDS * N_FIELDS, what).reshape(N_FIELDS, N_FIELDS)
    if not is_symmetric(M):
        raise ParameterError(name, what + " (it is not symmetric)", "non-symmetric matrix")
    if np.any(np.diag(M) < 0.0):
        raise ParameterError(name, what + " with non-negative variances on the diagonal",
                             [float(x) for x in np.diag(M)])
    sub = M[np.ix_(rows, rows)]
    names = ", ".join(FIELD_NAMES[r] for r in rows)
    if diagonal and np.any(sub[~np.eye(len(rows), dtype=bool)] != 0.0):
        raise ParameterError(name, f"no off-diagonal entries among the fields model '{model}' "
                             f"estimates ({names}): its process noise is diagonal", "off-diagonal entries")
    if positive_definite and not is_positive_definite(sub):
        raise ParameterError(name, f"a positive definite block for the fields model '{model}' "
                             f"estimates ({names})", [float(x) for x in np.diag(sub)])
    return M


# --- the parser -------------------------------------------------------------------------------

_INPUT_RE = re.compile(r"^(odom|pose|twist|imu|joint)(\d+)(.*)$")


def parse_ekf_config(values: Mapping[str, Any], models: Mapping[str, MotionModelSpec]) -> EkfConfig:
    """Validate a flat {parameter name: value} mapping into an :class:`EkfConfig`.

    ``models`` are the motion models ``model`` may name (``models.registry.MODELS``).
    """
    warnings: list[str] = []
    model = _str(values, "model", "mecanum", choices=tuple(models))
    spec = models[model]
    frequency = _float(values, "frequency", 30.0, minimum=MIN_FREQUENCY_HZ, maximum=MAX_FREQUENCY_HZ,
                       what=f"a rate in Hz from {MIN_FREQUENCY_HZ:g} to {MAX_FREQUENCY_HZ:g}")
    sensor_timeout = _float(values, "sensor_timeout", 1.0 / frequency, minimum=0.0, strict_minimum=True,
                            what="a duration in s > 0")
    map_frame = _str(values, "map_frame", "map")
    odom_frame = _str(values, "odom_frame", "odom")
    base_link_frame = _str(values, "base_link_frame", "base_link")
    world_frame = _str(values, "world_frame", odom_frame)
    if map_frame == odom_frame:
        raise ParameterError("odom_frame", "a frame different from map_frame", odom_frame)
    if base_link_frame in (map_frame, odom_frame):
        raise ParameterError("base_link_frame", "a frame different from map_frame and odom_frame",
                             base_link_frame)
    if world_frame not in (map_frame, odom_frame):
        raise ParameterError("world_frame", f"map_frame ('{map_frame}') or odom_frame ('{odom_frame}')",
                             world_frame)
    smooth = _bool(values, "smooth_lagged_data", True)
    history_length = _float(values, "history_length", 1.0, minimum=0.0, strict_minimum=smooth,
                            what="a duration in s"
                            + (" > 0 (smooth_lagged_data is true)" if smooth else " >= 0"))
    max_age = _float(values, "max_measurement_age", max(2.0, history_length), minimum=0.0,
                     strict_minimum=True, what="a duration in s > 0")
    if smooth and max_age < history_length:
        raise ParameterError("max_measurement_age", f"a duration in s >= history_length ({history_length})",
                             max_age)
    use_control = _bool(values, "use_control", False)
    if use_control and not spec.takes_control:
        raise ParameterError("use_control", f"false for model '{model}': its process input is "
                             f"{spec.process_input}", True)
    state_fields = spec.state_fields
    cfg = dict(
        model=model, frequency=frequency, sensor_timeout=sensor_timeout, map_frame=map_frame,
        odom_frame=odom_frame, base_link_frame=base_link_frame, world_frame=world_frame,
        publish_tf=_bool(values, "publish_tf", True),
        print_diagnostics=_bool(values, "print_diagnostics", True),
        predict_to_current_time=_bool(values, "predict_to_current_time", True),
        smooth_lagged_data=smooth, history_length=history_length, max_measurement_age=max_age,
        future_stamp_tolerance=_float(values, "future_stamp_tolerance", 0.5, minimum=0.0,
                                      what="a duration in s >= 0"),
        max_prediction_step=_float(values, "max_prediction_step", 0.01, minimum=1e-6,
                                   what="a duration in s >= 1e-6"),
        use_control=use_control,
        stamped_control=_bool(values, "stamped_control", False),
        control_timeout=_float(values, "control_timeout", 0.2, minimum=0.0, strict_minimum=True,
                               what="a duration in s > 0"),
        control_velocity_variance=tuple(_vector(
            values, "control_velocity_variance", DEFAULT_CONTROL_VELOCITY_VARIANCE, 6,
            "6 non-negative variances (vx vy vz vroll vpitch vyaw)", nonnegative=True)),
        control_tilt_compensation=_bool(values, "control_tilt_compensation", False),
        control_time_constant=tuple(_vector(
            values, "control_time_constant", np.zeros(6), 6,
            "6 time constants in s >= 0 (vx vy vz vroll vpitch vyaw)", nonnegative=True)),
        acceleration_limits=tuple(_vector(
            values, "acceleration_limits", np.zeros(6), 6,
            "6 accelerations >= 0 in m/s² and rad/s² (0 = no limit)", nonnegative=True)),
        deceleration_limits=tuple(_vector(
            values, "deceleration_limits", np.zeros(6), 6,
            "6 decelerations >= 0 in m/s² and rad/s² (0 = no limit)", nonnegative=True)),
        control_latency=_float(values, "control_latency", 0.0, minimum=0.0, what="a duration in s >= 0"),
        control_velocity_limits=tuple(_vector(
            values, "control_velocity_limits", np.zeros(6), 6,
            "6 speeds >= 0 in m/s and rad/s (0 = no check)", nonnegative=True)),
        **_wheel_geometry(values),
        process_noise_covariance=_matrix15(values, "process_noise_covariance", DEFAULT_PROCESS_NOISE,
                                           state_fields, positive_definite=False, diagonal=True, model=model),
        initial_estimate_covariance=_matrix15(values, "initial_estimate_covariance",
                                              DEFAULT_INITIAL_COVARIANCE, state_fields,
                                              positive_definite=True, diagonal=False, model=model),
        initial_state=_vector(values, "initial_state", np.zeros(N_FIELDS), N_FIELDS,
                              f"15 finite numbers in field order {_FIELDS_TEXT}"),
        **{name: _float(values, name, default, minimum=0.0, strict_minimum=True, allow_inf=True,
                        what=f"a limit in {PARAMETERS[name][0]} > 0 (.inf = none)")
           for name, default in (("max_plausible_speed", DEFAULT_MAX_PLAUSIBLE_SPEED),
                                 ("max_plausible_angular_speed", DEFAULT_MAX_PLAUSIBLE_ANGULAR_SPEED),
                                 ("max_plausible_acceleration", DEFAULT_MAX_PLAUSIBLE_ACCELERATION),
                                 ("max_plausible_position", DEFAULT_MAX_PLAUSIBLE_POSITION))},
        pose_recovery=_bool(values, "pose_recovery", True),
        pose_recovery_min_fixes=_int(values, "pose_recovery_min_fixes", 10, minimum=1),
        pose_recovery_min_duration=_float(values, "pose_recovery_min_duration", 1.0, minimum=0.0,
                                          what="a duration in s >= 0"),
        pose_recovery_agreement=_float(values, "pose_recovery_agreement", 0.2, minimum=0.0,
                                       strict_minimum=True, what="a distance in m > 0"),
        pose_recovery_angle_agreement=_float(values, "pose_recovery_angle_agreement", 0.3, minimum=0.0,
                                             strict_minimum=True, what="an angle in rad > 0"),
        static_transforms=_static_transforms(values),
        zero_variance_floor=_float(values, "zero_variance_floor", 1e-9, minimum=0.0, strict_minimum=True,
                                   what="a variance > 0"),
    )
    inputs = _parse_inputs(values, spec, warnings)
    _check_names(values, inputs, warnings)
    if not inputs:
        warnings.append("no inputs configured (odom0, pose0, twist0, imu0, ...): the filter will "
                        "only publish after set_pose")
    return EkfConfig(**cfg, inputs=tuple(inputs), warnings=tuple(warnings))


def _wheel_command(values: Mapping[str, Any], wheel_radius: float) -> dict[str, Any]:
    topic = values.get("wheel_command_topic", "")
    if not isinstance(topic, str):
        raise ParameterError("wheel_command_topic", "a topic name, or '' for none", topic)
    order = _seq(values.get("wheel_order", list(MECANUM_WHEELS)))
    if order is None or sorted(map(str, order)) != sorted(MECANUM_WHEELS):
        raise ParameterError("wheel_order", "the four wheels " + ", ".join(MECANUM_WHEELS) + " in any order",
                             values.get("wheel_order"))
    if topic.strip() and wheel_radius <= 0.0:
        raise ParameterError("wheel_command_topic", "'' unless wheel_radius, half_wheelbase and half_track "
                             "are set (wheel speeds need the geometry)", topic)
    return {"wheel_command_topic": topic.strip(), "wheel_order": tuple(str(w) for w in order)}


def _wheel_geometry(values: Mapping[str, Any]) -> dict[str, Any]:
    """wheel_radius, half_wheelbase, half_track (all > 0 or radius 0) and the wheel limits."""
    g = {name: _float(values, name, 0.0, minimum=0.0, what="a length in m >= 0")
         for name in ("wheel_radius", "half_wheelbase", "half_track")}
    if g["wheel_radius"] > 0.0:
        for name in ("half_wheelbase", "half_track"):
            if g[name] <= 0.0:
                raise ParameterError(name, "a length in m > 0 (wheel_radius is set)", g[name])
    for name, unit in (("wheel_acceleration_limit", "rad/s²"), ("wheel_speed_limit", "rad/s")):
        g[name] = _float(values, name, 0.0, minimum=0.0, what=f"a limit in {unit} >= 0 (0 = none)")
        if g[name] > 0.0 and g["wheel_radius"] == 0.0:
            raise ParameterError(name, "0.0 unless wheel_radius, half_wheelbase and half_track are set",
                                 g[name])
    g.update(_wheel_command(values, g["wheel_radius"]))
    return g


def _parse_inputs(values: Mapping[str, Any], spec: MotionModelSpec, warnings: list[str]) -> list[InputConfig]:
    found: dict[str, set[int]] = {k: set() for k in INPUT_KINDS}
    for key in values:
        m = _INPUT_RE.match(key)
        if m and m.group(3) == "":
            found[m.group(1)].add(int(m.group(2)))
    state_fields = set(spec.state_fields) | set(spec.input_fields)
    inputs = []
    for kind in INPUT_KINDS:
        numbers = sorted(found[kind])
        for expected, n in enumerate(numbers):
            if n != expected:
                raise ParameterError(f"{kind}{n}", f"inputs numbered from 0 without gaps ({kind}{expected} "
                                     "is missing)", values[f"{kind}{n}"])
        for n in numbers:
            inputs.append(_parse_input(values, kind, f"{kind}{n}", state_fields, spec, warnings))
    return inputs


def _parse_input(values: Mapping[str, Any], kind: str, name: str, state_fields: set[int],
                 spec: MotionModelSpec, warnings: list[str]) -> InputConfig:
    model = spec.name
    topic = values[name]
    if not isinstance(topic, str) or not topic.strip():
        raise ParameterError(name, "a topic name", topic)
    if kind == "joint":
        config = (False,) * N_FIELDS
    else:
        config = _bool_vector(values, f"{name}_config", N_FIELDS, f"a list of 15 booleans ({_FIELDS_TEXT})")
    queue = values.get(f"{name}_queue_size", 10)
    if isinstance(queue, bool) or not isinstance(queue, (int, np.integer)) or queue < 1:
        raise ParameterError(f"{name}_queue_size", "an integer >= 1", queue)
    thresholds = []
    seen_parts: dict[str, str] = {}
    for suffix, part in THRESHOLD_SUFFIXES[kind].items():
        pname = name + suffix
        if pname not in values:
            continue
        if part in seen_parts:
            raise ParameterError(pname, f"only one of {seen_parts[part]} and {pname}", values[pname])
        seen_parts[part] = pname
        thresholds.append((part, _float(values, pname, math.inf, minimum=0.0, strict_minimum=True,
                                        allow_inf=True, what="a Mahalanobis distance in sigmas > 0")))
    differential = _bool(values, name + "_differential", False)
    relative = _bool(values, name + "_relative", False)
    if kind not in ("odom", "pose", "imu") and (differential or relative):
        warnings.append(f"{name}: _differential and _relative apply to pose data only; ignored")
        differential = relative = False
    if differential and relative:
        warnings.append(f"{name}_relative: ignored, {name}_differential is true (as in robot_localization)")
        relative = False
    if kind == "joint":
        encoders = _parse_encoders(values, name, spec, warnings)
        return InputConfig(name=name, kind=kind, topic=topic, config=config, queue_size=int(queue),
                           rejection_thresholds=tuple(thresholds), encoders=encoders)
    tilt = _bool(values, f"{name}_tilt_compensation", False) if kind in ("odom", "twist") else False
    fused = {i for i, f in enumerate(config) if f}
    if kind == "imu" and all(config[f] for f in TILT_FIELDS):
        state_fields = state_fields | set(TILT_FIELDS)  # the tilt source: used, not estimated
    not_in_msg = sorted(fused - KIND_FIELDS[kind])
    if not_in_msg:
        warnings.append(f"{name}_config: a {kind} message has no "
                        + ", ".join(FIELD_NAMES[i] for i in not_in_msg) + "; ignored")
    not_in_model = sorted((fused & KIND_FIELDS[kind]) - state_fields)
    if not_in_model:
        warnings.append(f"{name}_config: model '{model}' does not estimate "
                        + ", ".join(FIELD_NAMES[i] for i in not_in_model) + "; ignored")
    if not ((fused & KIND_FIELDS[kind]) & state_fields):
        warnings.append(f"{name} ({topic}) fuses no field the '{model}' model estimates")
    variance_scale = _float(values, f"{name}_variance_scale", 1.0, minimum=0.0,
                            strict_minimum=True, what="a finite factor > 0 on the message covariances")
    pose_frame = _str(values, f"{name}_pose_frame", "") if kind in ("odom", "pose") else ""
    child = _bool(values, f"{name}_pose_use_child_frame", False) if kind == "odom" else False
    return InputConfig(name=name, kind=kind, topic=topic, config=config, queue_size=int(queue),
                       rejection_thresholds=tuple(thresholds), tilt_compensation=tilt,
                       variance_scale=variance_scale, pose_frame=pose_frame.strip("/ "),
                       pose_use_child_frame=child, differential=differential, relative=relative)


_STATIC_FORM = "a list of strings 'x y z yaw pitch roll parent child' (m, rad; static_transform_publisher)"


def _static_transforms(values: Mapping[str, Any]) -> tuple[tuple[str, str, tuple[float, ...]], ...]:
    """The ``static_transforms`` parameter: x y z yaw pitch roll parent child per entry."""
    items = _seq(values.get("static_transforms", []))
    if items is None or not all(isinstance(s, str) for s in items):
        raise ParameterError("static_transforms", _STATIC_FORM, values.get("static_transforms"))
    out = []
    for text in items:
        words = text.split()
        try:
            numbers = tuple(float(w) for w in words[:6])
        except ValueError:
            numbers = ()
        if len(words) != 8 or len(numbers) != 6 or not all(math.isfinite(v) for v in numbers) \
                or words[6].strip("/") == words[7].strip("/"):
            raise ParameterError("static_transforms", _STATIC_FORM + " with two different frames", text)
        out.append((words[6].strip("/"), words[7].strip("/"), numbers))
    return tuple(out)


def _parse_encoders(values: Mapping[str, Any], name: str, spec: MotionModelSpec,
                    warnings: list[str]) -> EncoderInputConfig:
    """A jointN input's dead-wheel settings (JOINT_SUFFIXES)."""
    key = name + "_names"
    model = spec.name
    want = spec.dead_wheel_count
    if want == 0:
        raise ParameterError(name, f"no jointN input: model '{model}' has no dead-wheel encoder measurement",
                             values[name])
    names = _seq(values.get(key))
    what = (f"a list of {want} joint names [left, right{', lateral' if want == 3 else ''}]"
            + (" (a lateral third name is ignored)" if want == 2 else ""))
    if key not in values:
        raise ParameterError(key, what + " (required)", has_value=False)
    if names is None or len(names) not in (want, 3) or not all(isinstance(n, str) and n for n in names):
        raise ParameterError(key, what, values[key])
    if len(names) > want:
        warnings.append(f"{key}: model '{model}' has no lateral velocity; '{names[2]}' is not used")
        names = names[:want]
    defaults = EncoderInputConfig(names=tuple(names))
    kwargs: dict[str, Any] = {"names": tuple(names)}
    for suffix, (attr, unit, _) in JOINT_SUFFIXES.items():
        if attr == "names":
            continue
        default = getattr(defaults, attr)
        if isinstance(default, bool):
            kwargs[attr] = _bool(values, name + suffix, default)
        else:
            kwargs[attr] = _float(values, name + suffix, default, what=f"a finite number ({unit})")
    cfg = EncoderInputConfig(**kwargs)
    problem = validate_encoder_config(cfg)
    if problem is not None:
        field_name, expected = problem.split(": ", 1)
        suffix = next(s for s, (a, _, _) in JOINT_SUFFIXES.items() if a == field_name)
        raise ParameterError(name + suffix, expected, values.get(name + suffix, getattr(cfg, field_name)))
    return cfg


def _input_suffixes(kind: str) -> set[str]:
    if kind == "joint":
        return {"", "_queue_size"} | set(THRESHOLD_SUFFIXES[kind]) | set(JOINT_SUFFIXES)
    tilt = {"_tilt_compensation"} if kind in ("odom", "twist") else set()
    frames = {"_pose_frame"} if kind in ("odom", "pose") else set()
    frames |= {"_pose_use_child_frame"} if kind == "odom" else set()
    return ({"", "_config", "_queue_size", "_variance_scale"} | set(THRESHOLD_SUFFIXES[kind])
            | set(RL_INPUT_IGNORED) | set(RL_INPUT_MODES) | tilt | frames)


def _check_names(values: Mapping[str, Any], inputs: list[InputConfig], warnings: list[str]) -> None:
    names = {i.name: i.kind for i in inputs}
    for key in values:
        if key in PARAMETERS or key in ROS_BUILTIN or key.startswith("qos_overrides."):
            continue
        if key in RL_IGNORED:
            warnings.append(f"parameter '{key}' (robot_localization) is not supported by ekf_node; ignored")
            continue
        m = _INPUT_RE.match(key)
        if m:
            name = m.group(1) + m.group(2)
            suffix = m.group(3)
            if name in names and suffix in _input_suffixes(names[name]):
                if suffix in RL_INPUT_IGNORED:
                    warnings.append(f"parameter '{key}' (robot_localization) is not supported; ignored")
                continue
            if name not in names:
                raise ParameterError(key, f"a setting of a configured input, but '{name}' has no topic",
                                     values[key])
        raise ParameterError(key, "a known ekf_node parameter (see docs/ekf_node.md)", values[key])


# --- YAML files, as rcl reads them ------------------------------------------------------------

def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


class _RclLikeLoader(yaml.SafeLoader):
    """SafeLoader that, like rcl's parser, reads ``1e-9`` as a float (YAML 1.1 needs ``1.0e-9``)."""


_RclLikeLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                  |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                  |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                  |[-+]?\.(?:inf|Inf|INF)
                  |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))


def parse_parameter_value(text: str) -> Any:
    """One parameter value written as YAML, read the way rcl reads a params file."""
    return yaml.load(text, Loader=_RclLikeLoader)  # a SafeLoader subclass


def read_parameter_yaml(yaml_path: str | Path) -> Any:
    """The YAML document of a ROS params file, scalars typed as rcl types them.

    Raises OSError (unreadable) or yaml.YAMLError (syntax).
    """
    return yaml.load(Path(yaml_path).read_text(), Loader=_RclLikeLoader)  # a SafeLoader subclass


def parameters_from_yaml(yaml_path: str | Path, node_name: str = "ekf_node") -> dict[str, Any]:
    """The flat parameter dict a ROS params file gives node ``node_name`` (``/**`` wildcard too)."""
    path = Path(yaml_path)
    try:
        doc = read_parameter_yaml(path)
    except (OSError, yaml.YAMLError) as exc:
        raise ParameterError(str(path), "a readable YAML parameter file", str(exc), what="file") from None
    if not isinstance(doc, Mapping):
        raise ParameterError(str(path), "a YAML mapping of node names to ros__parameters", type(doc).__name__,
                             what="file")
    name = node_name.strip("/").split("/")[-1]
    values: dict[str, Any] = {}
    matched = False
    for key, body in doc.items():
        k = str(key)
        if k in ("/**", name, "/" + name) or k.endswith("/" + name) or k == "/**/" + name:
            if not isinstance(body, Mapping) or not isinstance(body.get("ros__parameters"), Mapping):
                raise ParameterError(f"{k}.ros__parameters", "a mapping of parameters", body)
            values.update(_flatten(body["ros__parameters"]))
            matched = True
    if not matched:
        raise ParameterError(str(path), f"a section for node '{name}' or '/**'", sorted(map(str, doc)),
                             what="file")
    return values


def load_ekf_config(yaml_path: str | Path, models: Mapping[str, MotionModelSpec],
                    node_name: str = "ekf_node") -> EkfConfig:
    """Read and validate ekf_node's parameters straight from a ROS 2 params file (no ROS needed)."""
    return parse_ekf_config(parameters_from_yaml(yaml_path, node_name), models)


def defaults_to_declare(config: EkfConfig) -> dict[str, Any]:
    """Effective values of the global parameters, for the node to declare the unset ones."""
    out: dict[str, Any] = {}
    for name in PARAMETERS:
        if name == "static_transforms":  # a string list: declared only when given
            continue
        v = getattr(config, name)
        if isinstance(v, np.ndarray):
            v = [float(x) for x in v.ravel()]
        elif isinstance(v, tuple):
            v = [x if isinstance(x, str) else float(x) for x in v]
        out[name] = v
    return out
