"""pure_pursuit_node's parameters: the schema and its parsing into :class:`NodeSettings` (no rclpy).

The follower's own limits are checked by :class:`FollowerConfig` and :class:`PIDGains` (their
messages become problems of the parameter they name); every problem is collected and raised
as one :class:`ParameterError`. The defaults are FollowerConfig's. docs/pure_pursuit.md's
table is rendered from :data:`PURE_PURSUIT_PARAMETERS`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from ekf_localization.control.field_path import FieldPath, PathError, load_path, resolve_config_file
from ekf_localization.control.pid import PIDGains
from ekf_localization.control.pure_pursuit import FollowerConfig
from ekf_localization.core.units import seconds_to_ns
from ekf_localization.ros.parameters import (
    Check,
    Entry,
    Problem,
    Schema,
    at_least,
    positive,
    raise_problems,
    timer_rate,
)

NODE_NAME = "pure_pursuit_node"
_D = FollowerConfig()
PID_AXES = ("pid_x", "pid_y", "pid_yaw")
_PID_FIELDS = ("kp", "ki", "kd", "integral_limit")
_PID_UNITS = {"pid_x": ("1/s", "1/s²", "", "m·s"), "pid_y": ("1/s", "1/s²", "", "m·s"),
              "pid_yaw": ("1/s", "1/s²", "", "rad·s")}
_PID_DOCS = {"kp": "proportional gain", "ki": "integral gain", "kd": "derivative gain (on the measurement)",
             "integral_limit": "anti-windup bound on the integral (.inf = none)"}
_AXIS_DOC = {"pid_x": "field x (holonomic)", "pid_y": "field y (holonomic)",
             "pid_yaw": "heading (holonomic; in-place turns in differential mode)"}
_TOPIC = Check(lambda v: bool(v), "a non-empty topic name")

# (name, unit, doc) of the FollowerConfig fields; FollowerConfig checks their values.
_FOLLOWER = (
    ("mode", "", "holonomic (mecanum: x, y, yaw PIDs) or differential (tank: curvature)"),
    ("lookahead_distance", "m", "pursuit circle radius (about 12 in)"),
    ("search_window_factor", "", "targets are searched within factor x lookahead of arc length (>= 1)"),
    ("max_linear_velocity", "m/s", "speed limit"),
    ("max_angular_velocity", "rad/s", "turn rate limit"),
    ("max_linear_acceleration", "m/s²", "also shapes the braking and corner speed profile"),
    ("max_angular_acceleration", "rad/s²", "turn acceleration limit"),
    ("slowdown_distance", "m", "linear speed ramp before each stop; 0.0 = off"),
    ("min_approach_velocity", "m/s", "floor of the approach speed cap"),
    ("goal_position_tolerance", "m", "at every stop point and the end of the path"),
    ("goal_heading_tolerance", "rad", "at every stop point and the end of the path"),
    ("rotate_in_place_angle", "rad", "differential: turn in place when the target is further off the nose"),
    ("rotate_in_place_exit_angle", "rad", "differential: ... until it is within this angle"),
)

PURE_PURSUIT_PARAMETERS = Schema(NODE_NAME, "docs/pure_pursuit.md", (
    Entry("path_file", "str", "config/paths/seed000_test_path.yaml", "",
          "path YAML: absolute, or relative to the cwd, the package share directory, the source tree",
          Check(lambda v: bool(v), "a path YAML: absolute, or relative to the cwd or the package share "
                                   "directory")),
    Entry("cycles", "int", 0, "", "closed paths: repeat the loop N times; 0 = the file's value",
          at_least(0, "an integer >= 0 (0 = the file's value; > 0 only for a closed path)")),
    Entry("odom_topic", "str", "odometry/filtered", "",
          "the pose to follow (or ground_truth/odom, odometry/dead_wheels for comparisons)", _TOPIC),
    Entry("accepted_odom_frames", "str_list", [], "",
          "odometry frames accepted besides the path's (e.g. [odom] for the dead wheels)",
          Check(lambda v: all(v), "a list of non-empty frame ids accepted besides the path's frame")),
    Entry("odom_timeout", "float", 0.2, "s", "older odometry -> zero twist; also the stamp tolerance",
          positive()),
    Entry("base_link_frame", "str", "base_link", "",
          "robot body frame: the frame_id of a stamped cmd_vel (the name ekf_node and sim_node use)",
          Check(lambda v: bool(v.strip("/ ")), "a non-empty frame id")),
    Entry("stamped_cmd_vel", "bool", False, "",
          "publish cmd_vel as geometry_msgs/TwistStamped stamped at the control time (the ROS 2 Jazzy "
          "controllers' convention) instead of Twist"),
    Entry("frequency", "float", 50.0, "Hz", "control loop rate on the node clock", timer_rate()),
    Entry("publish_markers", "bool", False, "",
          "publish visualization_msgs/MarkerArray on pure_pursuit/markers: the path, the lookahead circle "
          "around the followed pose and the target point"),
    Entry("marker_frequency", "float", 5.0, "Hz", "rate of the markers (steady clock; with publish_markers)",
          timer_rate()),
    *(Entry(name, "str" if name == "mode" else "float", getattr(_D, name), unit, doc)
      for name, unit, doc in _FOLLOWER),
    *(Entry(f"{axis}.{g}", "float", getattr(getattr(_D, axis), g), unit, f"{_AXIS_DOC[axis]}: {_PID_DOCS[g]}")
      for axis in PID_AXES for g, unit in zip(_PID_FIELDS, _PID_UNITS[axis], strict=True)),
))
assert {n for n, _, _ in _FOLLOWER} == {f.name for f in fields(FollowerConfig)} - set(PID_AXES)


@dataclass(frozen=True)
class NodeSettings:
    path: FieldPath
    follower: FollowerConfig
    odom_topic: str
    frequency: float
    odom_timeout_ns: int
    accepted_frames: frozenset[str]
    stamped_cmd_vel: bool = False
    base_link_frame: str = "base_link"
    publish_markers: bool = False
    marker_frequency: float = 5.0


def _core_problem(exc: ValueError, prefix: str = "") -> Problem:
    """Core wording 'x must be ...' -> the problem of parameter ``prefix + x``: "must be ..."."""
    name, _, rest = str(exc).partition(" ")
    return Problem(prefix + name, rest)


def parse_settings(values: Mapping[str, Any]) -> NodeSettings:
    """Validate parameter values (missing ones take their defaults); raises one ParameterError."""
    parsed = PURE_PURSUIT_PARAMETERS.parse(values)
    problems = parsed.problems + PURE_PURSUIT_PARAMETERS.unknown_problems(parsed.others)
    v = parsed.values
    pids = {}
    for axis in PID_AXES:
        try:
            pids[axis] = PIDGains(**{g: v[f"{axis}.{g}"] for g in _PID_FIELDS})
        except ValueError as exc:
            problems.append(_core_problem(exc, prefix=f"{axis}."))
    follower = None
    if len(pids) == len(PID_AXES):
        try:
            follower = FollowerConfig(**{n: v[n] for n, _, _ in _FOLLOWER}, **pids)
        except ValueError as exc:
            problems.append(_core_problem(exc))
    path = None
    try:
        path = load_path(resolve_config_file(v["path_file"]), cycles=v["cycles"] or None)
    except (FileNotFoundError, PathError) as exc:
        problems.append(Problem("path_file", str(exc)))
    raise_problems(problems)
    return NodeSettings(path=path, follower=follower, odom_topic=v["odom_topic"], frequency=v["frequency"],
                        odom_timeout_ns=seconds_to_ns(v["odom_timeout"]),
                        accepted_frames=frozenset([path.frame_id, *v["accepted_odom_frames"]]),
                        stamped_cmd_vel=v["stamped_cmd_vel"],
                        base_link_frame=v["base_link_frame"].strip("/ "),
                        publish_markers=v["publish_markers"], marker_frequency=v["marker_frequency"])
