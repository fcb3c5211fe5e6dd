"""sim_node parameters: the schema (names, SI units, defaults) and its validation (no ROS).

``parse_parameters(values)`` turns a ``{name: value}`` dict (ROS parameter values, dotted
names as in config/sim.yaml) into a ``WorldConfig`` and ``NodeSettings``. A value of the
wrong type or out of range raises one ``ParameterError`` listing every bad parameter with
the expected form; floats must be written with a decimal point (``50.0``, not ``50``).
docs/simulator.md's parameter table is rendered from :data:`SIM_PARAMETERS`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ekf_localization.core.units import METRES_PER_INCH, NS_PER_S, seconds_to_ns
from ekf_localization.models.mecanum import MecanumKinematics
from ekf_localization.models.sensors.camera import CameraNoise
from ekf_localization.models.sensors.dead_wheels import EncoderNoise
from ekf_localization.models.swerve import SwerveKinematics, layout_problem
from ekf_localization.ros.parameters import (
    Check,
    Entry,
    Problem,
    Schema,
    at_least,
    choice,
    expected,
    finite,
    floats,
    non_empty,
    non_negative,
    positive,
    raise_problems,
)
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import load_tag_layout
from sim_robot.ros.sim_pod_params import DEAD_WHEEL_GEOMETRY, dead_wheel_geometry
from sim_robot.world.bump import Bump
from sim_robot.world.camera_image_sensor import CameraImageConfig
from sim_robot.world.camera_render import RenderSettings
from sim_robot.world.camera_sensor import CameraConfig
from sim_robot.world.dead_wheel_sensor import SAMPLING_MODES, DeadWheelConfig
from sim_robot.world.drives import DRIVES, DriveLimits, TankKinematics
from sim_robot.world.field import FIELD_SIZE_IN, PRESETS, Field, FieldImage
from sim_robot.world.imu_sensor import ImuConfig
from sim_robot.world.ramp import Ramp
from sim_robot.world.swerve_drive import SwerveDriveConfig
from sim_robot.world.wheel_encoder_sensor import WheelEncoderConfig
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


_dw, _cam, _imu, _ramp = _SEED.dead_wheels, _SEED.camera, _SEED.imu, _SEED.ramp
_we = _SEED.wheel_encoders
DRIVEN_JOINTS = ("wheel_rear_left", "wheel_rear_right", "wheel_front_left", "wheel_front_right")
_sw = _SEED.swerve
SWERVE_MODULES = ("front_left", "front_right", "rear_left", "rear_right")

_POSITIVE = positive()
_NON_NEGATIVE = non_negative()
_FRAME = non_empty("a non-empty frame id")
_TRIPLE = floats(3, "3 finite floats [x, y, yaw]")
_TRIPLE_NON_NEGATIVE = floats(3, "3 finite floats >= 0", non_negative_values=True)


def _float(name: str, default: float, unit: str, doc: str, check: Check = _POSITIVE) -> Entry:
    return Entry(name, "float", default, unit, doc, check)


def _bool(name: str, default: bool, doc: str) -> Entry:
    return Entry(name, "bool", default, "", doc)


SIM_PARAMETERS = Schema("sim_node", "docs/simulator.md", (
    Entry("seed", "int", 0, "", "random seed", at_least(0, "an integer >= 0")),
    Entry("drive", "str", "mecanum", "", "drive type", choice(DRIVES)),
    _float("real_time_factor", 1.0, "", "sim seconds per wall second; 0.0 = as fast as possible "
           "(needs publish_clock)", _NON_NEGATIVE),
    _bool("publish_clock", False, "publish /clock (other nodes set use_sim_time)"),
    _bool("publish_odom_tf", True,
          "broadcast odom->base_link on /tf from the dead-wheel odometry (as a drive controller does)"),
    _bool("stamped_cmd_vel", False, "cmd_vel is geometry_msgs/TwistStamped (true) or Twist (false)"),
    Entry("wait_for_topics", "str_list", [], "",
          "hold sim time at 0 until each of these topics has a publisher (e.g. the EKF's "
          "odometry/filtered and cmd_vel); [] = start at once",
          Check(lambda v: all(v), "a list of non-empty topic names")),
    _float("wait_timeout", 30.0, "s", "wall time: start anyway after waiting this long for wait_for_topics",
           _NON_NEGATIVE),
    _float("physics_frequency", 1000.0, "Hz", "truth integration rate"),
    _float("cmd_vel_timeout", 0.5, "s", "sim time without cmd_vel before the command is zeroed; 0.0 = never",
           _NON_NEGATIVE),
    _float("cmd_vel_latency", 0.0, "s", "the drive acts on a command this long after its stamp (the receipt "
           "time for an unstamped Twist); one that arrives later acts at once and is counted late",
           _NON_NEGATIVE),
    Entry("initial_pose", "float_list", [0.0, 0.0, 0.0], "m, m, rad", "[x, y, yaw] in map", _TRIPLE),
    Entry("map_frame", "str", "map", "", "field frame", _FRAME),
    Entry("odom_frame", "str", "odom", "", "odometry frame", _FRAME),
    Entry("base_link_frame", "str", "base_link", "", "robot body frame", _FRAME),
    Entry("field.preset", "str", "seed000", "", "wall image layout", choice((*PRESETS, "custom"))),
    _float("field.image_width", 10.0 * _IN, "m", "image width"),
    Entry("field.custom_images", "float_list", [], "m, m, rad",
          "for preset 'custom': [x, y, facing_yaw] per image",
          floats(None, "a flat list [x1, y1, facing_yaw1, x2, ...] of finite floats (length a multiple "
                 "of 3)", multiple_of=3)),
    _float("mecanum.wheel_radius", _SEED.mecanum.wheel_radius, "m", "r"),
    _float("mecanum.half_wheelbase", _SEED.mecanum.half_length, "m", "L, centre to front/rear axle (eq. 23)"),
    _float("mecanum.half_track", _SEED.mecanum.half_width, "m", "l, centre line to wheel centre (eq. 23)"),
    _float("mecanum.strafe_scale", 1.0, "", "the robot's vy per eq. 23's from the wheels (slip: < 1)"),
    _float("tank.wheel_radius", _SEED.tank.wheel_radius, "m", "r"),
    _float("tank.half_track", _SEED.tank.half_track, "m", "b"),
    Entry("swerve.module_positions", "float_list", [float(v) for v in _sw.kinematics.positions.ravel()], "m",
          "[x0, y0, x1, y1, ...] of each module in base_link (drive swerve)",
          Check(lambda v: len(v) % 2 == 0 and layout_problem([v[i:i + 2] for i in range(0, len(v), 2)])
                is None,
                "pairs [x, y] of two or more modules, not all at one point")),
    _float("swerve.wheel_radius", _sw.wheel_radius, "m", "module wheel radius"),
    _float("swerve.steer_rate_limit", _sw.steer_rate_limit, "rad/s", "how fast a module steers"),
    _float("swerve.drive_acceleration_limit", _sw.drive_acceleration_limit, "rad/s²",
           "wheel acceleration limit of a module"),
    _float("swerve.wheel_speed_limit", _sw.wheel_speed_limit, "rad/s", "module wheel speed limit (the "
           "module speeds are scaled together below it)"),
    _float("swerve.traction_limit", _sw.traction_limit, "m/s²", "the floor's grip: the most a module's "
           "contact point changes its velocity per second; asked for more, the wheel slips"),
    _float("swerve.drive_gear_ratio", _sw.drive_gear_ratio, "", "drive joint rad per wheel rad (the "
           "encoders read the drive joint)"),
    _float("swerve.coupling_ratio", _sw.coupling_ratio, "", "drive joint rad per steering rad (coaxial "
           "module)", finite()),
    Entry("swerve.module_names", "str_list", list(SWERVE_MODULES), "",
          "module names: joint_states has <name>_drive and <name>_steer per module",
          Check(lambda v: len(set(v)) == len(v) and all(v), "distinct non-empty names, one per module")),
    _float("limits.wheel_speed_limit", 0.0, "rad/s", "0.0 = no limit (sim.yaml: 312 rpm)", _NON_NEGATIVE),
    _float("limits.wheel_acceleration_limit", 0.0, "rad/s²", "0.0 = no limit", _NON_NEGATIVE),
    Entry("process_noise.pose_variance_rate", "float_list", list(POSE_VARIANCE_RATE),
          "m²/s, m²/s, rad²/s", "x, y, yaw variance per second, times the tick (eq. 26)",
          _TRIPLE_NON_NEGATIVE),
    Entry("process_noise.velocity_variance_per_step", "float_list", list(VELOCITY_VARIANCE_PER_TICK),
          "(m/s)², (m/s)², (rad/s)²", "vx, vy, vyaw variance per physics tick (eq. 26's form; see the notes)",
          _TRIPLE_NON_NEGATIVE),
    _bool("dead_wheels.enabled", True, "publish odometry/dead_wheels"),
    _float("dead_wheels.frequency", 100.0, "Hz", "encoder sampling rate"),
    *DEAD_WHEEL_GEOMETRY,
    _float("dead_wheels.speed_variance_coeff", _dw.noise.speed_variance_coeff, "",
           "a in a*E^2 + b (eq. 32), dimensionless", _NON_NEGATIVE),
    _float("dead_wheels.variance_floor", _dw.noise.variance_floor, "(m/s)²", "b in a*E^2 + b"),
    Entry("dead_wheels.sampling", "str", "instantaneous", "", "speed sampling", choice(SAMPLING_MODES)),
    _bool("dead_wheels.publish_pose", True, "integrate and publish the pose"),
    Entry("dead_wheels.dropout", "float_list", [], "s, s",
          "[start, duration] of sim time during which odometry/dead_wheels is silent; [] = none",
          Check(lambda v: not v or (len(v) == 2 and all(math.isfinite(x) and x >= 0.0 for x in v)),
                "[] or [start s >= 0, duration s >= 0]")),
    Entry("bump", "float_list", [], "s, m, m",
          "[t, dx, dy]: push the robot by (dx, dy) in the field frame over 0.3 s from sim time t, its "
          "driven wheels keeping their speeds (sim_robot/world/bump.py); [] = none",
          Check(lambda v: not v or (len(v) == 3 and all(math.isfinite(x) for x in v) and v[0] >= 0.0),
                "[] or [t s >= 0, dx m, dy m]")),
    _bool("dead_wheels.publish_joint_states", False,
          "also publish joint_states (sensor_msgs/JointState: encoder positions in rad, like ros2_control's "
          "joint_state_broadcaster)"),
    Entry("dead_wheels.joint_names", "str_list", ["left_pod", "right_pod", "lateral_pod"], "",
          "joint names of the left, right and lateral dead wheels in joint_states",
          Check(lambda v: len(v) == 3 and len(set(v)) == 3 and all(v),
                "3 distinct non-empty joint names [left, right, lateral]")),
    _float("dead_wheels.wheel_radius", _dw.wheel_radius, "m",
           "joint position (rad) = distance along the surface / wheel_radius"),
    _bool("wheel_encoders.publish_joint_states", False,
          "publish the drive's own wheels on joint_states (sensor_msgs/JointState: positions in rad "
          "quantised to whole counts, velocities in rad/s) at jittered intervals; not with "
          "dead_wheels.publish_joint_states"),
    Entry("wheel_encoders.joint_names", "str_list", list(DRIVEN_JOINTS), "",
          "joint names of the wheels [rear_left, rear_right, front_left, front_right] (mecanum, eq. 24's "
          "m1..m4) or, with drive tank, the first two are [left, right]",
          Check(lambda v: len(v) in (2, 4) and len(set(v)) == len(v) and all(v),
                "2 (tank) or 4 (mecanum) distinct non-empty joint names")),
    _float("wheel_encoders.resolution", _we.resolution, "rad",
           "one encoder count in rad of the wheel (2π / counts per turn); 0 = exact", _NON_NEGATIVE),
    _float("wheel_encoders.period", _we.period_ns / NS_PER_S, "s", "mean interval between read-outs"),
    _float("wheel_encoders.min_interval", _we.min_interval_ns / NS_PER_S, "s",
           "shortest interval (intervals: this plus an exponential delay, cut at max_interval)"),
    _float("wheel_encoders.max_interval", _we.max_interval_ns / NS_PER_S, "s", "longest interval"),
    _bool("camera.enabled", True, "publish camera/pose"),
    _float("camera.frequency", 100.0, "Hz", "capture rate"),
    _float("camera.latency", 0.0, "s", "from capture to publication", _NON_NEGATIVE),
    _float("camera.field_of_view_deg", 70.0, "deg", "horizontal field of view",
           Check(lambda v: 0.0 < v < 180.0, "an angle in (0.0, 180.0) degrees")),
    _float("camera.max_range", 10.0, "m", "camera to image centre"),
    Entry("camera.mount_pose", "float_list", [0.0, 0.0, 0.0], "m, m, rad", "[x, y, yaw] of the camera in "
          "base_link", _TRIPLE),
    _bool("camera.pose_of_camera", False, "camera/pose is the camera's pose at mount_pose (the filter's "
          "poseN_pose_frame and mount turn it into base_link's), not base_link's"),
    _float("camera.position_distance_variance_coeff", _cam.position_noise.distance_variance_coeff, "",
           "a in a*d^2 + b for x and y (eq. 32), dimensionless", _NON_NEGATIVE),
    _float("camera.position_variance_floor", _cam.position_noise.variance_floor, "m²", "b for x and y"),
    _float("camera.yaw_distance_variance_coeff", _cam.yaw_noise.distance_variance_coeff, "rad²/m²",
           "a for yaw (the default is seed 000's eq. 32 applied to yaw)", _NON_NEGATIVE),
    _float("camera.yaw_variance_floor", _cam.yaw_noise.variance_floor, "rad²", "b for yaw"),
    _float("camera.outlier_probability", 0.0, "", "per visible capture",
           Check(lambda v: 0.0 <= v <= 1.0, "a probability in [0.0, 1.0]")),
    _float("camera.outlier_position_std", _cam.outlier_position_std, "m", "outlier position std",
           _NON_NEGATIVE),
    _float("camera.outlier_yaw_std", _cam.outlier_yaw_std, "rad", "outlier yaw std", _NON_NEGATIVE),
    _bool("camera_images.enabled", False, "publish camera/image_raw (mono8) and camera/camera_info "
          "of the tags in camera_images.tag_layout, and the static TF base_link -> frame_id"),
    _float("camera_images.frequency", 20.0, "Hz", "capture rate"),
    _float("camera_images.latency", 0.03, "s", "from capture (the stamp, mid-exposure) to publication",
           _NON_NEGATIVE),
    Entry("camera_images.width", "int", 640, "px", "image width", at_least(16, "an integer >= 16")),
    Entry("camera_images.height", "int", 480, "px", "image height", at_least(16, "an integer >= 16")),
    _float("camera_images.horizontal_fov_deg", 70.0, "deg", "horizontal field of view (square pixels, "
           "centred principal point, no distortion)",
           Check(lambda v: 0.0 < v < 180.0, "an angle in (0.0, 180.0) degrees")),
    Entry("camera_images.mount", "float_list", [0.1, 0.0, 0.15, 0.0, 0.0], "m, m, m, rad, rad",
          "[x, y, z, yaw, pitch] of the camera in base_link (pitch > 0 looks down)",
          floats(5, "5 finite floats [x, y, z, yaw, pitch]")),
    Entry("camera_images.frame_id", "str", "camera_optical", "", "the camera's optical frame "
          "(REP-103: z forward, x right, y down)", _FRAME),
    Entry("camera_images.tag_layout", "str", "", "", "tag layout YAML (config/tags/*.yaml; a relative "
          "path not found from the working directory is taken from the repository root); required "
          "when camera_images.enabled"),
    _float("camera_images.exposure_time", 0.004, "s", "exposure: motion blur and brightness (grey "
           "levels as given at 0.004 s, scaled linearly)"),
    _float("camera_images.noise_std", 0.42, "grey levels", "Gaussian pixel noise std (real "
           "photographs: docs/apriltags.md)", _NON_NEGATIVE),
    _float("camera_images.optics_blur_std", 0.52, "px", "std of the lens's Gaussian blur (real "
           "photographs: docs/apriltags.md)", _NON_NEGATIVE),
    _bool("camera_images.motion_blur", True, "blur along the image motion during the exposure"),
    _float("camera_images.background_level", 120.0, "grey levels", "the field around the tags",
           _NON_NEGATIVE),
    _float("camera_images.white_level", 215.0, "grey levels", "a tag's white", _NON_NEGATIVE),
    _float("camera_images.black_level", 25.0, "grey levels", "a tag's black", _NON_NEGATIVE),
    _bool("camera1.enabled", False, "a second camera at camera1.mount: camera1/pose (with camera.enabled; "
          "the camera.* model) and camera1/image_raw + camera1/camera_info (with camera_images.enabled; the "
          "camera_images.* camera, its own noise stream, capturing half a period after the first) and the "
          "static TF base_link -> camera1.frame_id"),
    Entry("camera1.mount", "float_list", [-0.1, 0.0, 0.15, math.pi, 0.0], "m, m, m, rad, rad",
          "[x, y, z, yaw, pitch] of the second camera in base_link (the pose camera uses x, y, yaw)",
          floats(5, "5 finite floats [x, y, z, yaw, pitch]")),
    Entry("camera1.frame_id", "str", "camera1_optical", "", "the second camera's optical frame", _FRAME),
    _bool("imu.enabled", True, "publish imu/data"),
    _float("imu.frequency", 100.0, "Hz", "sampling rate"),
    _float("imu.yaw_variance", _imu.yaw_variance, "rad²", "yaw variance"),
    _float("imu.yaw_rate_variance", _imu.yaw_rate_variance, "(rad/s)²", "yaw rate variance"),
    _float("imu.accel_variance", _imu.accel_variance, "(m/s²)²", "acceleration variance"),
    _float("imu.tilt_variance", _imu.tilt_variance, "rad²", "roll and pitch variance"),
    _float("imu.yaw_rate_scale", 1.0, "", "the gyro reports scale * true rate + bias (miscalibrated)"),
    _float("imu.yaw_rate_bias", 0.0, "rad/s", "the gyro's yaw-rate bias (see yaw_rate_scale)", finite()),
    _bool("ramp.enabled", False, "a ramp on the field (sim_robot/world/ramp.py)"),
    _float("ramp.x_min", _ramp.x_min, "m", "region start (the slope rises along +x)", finite()),
    _float("ramp.x_max", _ramp.x_max, "m", "region end", finite()),
    _float("ramp.y_min", _ramp.y_min, "m", "region side", finite()),
    _float("ramp.y_max", _ramp.y_max, "m", "region side", finite()),
    _float("ramp.slope_deg", math.degrees(_ramp.slope), "deg", "slope",
           Check(lambda v: 0.0 < v < 45.0, "an angle in (0.0, 45.0) degrees")),
    _float("ramp.flat_top_length", _ramp.flat_top_length, "m", "level top between the up and down slopes",
           _NON_NEGATIVE),
    _float("ground_truth.frequency", 100.0, "Hz", "ground_truth/odom rate"),
    _bool("ground_truth.at_clock", False, "also a ground_truth/odom at the end of every step of sim time, "
          "the stamp /clock then publishes (an estimate stamped at a node's sim-time clock has an exact "
          "truth sample)"),
))


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
    driven_joint_names: tuple[str, ...] = ()  # the drive's wheels on joint_states (empty: not published)
    publish_odom_tf: bool = True
    odom_dropout_ns: tuple[int, int] | None = None  # [start, end) of sim time without dead wheels
    camera_images: CameraImageConfig | None = None  # None: no images
    camera_frame: str = "camera_optical"
    truth_at_clock: bool = False  # ground_truth.at_clock
    camera1_images: CameraImageConfig | None = None  # the second camera's images (None: none)
    camera1_frame: str = "camera1_optical"


def _period_ns(name: str, frequency: float, physics_ns: int, errors: list[Problem]) -> int:
    ratio = NS_PER_S / frequency
    period = round(ratio) if math.isfinite(ratio) else 0  # (a rate near 0 has no period)
    if period <= 0 or abs(period * frequency - NS_PER_S) > 1e-6 * NS_PER_S or period % physics_ns:
        physics_hz = NS_PER_S / physics_ns
        examples = ", ".join(f"{physics_hz / m:.1f}" for m in (1, 2, 4, 5, 10, 20, 25, 40, 50, 100)[:8])
        errors.append(expected(name, f"a rate in Hz whose period is a whole number of physics ticks "
                               f"({physics_ns} ns), e.g. {examples}", frequency))
        return physics_ns
    return period


def parse_parameters(values: Mapping[str, Any]) -> tuple[WorldConfig, NodeSettings]:
    """Validate ``values`` (missing names take their defaults) and build the configs.

    Raises one :class:`ParameterError` listing every bad parameter.
    """
    parsed = SIM_PARAMETERS.parse(values)
    errors = parsed.problems + SIM_PARAMETERS.unknown_problems(parsed.others)
    v = parsed.values
    tick = NS_PER_S / v["physics_frequency"]
    physics_ns = round(tick) if math.isfinite(tick) else 0
    if physics_ns < 1 or abs(physics_ns * v["physics_frequency"] - NS_PER_S) > 1e-6 * NS_PER_S:
        errors.append(expected("physics_frequency", "a rate with a whole number of ns per tick, e.g. 1000.0",
                               v["physics_frequency"]))
        physics_ns = 1_000_000  # to check the other rates against
    periods = {name: _period_ns(name, v[name], physics_ns, errors)
               for name in ("dead_wheels.frequency", "camera.frequency", "imu.frequency",
                            "ground_truth.frequency", "camera_images.frequency")}
    images = _camera_images(v, periods["camera_images.frequency"], errors)
    second = v["camera1.enabled"]
    if second and v["camera1.frame_id"] == v["camera_images.frame_id"]:
        errors.append(expected("camera1.frame_id", "a frame other than camera_images.frame_id",
                               v["camera1.frame_id"]))
    if v["real_time_factor"] != 1.0 and not v["publish_clock"]:
        errors.append(expected("real_time_factor", "1.0 unless publish_clock is true (other nodes can "
                               "follow a faster or slower sim only on sim time)", v["real_time_factor"]))
    if v["field.preset"] == "custom":
        c = v["field.custom_images"]
        wall_images = tuple(FieldImage(c[i], c[i + 1], c[i + 2], v["field.image_width"], f"image {i // 3}")
                       for i in range(0, len(c), 3))
        field = Field(FIELD_SIZE_IN * _IN, wall_images)
    else:
        field = Field.preset(v["field.preset"], _IN, v["field.image_width"])
    try:
        ramp = Ramp(v["ramp.enabled"], v["ramp.x_min"], v["ramp.x_max"], v["ramp.y_min"], v["ramp.y_max"],
                    math.radians(v["ramp.slope_deg"]), v["ramp.flat_top_length"])
    except ValueError as exc:
        ramp = _SEED.ramp
        errors.append(Problem("ramp.*", f"expected a region with x_min < x_max, y_min < y_max and a "
                              f"flat_top_length shorter than it ({exc})", what="parameters"))
    encoders = _wheel_encoders(v, physics_ns, errors)
    swerve = _swerve(v, errors)
    raise_problems(errors)

    def limit(name: str) -> float:
        return math.inf if v[name] == 0.0 else v[name]

    camera = CameraConfig(
        period_ns=periods["camera.frequency"],
        latency_ns=seconds_to_ns(v["camera.latency"]),
        field_of_view=math.radians(v["camera.field_of_view_deg"]),
        max_range=v["camera.max_range"],
        mount_pose=tuple(v["camera.mount_pose"]),
        position_noise=CameraNoise(v["camera.position_distance_variance_coeff"],
                                   v["camera.position_variance_floor"]),
        yaw_noise=CameraNoise(v["camera.yaw_distance_variance_coeff"], v["camera.yaw_variance_floor"]),
        outlier_probability=v["camera.outlier_probability"],
        outlier_position_std=v["camera.outlier_position_std"], outlier_yaw_std=v["camera.outlier_yaw_std"],
        enabled=v["camera.enabled"], pose_of_camera=v["camera.pose_of_camera"])
    x1, y1, _, yaw1, _ = v["camera1.mount"]
    camera1 = replace(camera, mount_pose=(x1, y1, yaw1), enabled=camera.enabled and second)
    world = WorldConfig(
        drive=v["drive"],
        mecanum=MecanumKinematics(v["mecanum.wheel_radius"], v["mecanum.half_wheelbase"],
                                  v["mecanum.half_track"]),
        tank=TankKinematics(v["tank.wheel_radius"], v["tank.half_track"]),
        strafe_scale=v["mecanum.strafe_scale"],
        limits=DriveLimits(limit("limits.wheel_speed_limit"), limit("limits.wheel_acceleration_limit")),
        physics_period_ns=physics_ns,
        pose_variance_rate=tuple(v["process_noise.pose_variance_rate"]),
        velocity_variance_per_step=tuple(v["process_noise.velocity_variance_per_step"]),
        field=field,
        dead_wheels=DeadWheelConfig(
            **dead_wheel_geometry(v),
            noise=EncoderNoise(v["dead_wheels.speed_variance_coeff"], v["dead_wheels.variance_floor"]),
            period_ns=periods["dead_wheels.frequency"],
            sampling=v["dead_wheels.sampling"],
            integrate_pose=v["dead_wheels.publish_pose"],
            enabled=v["dead_wheels.enabled"],
            wheel_radius=v["dead_wheels.wheel_radius"]),
        camera=camera,
        camera1=camera1,
        imu=ImuConfig(period_ns=periods["imu.frequency"], yaw_variance=v["imu.yaw_variance"],
                      yaw_rate_variance=v["imu.yaw_rate_variance"], accel_variance=v["imu.accel_variance"],
                      enabled=v["imu.enabled"], tilt_variance=v["imu.tilt_variance"],
                      yaw_rate_scale=v["imu.yaw_rate_scale"], yaw_rate_bias=v["imu.yaw_rate_bias"]),
        truth_period_ns=periods["ground_truth.frequency"],
        ramp=ramp,
        command_latency_ns=seconds_to_ns(v["cmd_vel_latency"]),
        wheel_encoders=encoders,
        swerve=swerve,
        bump=(Bump(seconds_to_ns(v["bump"][0]), float(v["bump"][1]), float(v["bump"][2]))
              if v["bump"] else None),
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
        driven_joint_names=_driven_joint_names(v) if encoders.enabled else (),
        publish_odom_tf=v["publish_odom_tf"],
        odom_dropout_ns=(seconds_to_ns(v["dead_wheels.dropout"][0]),
                         seconds_to_ns(sum(v["dead_wheels.dropout"]))) if v["dead_wheels.dropout"] else None,
        camera_images=images, camera_frame=v["camera_images.frame_id"],
        truth_at_clock=v["ground_truth.at_clock"],
        # free-running: the second camera captures half a period after the first (whole physics ticks)
        camera1_images=replace(images, mount=tuple(v["camera1.mount"]),
                               phase_ns=images.period_ns // 2 // physics_ns * physics_ns)
        if images and second else None,
        camera1_frame=v["camera1.frame_id"])
    return world, node


def _driven_joint_names(v: Mapping[str, Any]) -> tuple[str, ...]:
    """The names on joint_states: the wheels', or a swerve's drive joints then its steer joints."""
    if v["drive"] == "swerve":
        names = v["swerve.module_names"]
        return tuple(f"{m}_drive" for m in names) + tuple(f"{m}_steer" for m in names)
    return tuple(v["wheel_encoders.joint_names"][:2 if v["drive"] == "tank" else 4])


def _swerve(v: Mapping[str, Any], errors: list[Problem]) -> SwerveDriveConfig:
    """The swerve drive (sim_robot.world.swerve_drive) from ``swerve.*``."""
    pos = v["swerve.module_positions"]
    if len(v["swerve.module_names"]) * 2 != len(pos):
        errors.append(expected("swerve.module_names", f"{len(pos) // 2} names, one per module in "
                               "swerve.module_positions", v["swerve.module_names"]))
    try:
        return SwerveDriveConfig(SwerveKinematics(pos), v["swerve.wheel_radius"],
                                 v["swerve.steer_rate_limit"],
                                 v["swerve.drive_acceleration_limit"], v["swerve.wheel_speed_limit"],
                                 v["swerve.traction_limit"], v["swerve.drive_gear_ratio"],
                                 v["swerve.coupling_ratio"])
    except ValueError as exc:
        errors.append(Problem("swerve.*", str(exc), what="parameters"))
        return _SEED.swerve


def _wheel_encoders(v: Mapping[str, Any], physics_ns: int, errors: list[Problem]) -> WheelEncoderConfig:
    """The drive's wheel encoders (sim_robot.world.wheel_encoder_sensor) from ``wheel_encoders.*``."""
    on = v["wheel_encoders.publish_joint_states"]
    if on and v["dead_wheels.publish_joint_states"]:
        errors.append(expected("wheel_encoders.publish_joint_states", "false while "
                               "dead_wheels.publish_joint_states is true (one source on joint_states)", on))
    if on and v["drive"] == "mecanum" and len(v["wheel_encoders.joint_names"]) != 4:
        errors.append(expected("wheel_encoders.joint_names", "4 joint names for drive mecanum",
                               v["wheel_encoders.joint_names"]))
    try:
        return WheelEncoderConfig(on, seconds_to_ns(v["wheel_encoders.period"]),
                                  seconds_to_ns(v["wheel_encoders.min_interval"]),
                                  seconds_to_ns(v["wheel_encoders.max_interval"]),
                                  v["wheel_encoders.resolution"])
    except ValueError as exc:
        errors.append(Problem("wheel_encoders.*", str(exc), what="parameters"))
        return WheelEncoderConfig()


