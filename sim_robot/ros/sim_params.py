"""sim_node parameters: the schema (names, SI units, defaults) and its validation (no ROS).

``parse_parameters(values)`` turns a ``{name: value}`` dict (ROS parameter values, dotted
names as in config/sim.yaml) into a ``WorldConfig`` and ``NodeSettings``. A value of the
wrong type or out of range raises ``SimParameterError`` listing every bad parameter with
the expected form; floats must be written with a decimal point (``50.0``, not ``50``).
Parameter names and units are documented in docs/simulator.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from ekf_localization.core.units import METRES_PER_INCH, NS_PER_S, seconds_to_ns
from ekf_localization.models.mecanum import MecanumKinematics
from ekf_localization.models.sensors.camera import CameraNoise
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, EncoderNoise
from sim_robot.world.camera_sensor import CameraConfig
from sim_robot.world.dead_wheel_sensor import SAMPLING_MODES, DeadWheelConfig
from sim_robot.world.drives import DRIVES, DriveLimits, TankKinematics
from sim_robot.world.field import FIELD_SIZE_IN, PRESETS, Field, FieldImage
from sim_robot.world.imu_sensor import ImuConfig
from sim_robot.world.ramp import Ramp
from sim_robot.world.world import WorldConfig

_IN = METRES_PER_INCH
_SEED = WorldConfig()  # seed 000's robot in SI: the source of the defaults below
# Truth velocity jitter per 1 ms tick. Seed 000 adds 0.45 (in/s)² and 0.45 (rad/s)² of white
# noise to the velocity at every tick: in SI a 0.67 rad/s yaw-rate jitter at 1 kHz, 670 rad/s²
# accelerations no drive makes, which no filter can track (a yaw-rate NIS of ~700). The
# simulator's SI default is a small jitter, 1 mm/s and 3 mrad/s per tick (docs/simulator.md).
VELOCITY_VARIANCE_PER_TICK = (1.0e-6, 1.0e-6, 1.0e-5)
# Pose slip: seed 000's x, y (0.002 in²/s in SI); its heading term, 0.002 rad²/s (2.6°/√s of
# heading random walk the gyro does not see), is replaced by 1e-5 rad²/s (0.18°/√s).
POSE_VARIANCE_RATE = (_SEED.pose_variance_rate[0], _SEED.pose_variance_rate[1], 1.0e-5)


class SimParameterError(ValueError):
    """One or more sim_node parameters are invalid; the message names each of them."""


Check = Callable[[Any], str | None]  # returns the expected form when the value is bad


def _positive(v: float) -> str | None:
    return None if math.isfinite(v) and v > 0.0 else "a finite value > 0"


def _non_negative(v: float) -> str | None:
    return None if math.isfinite(v) and v >= 0.0 else "a finite value >= 0"


def _finite(v: float) -> str | None:
    return None if math.isfinite(v) else "a finite value"


def _probability(v: float) -> str | None:
    return None if 0.0 <= v <= 1.0 else "a probability in [0.0, 1.0]"


def _choice(options: Sequence[str]) -> Check:
    return lambda v: None if v in options else "one of " + ", ".join(repr(o) for o in options)


def _triple_finite(v: list[float]) -> str | None:
    return None if len(v) == 3 and all(math.isfinite(x) for x in v) else "3 finite floats [x, y, yaw]"


def _triple_non_negative(v: list[float]) -> str | None:
    ok = len(v) == 3 and all(math.isfinite(x) and x >= 0.0 for x in v)
    return None if ok else "3 finite floats >= 0"


def _images(v: list[float]) -> str | None:
    ok = len(v) % 3 == 0 and all(math.isfinite(x) for x in v)
    return None if ok else ("a flat list [x1, y1, facing_yaw1, x2, ...] of finite floats "
                            "(length a multiple of 3)")


def _fov_deg(v: float) -> str | None:
    return None if 0.0 < v < 180.0 else "an angle in (0.0, 180.0) degrees"


def _dropout(v: list[float]) -> str | None:
    ok = not v or (len(v) == 2 and all(math.isfinite(x) and x >= 0.0 for x in v))
    return None if ok else "[] or [start s >= 0, duration s >= 0]"


def _none(_: Any) -> str | None:
    return None


@dataclass(frozen=True)
class ParamSpec:
    name: str
    kind: str  # "float", "int", "bool", "str", "float_list"
    default: Any
    check: Check
    description: str


_dw, _cam, _imu, _ramp = _SEED.dead_wheels, _SEED.camera, _SEED.imu, _SEED.ramp

PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("seed", "int", 0, lambda v: None if v >= 0 else "an int >= 0", "random seed"),
    ParamSpec("drive", "str", "mecanum", _choice(DRIVES), "drive type"),
    ParamSpec("real_time_factor", "float", 1.0, _non_negative,
              "sim seconds per wall second; 0.0 = as fast as possible"),
    ParamSpec("publish_clock", "bool", False, _none, "publish /clock (other nodes use_sim_time)"),
    ParamSpec("publish_odom_tf", "bool", True, _none,
              "broadcast odom->base_link on /tf from the dead-wheel odometry (as a drive controller does)"),
    ParamSpec("stamped_cmd_vel", "bool", False, _none,
              "cmd_vel is geometry_msgs/TwistStamped (true) or Twist (false)"),
    ParamSpec("wait_for_topics", "str_list", [],
              lambda v: None if all(v) else "a list of non-empty topic names",
              "hold sim time at 0 until each of these topics has a publisher (e.g. the EKF's "
              "odometry/filtered and cmd_vel); [] = start at once"),
    ParamSpec("wait_timeout", "float", 30.0, _non_negative,
              "s (wall): start anyway after waiting this long for wait_for_topics"),
    ParamSpec("physics_frequency", "float", 1000.0, _positive, "truth integration rate, Hz"),
    ParamSpec("cmd_vel_timeout", "float", 0.5, _non_negative,
              "s of sim time without cmd_vel before the command is zeroed; 0.0 = never"),
    ParamSpec("initial_pose", "float_list", [0.0, 0.0, 0.0], _triple_finite, "[x m, y m, yaw rad] in map"),
    ParamSpec("map_frame", "str", "map", lambda v: None if v else "a non-empty frame id", "field frame"),
    ParamSpec("odom_frame", "str", "odom", lambda v: None if v else "a non-empty frame id", "odometry frame"),
    ParamSpec("base_link_frame", "str", "base_link", lambda v: None if v else "a non-empty frame id",
              "robot body frame"),
    ParamSpec("field.preset", "str", "seed000", _choice((*PRESETS, "custom")), "wall image layout"),
    ParamSpec("field.image_width", "float", 10.0 * _IN, _positive, "image width, m"),
    ParamSpec("field.custom_images", "float_list", [], _images,
              "for preset 'custom': [x m, y m, facing_yaw rad] per image"),
    ParamSpec("mecanum.wheel_radius", "float", _SEED.mecanum.wheel_radius, _positive, "r, m"),
    ParamSpec("mecanum.half_wheelbase", "float", _SEED.mecanum.half_length, _positive, "L, m (eq. 23)"),
    ParamSpec("mecanum.half_track", "float", _SEED.mecanum.half_width, _positive, "l, m (eq. 23)"),
    ParamSpec("tank.wheel_radius", "float", _SEED.tank.wheel_radius, _positive, "r, m"),
    ParamSpec("tank.half_track", "float", _SEED.tank.half_track, _positive, "b, m"),
    ParamSpec("limits.wheel_speed_limit", "float", 0.0, _non_negative, "rad/s; 0.0 = no limit"),
    ParamSpec("limits.wheel_acceleration_limit", "float", 0.0, _non_negative, "rad/s^2; 0.0 = no limit"),
    ParamSpec("process_noise.pose_variance_rate", "float_list", list(POSE_VARIANCE_RATE),
              _triple_non_negative, "[m^2/s, m^2/s, rad^2/s] (eq. 26, times the tick)"),
    ParamSpec("process_noise.velocity_variance_per_step", "float_list",
              list(VELOCITY_VARIANCE_PER_TICK), _triple_non_negative,
              "[(m/s)^2, (m/s)^2, (rad/s)^2] per physics tick (eq. 26's form; see docs/simulator.md)"),
    ParamSpec("dead_wheels.enabled", "bool", True, _none, "publish odometry/dead_wheels"),
    ParamSpec("dead_wheels.dropout", "float_list", [], _dropout,
              "[start s, duration s] of sim time during which odometry/dead_wheels is silent; [] = none"),
    ParamSpec("dead_wheels.frequency", "float", 100.0, _positive, "Hz"),
    ParamSpec("dead_wheels.half_spacing", "float", _dw.geometry.half_track, _positive, "W, m (eq. 29)"),
    ParamSpec("dead_wheels.lateral_offset", "float", _dw.geometry.lateral_offset, _finite,
              "D, m, > 0 = lateral wheel behind the centre (eq. 30)"),
    ParamSpec("dead_wheels.speed_variance_coeff", "float", _dw.noise.speed_variance_coeff, _non_negative,
              "a in a*E^2 + b (eq. 32), dimensionless"),
    ParamSpec("dead_wheels.variance_floor", "float", _dw.noise.variance_floor, _positive,
              "b in a*E^2 + b, (m/s)^2"),
    ParamSpec("dead_wheels.sampling", "str", "instantaneous", _choice(SAMPLING_MODES), "speed sampling"),
    ParamSpec("dead_wheels.publish_pose", "bool", True, _none, "integrate and publish the pose"),
    ParamSpec("dead_wheels.publish_joint_states", "bool", False, _none,
              "also publish joint_states (sensor_msgs/JointState: encoder positions in rad, like "
              "ros2_control's joint_state_broadcaster)"),
    ParamSpec("dead_wheels.joint_names", "str_list", ["left_pod", "right_pod", "lateral_pod"],
              lambda v: None if len(v) == 3 and len(set(v)) == 3 and all(v) else
              "3 distinct non-empty joint names [left, right, lateral]",
              "joint names of the left, right and lateral dead wheels in joint_states"),
    ParamSpec("dead_wheels.wheel_radius", "float", _dw.wheel_radius, _positive,
              "m: joint position (rad) = distance along the surface / wheel_radius"),
    ParamSpec("camera.enabled", "bool", True, _none, "publish camera/pose"),
    ParamSpec("camera.frequency", "float", 100.0, _positive, "capture rate, Hz"),
    ParamSpec("camera.latency", "float", 0.0, _non_negative, "s from capture to publication"),
    ParamSpec("camera.field_of_view_deg", "float", 70.0, _fov_deg, "horizontal field of view, degrees"),
    ParamSpec("camera.max_range", "float", 10.0, _positive, "m, camera to image centre"),
    ParamSpec("camera.mount_pose", "float_list", [0.0, 0.0, 0.0], _triple_finite,
              "[x m, y m, yaw rad] of the camera in base_link"),
    ParamSpec("camera.position_distance_variance_coeff", "float", _cam.position_noise.distance_variance_coeff,
              _non_negative, "a in a*d^2 + b for x and y (eq. 32), dimensionless"),
    ParamSpec("camera.position_variance_floor", "float", _cam.position_noise.variance_floor, _positive,
              "b for x and y, m^2"),
    ParamSpec("camera.yaw_distance_variance_coeff", "float", _cam.yaw_noise.distance_variance_coeff,
              _non_negative, "a for yaw, rad^2/m^2"),
    ParamSpec("camera.yaw_variance_floor", "float", _cam.yaw_noise.variance_floor, _positive,
              "b for yaw, rad^2"),
    ParamSpec("camera.outlier_probability", "float", 0.0, _probability, "per visible capture"),
    ParamSpec("camera.outlier_position_std", "float", _cam.outlier_position_std, _non_negative, "m"),
    ParamSpec("camera.outlier_yaw_std", "float", _cam.outlier_yaw_std, _non_negative, "rad"),
    ParamSpec("imu.enabled", "bool", True, _none, "publish imu/data"),
    ParamSpec("imu.frequency", "float", 100.0, _positive, "Hz"),
    ParamSpec("imu.yaw_variance", "float", _imu.yaw_variance, _positive, "rad^2"),
    ParamSpec("imu.yaw_rate_variance", "float", _imu.yaw_rate_variance, _positive, "(rad/s)^2"),
    ParamSpec("imu.accel_variance", "float", _imu.accel_variance, _positive, "(m/s^2)^2"),
    ParamSpec("imu.tilt_variance", "float", _imu.tilt_variance, _positive, "roll and pitch, rad^2"),
    ParamSpec("ramp.enabled", "bool", False, _none, "a ramp on the field (sim_robot/world/ramp.py)"),
    ParamSpec("ramp.x_min", "float", _ramp.x_min, _finite, "m, region start (the slope rises along +x)"),
    ParamSpec("ramp.x_max", "float", _ramp.x_max, _finite, "m, region end"),
    ParamSpec("ramp.y_min", "float", _ramp.y_min, _finite, "m"),
    ParamSpec("ramp.y_max", "float", _ramp.y_max, _finite, "m"),
    ParamSpec("ramp.slope_deg", "float", math.degrees(_ramp.slope),
              lambda v: None if 0.0 < v < 45.0 else "an angle in (0.0, 45.0) degrees", "slope, degrees"),
    ParamSpec("ramp.flat_top_length", "float", _ramp.flat_top_length, _non_negative,
              "m, level top between the up and down slopes"),
    ParamSpec("ground_truth.frequency", "float", 100.0, _positive, "Hz"),
)
SPECS = {p.name: p for p in PARAMS}

_FORMS = {
    "float": "a float written with a decimal point, e.g. 50.0",
    "int": "an integer, e.g. 3",
    "bool": "true or false",
    "str": "a string",
    "float_list": "a list of floats, e.g. [0.0, 1.5]",
    "str_list": "a list of strings, e.g. [odometry/filtered, cmd_vel]",
}


@dataclass(frozen=True)
class NodeSettings:
    """What sim_node needs besides the world."""

    seed: int
    real_time_factor: float
    publish_clock: bool
    cmd_vel_timeout_ns: int
    wait_for_topics: tuple[str, ...]
    stamped_cmd_vel: bool
    wait_timeout_s: float
    initial_pose: tuple[float, float, float]
    map_frame: str
    odom_frame: str
    base_link_frame: str
    publish_joint_states: bool = False
    joint_names: tuple[str, str, str] = ("left_pod", "right_pod", "lateral_pod")
    publish_odom_tf: bool = True
    odom_dropout_ns: tuple[int, int] | None = None  # [start, end) of sim time without dead wheels


def _type_ok(kind: str, v: Any) -> bool:
    if kind == "float":
        return isinstance(v, float)
    if kind == "int":
        return isinstance(v, int) and not isinstance(v, bool)
    if kind == "bool":
        return isinstance(v, bool)
    if kind == "str":
        return isinstance(v, str)
    if kind == "str_list":
        return isinstance(v, Sequence) and not isinstance(v, str) and all(isinstance(x, str) for x in v)
    if kind == "float_list":
        return (isinstance(v, Sequence) or hasattr(v, "typecode")) and not isinstance(v, str) and all(
            isinstance(x, float) for x in v)
    raise AssertionError(kind)


def _period_ns(name: str, frequency: float, physics_ns: int, errors: list[str]) -> int:
    period = round(NS_PER_S / frequency)
    if abs(period * frequency - NS_PER_S) > 1e-6 * NS_PER_S or period % physics_ns:
        physics_hz = NS_PER_S / physics_ns
        examples = ", ".join(f"{physics_hz / m:.1f}" for m in (1, 2, 4, 5, 10, 20, 25, 40, 50, 100)[:8])
        errors.append(f"parameter '{name}': expected a rate in Hz whose period is a whole number of "
                      f"physics ticks ({physics_ns} ns), e.g. {examples}; got {frequency!r}")
        return physics_ns
    return period


def parse_parameters(values: dict[str, Any]) -> tuple[WorldConfig, NodeSettings]:
    """Validate ``values`` (missing names take their defaults) and build the configs."""
    errors: list[str] = []
    unknown = sorted(set(values) - set(SPECS))
    errors += [f"unknown parameter '{n}' (not one of sim_node's parameters; see docs/simulator.md)"
               for n in unknown]
    v: dict[str, Any] = {}
    for spec in PARAMS:
        value = values.get(spec.name, spec.default)
        if not _type_ok(spec.kind, value):
            errors.append(f"parameter '{spec.name}': expected {_FORMS[spec.kind]}, got {value!r}")
            continue
        if spec.kind == "float_list":
            value = [float(x) for x in value]
        problem = spec.check(value)
        if problem:
            errors.append(f"parameter '{spec.name}': expected {problem}, got {value!r}")
            continue
        v[spec.name] = value
    if errors:
        raise SimParameterError("invalid sim_node parameters:\n  " + "\n  ".join(errors))

    physics_ns = round(NS_PER_S / v["physics_frequency"])
    if abs(physics_ns * v["physics_frequency"] - NS_PER_S) > 1e-6 * NS_PER_S:
        errors.append(f"parameter 'physics_frequency': expected a rate with a whole number of ns per tick, "
                      f"e.g. 1000.0; got {v['physics_frequency']!r}")
    periods = {name: _period_ns(name, v[name], physics_ns, errors)
               for name in ("dead_wheels.frequency", "camera.frequency", "imu.frequency",
                            "ground_truth.frequency")}
    if v["real_time_factor"] != 1.0 and not v["publish_clock"]:
        errors.append("parameter 'real_time_factor': expected 1.0 unless publish_clock is true "
                      f"(other nodes can follow a faster or slower sim only on sim time); "
                      f"got {v['real_time_factor']!r}")
    images: tuple[FieldImage, ...] = ()
    if v["field.preset"] == "custom":
        c = v["field.custom_images"]
        images = tuple(FieldImage(c[i], c[i + 1], c[i + 2], v["field.image_width"], f"image {i // 3}")
                       for i in range(0, len(c), 3))
        field = Field(FIELD_SIZE_IN * _IN, images)
    else:
        field = Field.preset(v["field.preset"], _IN, v["field.image_width"])
    try:
        ramp = Ramp(v["ramp.enabled"], v["ramp.x_min"], v["ramp.x_max"], v["ramp.y_min"], v["ramp.y_max"],
                    math.radians(v["ramp.slope_deg"]), v["ramp.flat_top_length"])
    except ValueError as exc:
        errors.append(f"parameters 'ramp.*': expected a region with x_min < x_max, y_min < y_max and a "
                      f"flat_top_length shorter than it ({exc})")
    if errors:
        raise SimParameterError("invalid sim_node parameters:\n  " + "\n  ".join(errors))

    def limit(name: str) -> float:
        return math.inf if v[name] == 0.0 else v[name]

    world = WorldConfig(
        drive=v["drive"],
        mecanum=MecanumKinematics(v["mecanum.wheel_radius"], v["mecanum.half_wheelbase"],
                                  v["mecanum.half_track"]),
        tank=TankKinematics(v["tank.wheel_radius"], v["tank.half_track"]),
        limits=DriveLimits(limit("limits.wheel_speed_limit"), limit("limits.wheel_acceleration_limit")),
        physics_period_ns=physics_ns,
        pose_variance_rate=tuple(v["process_noise.pose_variance_rate"]),
        velocity_variance_per_step=tuple(v["process_noise.velocity_variance_per_step"]),
        field=field,
        dead_wheels=DeadWheelConfig(
            geometry=DeadWheelGeometry(v["dead_wheels.half_spacing"], v["dead_wheels.lateral_offset"]),
            noise=EncoderNoise(v["dead_wheels.speed_variance_coeff"], v["dead_wheels.variance_floor"]),
            period_ns=periods["dead_wheels.frequency"],
            sampling=v["dead_wheels.sampling"],
            integrate_pose=v["dead_wheels.publish_pose"],
            enabled=v["dead_wheels.enabled"],
            wheel_radius=v["dead_wheels.wheel_radius"]),
        camera=CameraConfig(
            period_ns=periods["camera.frequency"],
            latency_ns=seconds_to_ns(v["camera.latency"]),
            field_of_view=math.radians(v["camera.field_of_view_deg"]),
            max_range=v["camera.max_range"],
            mount_pose=tuple(v["camera.mount_pose"]),
            position_noise=CameraNoise(v["camera.position_distance_variance_coeff"],
                                       v["camera.position_variance_floor"]),
            yaw_noise=CameraNoise(v["camera.yaw_distance_variance_coeff"], v["camera.yaw_variance_floor"]),
            outlier_probability=v["camera.outlier_probability"],
            outlier_position_std=v["camera.outlier_position_std"],
            outlier_yaw_std=v["camera.outlier_yaw_std"],
            enabled=v["camera.enabled"]),
        imu=ImuConfig(period_ns=periods["imu.frequency"], yaw_variance=v["imu.yaw_variance"],
                      yaw_rate_variance=v["imu.yaw_rate_variance"], accel_variance=v["imu.accel_variance"],
                      enabled=v["imu.enabled"], tilt_variance=v["imu.tilt_variance"]),
        truth_period_ns=periods["ground_truth.frequency"],
        ramp=ramp,
    )
    node = NodeSettings(
        seed=v["seed"], real_time_factor=v["real_time_factor"], publish_clock=v["publish_clock"],
        cmd_vel_timeout_ns=seconds_to_ns(v["cmd_vel_timeout"]),
        wait_for_topics=tuple(v["wait_for_topics"]), wait_timeout_s=v["wait_timeout"],
        stamped_cmd_vel=v["stamped_cmd_vel"],
        initial_pose=tuple(v["initial_pose"]),  # type: ignore[arg-type]
        map_frame=v["map_frame"], odom_frame=v["odom_frame"], base_link_frame=v["base_link_frame"],
        publish_joint_states=v["dead_wheels.publish_joint_states"],
        joint_names=tuple(v["dead_wheels.joint_names"]),  # type: ignore[arg-type]
        publish_odom_tf=v["publish_odom_tf"],
        odom_dropout_ns=(seconds_to_ns(v["dead_wheels.dropout"][0]),
                         seconds_to_ns(sum(v["dead_wheels.dropout"]))) if v["dead_wheels.dropout"] else None)
    return world, node
