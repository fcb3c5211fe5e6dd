"""ekf_node's parameters: the schema and its parsing into :class:`EkfNodeSettings` (no rclpy).

The settings hold the Localizer's :class:`EkfConfig` and what only the node uses
(ros.ekf_node_settings). The same parser serves ekf_node (values read from rclpy after the
parameter file is loaded) and the offline tools (:func:`load_ekf_settings` and
:func:`load_ekf_config` read the YAML directly). Every problem is collected and raised as one
:class:`ParameterError`. Names follow robot_localization (RL) where the concept is the same,
including the per-input settings (``odom0``, ``odom0_config``,
``imu0_twist_rejection_threshold``, ...); the defaults are :class:`EkfConfig`'s and
:class:`EkfNodeSettings`'. The inputs' settings are ros.input_parameters'. docs/ekf_node.md's
tables are rendered from :data:`EKF_PARAMETERS` and ros.input_parameters' schemas.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from ekf_localization.core.config import MECANUM_WHEELS, EkfConfig, InputConfig
from ekf_localization.core.linalg import is_positive_definite, is_symmetric
from ekf_localization.core.measurements import FIELD_NAMES, N_FIELDS
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.models.differential import TANK_WHEELS
from ekf_localization.models.registry import MODELS
from ekf_localization.models.swerve import layout_problem
from ekf_localization.ros.ekf_node_settings import NODE_SETTINGS, EkfNodeSettings
from ekf_localization.ros.input_parameters import DOC, INPUT_KINDS, INPUT_RE, NODE_NAME, parse_input
from ekf_localization.ros.parameters import (
    MAX_FREQUENCY_HZ,
    MIN_FREQUENCY_HZ,
    Check,
    Entry,
    Problem,
    Schema,
    at_least,
    choice,
    expected,
    floats,
    is_ros_builtin,
    non_empty,
    non_negative,
    parameters_from_yaml,
    positive,
    raise_problems,
    timer_rate,
)
from ekf_localization.ros.scheduling import FIFO_PRIORITIES

# RL parameters this node does not implement: accepted and ignored with a warning.
RL_IGNORED = frozenset((
    "transform_time_offset", "transform_timeout", "debug", "debug_out_file", "publish_acceleration",
    "control_config", "acceleration_gains", "deceleration_gains", "dynamic_process_noise_covariance",
    "use_dynamic_process_noise_covariance", "permit_corrected_publication", "disabled_at_startup",
    "gravitational_acceleration", "reset_on_time_jump", "two_d_mode",
    # launch / node options and outputs that do not apply (docs/ekf_node.md, robot_localization table)
    "clear_params", "filter_type", "tf_prefix", "base_link_frame_output"))

_FIELDS_TEXT = " ".join(FIELD_NAMES)
_STATIC_FORM = "a list of strings 'x y z yaw pitch roll parent child' (m, rad; static_transform_publisher)"
_MATRIX_FORM = (f"225 numbers (a symmetric 15x15 matrix, row-major) or 15 (its diagonal), field order "
                f"{_FIELDS_TEXT}")
_D = EkfConfig()
_N = EkfNodeSettings()
_MATRIX = Check(lambda v: len(v) in (N_FIELDS, N_FIELDS * N_FIELDS) and all(math.isfinite(x) for x in v),
                _MATRIX_FORM)


def _floats_of(a: Any) -> list[float]:
    return [float(x) for x in np.asarray(a).ravel()]


def _diagonal_text(m: np.ndarray) -> str:
    return "diag " + " ".join(f"{x:g}" for x in np.diag(m))


EKF_PARAMETERS = Schema(NODE_NAME, DOC, (
    Entry("model", "str", _D.model, "",
          "motion model, a name in models.registry.MODELS: "
          + "; ".join(f"'{n}' (state {' '.join(m.state_names)})" for n, m in MODELS.items())),
    Entry("frequency", "float", _N.frequency, "Hz",
          "rate of odometry/filtered (the timer runs on ROS time: on /clock with use_sim_time)",
          timer_rate(f"a rate in Hz from {MIN_FREQUENCY_HZ:g} to {MAX_FREQUENCY_HZ:g}")),
    Entry("publish_on_measurement", "bool", _N.publish_on_measurement, "",
          "also publish odometry/filtered from the callback of each message that was fused (lowest "
          "latency, for inputs at or above frequency; the timer then publishes only what is new; not in RL)"),
    Entry("sensor_timeout", "float", None, "s",
          "an input silent this long is reported stale; with predict_to_current_time false, the output "
          "is predicted to now after this long without measurements", positive(), default_doc="1/frequency"),
    Entry("map_frame", "str", _N.map_frame, "", "REP-105 map frame", non_empty("a non-empty frame name")),
    Entry("odom_frame", "str", _N.odom_frame, "", "REP-105 odom frame", non_empty("a non-empty frame name")),
    Entry("base_link_frame", "str", _D.base_link_frame, "", "robot body frame",
          non_empty("a non-empty frame name")),
    Entry("world_frame", "str", None, "", "frame of the estimate: map_frame or odom_frame",
          non_empty("a non-empty frame name"), default_doc="odom_frame"),
    Entry("publish_tf", "bool", _N.publish_tf, "",
          "broadcast odom_frame->base_link_frame (world odom) or map_frame->odom_frame (world map) "
          "when tf2_ros is installed"),
    Entry("print_diagnostics", "bool", _N.print_diagnostics, "", "publish /diagnostics once a second"),
    Entry("thread_priority", "int", _N.thread_priority, "",
          "run every thread of the node under SCHED_FIFO at this priority (1-99; controller_manager's "
          "name; it uses 50: stay below it, the shipped configs use 40), so that other busy processes "
          "cannot hold the filter off the CPU; 0 = the default scheduling. Where the system refuses it, "
          "a warning and the default (not in RL)",
          Check(lambda v: v in FIFO_PRIORITIES, "an integer from 0 (default scheduling) to 99")),
    Entry("publish_fusion_log", "bool", _N.publish_fusion_log, "",
          "publish std_msgs/Int64MultiArray on ekf_node/fusion_log after each output: the messages fused "
          "since the last one, in order, with their receive times; a bag that records it replays to "
          "the published estimates (bag_replay, ekf_tune; not in RL)"),
    Entry("publish_markers", "bool", _N.publish_markers, "",
          "publish visualization_msgs/MarkerArray on ekf_node/markers (the 95 % position ellipse, the "
          "recent pose fixes: accepted green, gated red; not in RL)"),
    Entry("marker_frequency", "float", _N.marker_frequency, "Hz",
          "rate of the markers (steady clock; with publish_markers)", timer_rate()),
    Entry("marker_fix_count", "int", _N.marker_fix_count, "",
          "how many recent pose fixes (poseN inputs) the markers show", at_least(1, "an integer >= 1")),
    Entry("predict_to_current_time", "bool", _D.predict_to_current_time, "",
          "stamp each output at the current time, predicted; false: at the newest fused measurement "
          "(RL's default)"),
    Entry("smooth_lagged_data", "bool", _D.smooth_lagged_data, "",
          "apply a lagged measurement at its own stamp by rewinding (RL: false)"),
    Entry("history_length", "float", _D.history_length, "s",
          "how far back the filter can rewind (RL: 0); > 0 with smooth_lagged_data", non_negative()),
    Entry("max_measurement_age", "float", None, "s",
          "a measurement stamped before now minus this is rejected as stale_stamp (not in RL)", positive(),
          default_doc="max(2.0, history_length)"),
    Entry("future_stamp_tolerance", "float", _D.future_stamp_tolerance, "s",
          "a measurement, command or set_pose stamped after now plus this is rejected as future_stamp; "
          "one ahead by less is applied at now (not in RL)",
          non_negative()),
    Entry("max_prediction_step", "float", _D.max_prediction_step, "s",
          "longest single prediction step; longer gaps are sub-stepped (not in RL)",
          at_least(1e-6, "a float >= 1e-6")),
    Entry("use_control", "bool", _D.use_control, "",
          "use cmd_vel as the process input (mecanum model only)"),
    Entry("stamped_cmd_vel", "bool", _N.stamped_cmd_vel, "",
          "cmd_vel is geometry_msgs/TwistStamped, applied at its header stamp (false: Twist, at its "
          "receive time); stamped_control, robot_localization's name, is accepted with a warning"),
    Entry("cmd_vel_topic", "str", _N.cmd_vel_topic, "",
          "the topic of the commands with use_control, e.g. diff_drive_controller/cmd_vel or "
          "mecanum_drive_controller/reference (ros2_control); ekf.launch.py's cmd_vel_topic:= "
          "overrides it (not in RL, which takes a remap of cmd_vel)", non_empty("a topic name")),
    Entry("control_timeout", "float", _D.control_timeout, "s",
          "a command (or the differential model's IMU acceleration input) stops being used this long "
          "after its stamp", positive()),
    Entry("control_velocity_variance", "float_list", list(_D.control_velocity_variance), "(m/s)², (rad/s)²",
          "variance of the true velocity about the drive's response to the command (stationary variance "
          "of an Ornstein-Uhlenbeck deviation of correlation time control_time_constant), vx vy vz vroll "
          "vpitch vyaw (seed 000 eq. 26; not in RL)",
          floats(6, "6 non-negative variances (vx vy vz vroll vpitch vyaw)", non_negative_values=True)),
    Entry("control_time_constant", "float_list", list(_D.control_time_constant), "s",
          "first-order lag of the drive toward the command, vx vy vz vroll vpitch vyaw (0 = none: the "
          "command is the next velocity, seed 000 eq. 25; not in RL)",
          floats(6, "6 time constants in s >= 0 (vx vy vz vroll vpitch vyaw)", non_negative_values=True)),
    Entry("acceleration_limits", "float_list", list(_D.acceleration_limits), "m/s², rad/s²",
          "the drive's largest acceleration toward the command while the speed grows (RL's name; "
          "0 = no limit)",
          floats(6, "6 accelerations >= 0 in m/s² and rad/s² (0 = no limit)", non_negative_values=True)),
    Entry("deceleration_limits", "float_list", list(_D.deceleration_limits), "m/s², rad/s²",
          "the same while the speed shrinks (RL's name; 0 = no limit)",
          floats(6, "6 decelerations >= 0 in m/s² and rad/s² (0 = no limit)", non_negative_values=True)),
    Entry("control_latency", "float", _D.control_latency, "s",
          "the drive responds this long after a command's stamp (the previous command acts until then; "
          "not in RL)", non_negative("a duration in s >= 0")),
    Entry("control_velocity_limits", "float_list", list(_D.control_velocity_limits), "m/s, rad/s",
          "a command beyond these magnitudes is rejected as beyond_limits (0 = no check; not in RL)",
          floats(6, "6 speeds >= 0 in m/s and rad/s (0 = no check)", non_negative_values=True)),
    Entry("control_guard", "bool", _D.control_guard, "",
          "drop cmd_vel while the measured velocity fails a windowed χ² test against the command-driven "
          "prediction, or no velocity measurement confirms it for control_guard_confirm "
          "(docs/ekf_node.md; not in RL)"),
    Entry("control_guard_window", "float", _D.control_guard_window, "s",
          "window of control_guard's χ² test (the sum of the velocity updates' NIS)", positive()),
    Entry("control_guard_false_alarm", "float", _D.control_guard_false_alarm, "",
          "control_guard trips when the window's NIS sum exceeds the χ² quantile 1 - this", positive()),
    Entry("control_guard_confirm", "float", _D.control_guard_confirm, "s",
          "control_guard drops cmd_vel this long after the newest velocity measurement (the drive is "
          "unconfirmed) and widens the covariance by the command's velocity", positive()),
    *(Entry(name, "float", getattr(_D, name), "m", doc, non_negative("a length in m >= 0")) for name, doc in (
        ("wheel_radius", "mecanum wheel radius r (seed 000 eq. 23); 0 = no wheel geometry"),
        ("half_wheelbase", "L, centre to the front/rear axle (eq. 23)"),
        ("half_track", "l, centre line to a wheel centre (eq. 23)"))),
    Entry("wheel_acceleration_limit", "float", _D.wheel_acceleration_limit, "rad/s²",
          "the drive response in wheel space: every wheel ramps toward its commanded speed together, at "
          "most this fast (0 = per-axis acceleration_limits instead); needs wheel_radius",
          non_negative("a limit in rad/s² >= 0 (0 = none)")),
    Entry("wheel_speed_limit", "float", _D.wheel_speed_limit, "rad/s",
          "commanded wheel speeds are scaled together below this (0 = none)",
          non_negative("a limit in rad/s >= 0 (0 = none)")),
    Entry("control_steer_rate_limit", "float", _D.control_steer_rate_limit, "rad/s",
          "the swerve response: each module turns toward its commanded direction at most this fast "
          "while its speed follows the vx axis's response (0 = per-axis response); needs "
          "control_module_positions (docs/models.md, \"Swerve response\"; not in RL)",
          non_negative("a rate in rad/s >= 0 (0 = none)")),
    Entry("control_module_positions", "float_list", list(_D.control_module_positions), "m",
          "the swerve modules' positions [x0, y0, x1, y1, ...] in base_link for control_steer_rate_limit",
          floats(None, "[x, y] pairs of finite numbers in m", multiple_of=2)),
    Entry("wheel_command_topic", "str", _N.wheel_command_topic, "",
          "std_msgs/Float64MultiArray of commanded wheel speeds (rad/s, seed 000 eq. 20), a process input "
          "besides cmd_vel, stamped on receipt; '' = none"),
    Entry("wheel_order", "str_list", list(_D.wheel_order), "",
          "the wheel of each entry of a wheel command: rear_left, rear_right, front_left, front_right "
          "(eq. 24's m1..m4; model tank: left, right)",
          Check(lambda v: sorted(v) in (sorted(MECANUM_WHEELS), sorted(TANK_WHEELS)),
                "the four wheels " + ", ".join(MECANUM_WHEELS) + " (tank: " + ", ".join(TANK_WHEELS)
                + ") in any order")),
    Entry("control_tilt_compensation", "bool", _D.control_tilt_compensation, "",
          "project the cmd_vel body twist onto the horizontal plane with an IMU's roll and pitch"),
    Entry("process_noise_covariance", "float_list", _floats_of(_D.process_noise_covariance), "(SI unit)²/s",
          "Q, 15x15 row-major in RL field order, times dt; only the diagonal among the model's fields "
          "is used (an off-diagonal entry there is an error)", _MATRIX,
          default_doc="RL's, " + _diagonal_text(_D.process_noise_covariance)),
    Entry("initial_estimate_covariance", "float_list", _floats_of(_D.initial_estimate_covariance),
          "(SI unit)²", "P0, 15x15; the block of the model's fields must be positive definite",
          _MATRIX, default_doc="diag 1 for x y yaw vx vy vyaw, 1e-9 elsewhere"),
    *(Entry(name, "float", getattr(_D, name), unit, doc + "; .inf = no limit",
            Check(lambda v: v > 0.0, f"a limit in {unit} > 0 (.inf = none)"))
      for name, unit, doc in (
          ("max_plausible_speed", "m/s",
           "a fused linear velocity (twist, odometry, cmd_vel) beyond this is rejected as implausible_value"),
          ("max_plausible_angular_speed", "rad/s", "a fused angular velocity (twist, IMU, cmd_vel) beyond "
           "this is rejected (a MEMS gyro's range is about 35 rad/s)"),
          ("max_plausible_acceleration", "m/s²", "a fused linear acceleration beyond this is rejected"),
          ("max_plausible_position", "m", "a fused or set_pose position coordinate beyond this is rejected"),
      )),
    Entry("pose_recovery", "bool", _D.pose_recovery, "",
          "kidnapped-robot recovery: re-initialise the pose from absolute pose fixes (world-frame x, y, yaw) "
          "that keep failing the gate while agreeing with each other"),
    Entry("pose_recovery_min_fixes", "int", _D.pose_recovery_min_fixes, "",
          "at least this many agreeing gated fixes in a row", at_least(1, "an integer >= 1")),
    Entry("pose_recovery_min_duration", "float", _D.pose_recovery_min_duration, "s",
          "spanning at least this long", non_negative("a duration in s >= 0")),
    Entry("pose_recovery_agreement", "float", _D.pose_recovery_agreement, "m",
          "within this of their median position correction", positive("a distance in m > 0")),
    Entry("pose_recovery_angle_agreement", "float", _D.pose_recovery_angle_agreement, "rad",
          "and within this of their median heading correction", positive("an angle in rad > 0")),
    Entry("static_transforms", "str_list", [], "m, rad",
          "fixed transforms, each 'x y z yaw pitch roll parent child' (static_transform_publisher's "
          "arguments), published once on /tf_static and used over any /tf or /tf_static value for "
          "the same child (another node's different value: WARN)",
          Check(lambda v: all(len(t.split()) == 8 for t in v), _STATIC_FORM)),
    Entry("zero_variance_floor", "float", _D.zero_variance_floor, "SI²",
          "a zero variance on a fused field is replaced by this (RL: 1e-9)", positive("a variance > 0")),
    Entry("initial_state", "float_list", _floats_of(_D.initial_state), "SI",
          "15 initial values in RL field order; the model's fields are used",
          floats(N_FIELDS, f"15 finite numbers in field order {_FIELDS_TEXT}"), default_doc="zeros"),
), renamed={"stamped_control": "stamped_cmd_vel"}, ints_as_floats=True)


def parse_ekf_settings(values: Mapping[str, Any],
                       models: Mapping[str, MotionModelSpec] | None = None) -> EkfNodeSettings:
    """Validate a flat {parameter name: value} mapping into ekf_node's :class:`EkfNodeSettings`.

    ``models``: the motion models ``model`` may name (default ``models.registry.MODELS``).
    Raises one :class:`ParameterError` listing every bad parameter.
    """
    models = MODELS if models is None else models
    parsed = EKF_PARAMETERS.parse(values)
    problems: list[Problem] = list(parsed.problems)
    warnings: list[str] = list(parsed.warnings)
    v = parsed.values
    if v["model"] not in models:
        problems.append(expected("model", choice(tuple(models)).form, v["model"]))
        v["model"] = _D.model if _D.model in models else next(iter(models))
    spec = models[v["model"]]
    for name in ("map_frame", "odom_frame", "base_link_frame", "world_frame"):
        if v[name] is not None:
            v[name] = v[name].strip("/ ")
    if v["sensor_timeout"] is None:
        v["sensor_timeout"] = 1.0 / v["frequency"]
    if v["world_frame"] is None:
        v["world_frame"] = v["odom_frame"]
    if v["max_measurement_age"] is None:
        v["max_measurement_age"] = max(2.0, v["history_length"])
    _cross_checks(v, spec, problems)
    model = v["model"]
    state_fields = spec.state_fields
    matrices = {}
    for name, pd, diagonal in (("process_noise_covariance", False, True),
                               ("initial_estimate_covariance", True, False)):
        matrices[name] = _matrix15(name, v[name], state_fields, pd, diagonal, model, problems)
    static = _static_transforms(v["static_transforms"], problems)
    inputs = _parse_inputs(parsed.others, spec, problems, warnings)
    raise_problems(problems)
    if not inputs:
        warnings.append("no inputs configured (odom0, pose0, twist0, imu0, ...): the filter will "
                        "only publish after set_pose")
    scalars = {e: v[e] for e in EKF_PARAMETERS if e not in matrices}
    scalars["static_transforms"] = static
    scalars["wheel_order"] = tuple(v["wheel_order"])
    for name in ("control_velocity_variance", "control_time_constant", "acceleration_limits",
                 "deceleration_limits", "control_velocity_limits", "control_module_positions"):
        scalars[name] = tuple(v[name])
    scalars["initial_state"] = np.array(v["initial_state"], dtype=float)
    node = {name: scalars.pop(name) for name in NODE_SETTINGS}
    config = EkfConfig(**scalars, **matrices, inputs=tuple(inputs))
    return EkfNodeSettings(config, **node, warnings=tuple(warnings))


def parse_ekf_config(values: Mapping[str, Any],
                     models: Mapping[str, MotionModelSpec] | None = None) -> EkfConfig:
    """The Localizer's :class:`EkfConfig` of :func:`parse_ekf_settings` (the warnings are the node's)."""
    return parse_ekf_settings(values, models).config


def _cross_checks(v: dict[str, Any], spec: MotionModelSpec, problems: list[Problem]) -> None:
    if v["map_frame"] == v["odom_frame"]:
        problems.append(expected("odom_frame", "a frame different from map_frame", v["odom_frame"]))
    if v["base_link_frame"] in (v["map_frame"], v["odom_frame"]):
        problems.append(expected("base_link_frame", "a frame different from map_frame and odom_frame",
                                 v["base_link_frame"]))
    if v["world_frame"] not in (v["map_frame"], v["odom_frame"]):
        problems.append(expected("world_frame", f"map_frame ('{v['map_frame']}') or odom_frame "
                                 f"('{v['odom_frame']}')", v["world_frame"]))
    if v["smooth_lagged_data"] and v["history_length"] == 0.0:
        problems.append(expected("history_length", "a duration in s > 0 (smooth_lagged_data is true)",
                                 v["history_length"]))
    if v["smooth_lagged_data"] and v["max_measurement_age"] < v["history_length"]:
        problems.append(expected("max_measurement_age", f"a duration in s >= history_length "
                                 f"({v['history_length']})", v["max_measurement_age"]))
    if v["wheel_radius"] > 0.0:
        for name in ("half_wheelbase", "half_track"):
            if v[name] <= 0.0:
                problems.append(expected(name, "a length in m > 0 (wheel_radius is set)", v[name]))
    for name in ("wheel_acceleration_limit", "wheel_speed_limit"):
        if v[name] > 0.0 and v["wheel_radius"] == 0.0:
            problems.append(expected(name, "0.0 unless wheel_radius, half_wheelbase and half_track are set",
                                     v[name]))
    if v["control_steer_rate_limit"] > 0.0:
        problem = layout_problem(np.reshape(v["control_module_positions"], (-1, 2)))
        if problem is not None:
            problems.append(expected("control_module_positions", f"{problem} (control_steer_rate_limit "
                                     "is set)", v["control_module_positions"]))
        if v["wheel_acceleration_limit"] > 0.0 or v["wheel_speed_limit"] > 0.0:
            problems.append(expected("control_steer_rate_limit", "0.0 with wheel_acceleration_limit or "
                                     "wheel_speed_limit (one drive response)", v["control_steer_rate_limit"]))
    v["wheel_command_topic"] = v["wheel_command_topic"].strip()
    if v["wheel_command_topic"] and v["wheel_radius"] <= 0.0:
        problems.append(expected("wheel_command_topic", "'' unless wheel_radius, half_wheelbase and "
                                 "half_track are set (wheel speeds need the geometry)",
                                 v["wheel_command_topic"]))
    if v["wheel_radius"] > 0.0 and spec.twist_from_wheels is not None and v["half_track"] > 0.0 \
            and v["half_wheelbase"] > 0.0:
        wheels = spec.twist_from_wheels(SimpleNamespace(**v))[0]  # the model's wheels by name
        if sorted(v["wheel_order"]) != sorted(wheels):
            problems.append(expected("wheel_order", f"the wheels {', '.join(wheels)} of model '{spec.name}' "
                                     "in any order", v["wheel_order"]))
    if v["use_control"] and not spec.takes_control:
        problems.append(expected("use_control", f"false for model '{spec.name}': its process input is "
                                 f"{spec.process_input}", True))


def _matrix15(name: str, values: list[float], rows: tuple[int, ...], positive_definite: bool,
              diagonal: bool, model: str, problems: list[Problem]) -> np.ndarray:
    M = np.array(values, dtype=float)
    M = np.diag(M) if len(M) == N_FIELDS else M.reshape(N_FIELDS, N_FIELDS)  # RL's diagonal form too
    sub = M[np.ix_(rows, rows)]
    names = ", ".join(FIELD_NAMES[r] for r in rows)
    if not is_symmetric(M):
        problems.append(expected(name, _MATRIX_FORM + " (it is not symmetric)", "non-symmetric matrix"))
    elif np.any(np.diag(M) < 0.0):
        problems.append(expected(name, _MATRIX_FORM + " with non-negative variances on the diagonal",
                                 [float(x) for x in np.diag(M)]))
    elif diagonal and np.any(sub[~np.eye(len(rows), dtype=bool)] != 0.0):
        problems.append(expected(name, f"no off-diagonal entries among the fields model '{model}' "
                                 f"estimates ({names}): its process noise is diagonal",
                                 "off-diagonal entries"))
    elif positive_definite and not is_positive_definite(sub):
        problems.append(expected(name, f"a positive definite block for the fields model '{model}' "
                                 f"estimates ({names})", [float(x) for x in np.diag(sub)]))
    return M


def _parse_inputs(others: Mapping[str, Any], spec: MotionModelSpec, problems: list[Problem],
                  warnings: list[str]) -> list[InputConfig]:
    """The inputs among the names the global schema does not know; judges every other name."""
    found: dict[str, set[int]] = {k: set() for k in INPUT_KINDS}
    for key in others:
        m = INPUT_RE.match(key)
        if m and m.group(3) == "":
            found[m.group(1)].add(int(m.group(2)))
    inputs = []
    claimed: set[str] = set()
    for kind in INPUT_KINDS:
        numbers = sorted(found[kind])
        for expected_n, n in enumerate(numbers):
            if n != expected_n:
                problems.append(expected(f"{kind}{n}", f"inputs numbered from 0 without gaps ({kind}"
                                         f"{expected_n} is missing)", others[f"{kind}{n}"]))
                break
        for n in numbers:
            inp = parse_input(others, kind, f"{kind}{n}", spec, problems, warnings, claimed)
            if inp is not None:
                inputs.append(inp)
    configured = {i.name for i in inputs} | {f"{k}{n}" for k, ns in found.items() for n in ns}
    for key, value in others.items():
        if key in claimed or is_ros_builtin(key):
            continue
        if key in RL_IGNORED:
            warnings.append(f"parameter '{key}' (robot_localization) is not supported by ekf_node; ignored")
            continue
        m = INPUT_RE.match(key)
        if m and m.group(1) + m.group(2) not in configured:
            problems.append(expected(key, f"a setting of a configured input, but '{m.group(1)}{m.group(2)}' "
                                     "has no topic", value))
            continue
        problems.append(EKF_PARAMETERS.unknown(key, value))
    return inputs


def _static_transforms(items: list[str],
                       problems: list[Problem]) -> tuple[tuple[str, str, tuple[float, ...]], ...]:
    """The ``static_transforms`` parameter: x y z yaw pitch roll parent child per entry."""
    out = []
    for text in items:
        words = text.split()
        try:
            numbers = tuple(float(w) for w in words[:6])
        except ValueError:
            numbers = ()
        if len(words) != 8 or len(numbers) != 6 or not all(math.isfinite(x) for x in numbers) \
                or words[6].strip("/") == words[7].strip("/"):
            problems.append(expected("static_transforms", _STATIC_FORM + " with two different frames",
                                     text))
            continue
        out.append((words[6].strip("/"), words[7].strip("/"), numbers))
    return tuple(out)


def load_ekf_settings(yaml_path: str | Path, models: Mapping[str, MotionModelSpec] | None = None,
                      node_name: str = NODE_NAME) -> EkfNodeSettings:
    """Read and validate ekf_node's parameters straight from a ROS 2 params file (no ROS needed)."""
    return parse_ekf_settings(parameters_from_yaml(yaml_path, node_name), models)


def load_ekf_config(yaml_path: str | Path, models: Mapping[str, MotionModelSpec] | None = None,
                    node_name: str = NODE_NAME) -> EkfConfig:
    """The Localizer's :class:`EkfConfig` of :func:`load_ekf_settings`."""
    return load_ekf_settings(yaml_path, models, node_name).config


def effective_values(settings: EkfNodeSettings) -> dict[str, Any]:
    """The global parameters' values in effect (derived defaults included), for the node to declare."""
    out: dict[str, Any] = {}
    for name in EKF_PARAMETERS:
        if name == "static_transforms":  # strings in the file, parsed in the config: declared when given
            continue
        v = getattr(settings if name in NODE_SETTINGS else settings.config, name)
        if name == "wheel_order":
            v = list(v)
        elif isinstance(v, (np.ndarray, tuple)):
            v = _floats_of(v)
        out[name] = v
    return out