def _camera_images(v: Mapping[str, Any], period_ns: int, errors: list[Problem]) -> CameraImageConfig | None:
    """The image camera's config when enabled (its tag layout read here), else None."""
    if not v["camera_images.enabled"]:
        return None
    path = v["camera_images.tag_layout"]
    try:
        if not path:
            raise ValueError("no file given")
        if not Path(path).is_absolute() and not Path(path).exists():   # relative to the repository
            path = str(Path(__file__).resolve().parents[2] / path)
        layout = load_tag_layout(path)
    except (OSError, ValueError) as exc:
        errors.append(expected("camera_images.tag_layout", f"a readable tag layout YAML ({exc})", path))
        return None
    try:
        render = RenderSettings(
            v["camera_images.background_level"], v["camera_images.white_level"],
            v["camera_images.black_level"], v["camera_images.exposure_time"],
            noise_std=v["camera_images.noise_std"], motion_blur=v["camera_images.motion_blur"],
            optics_blur_std=v["camera_images.optics_blur_std"])
        camera = PinholeCamera.from_fov(v["camera_images.width"], v["camera_images.height"],
                                        math.radians(v["camera_images.horizontal_fov_deg"]))
        return CameraImageConfig(camera, layout, period_ns, seconds_to_ns(v["camera_images.latency"]),
                                 tuple(v["camera_images.mount"]), render)  # type: ignore[arg-type]
    except ValueError as exc:
        errors.append(Problem("camera_images.*", str(exc), what="parameters"))
        return None
