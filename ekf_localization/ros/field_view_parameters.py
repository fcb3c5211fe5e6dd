"""field_view's parameters: the schema and :class:`FieldViewSettings` (no rclpy).

docs/field_view.md's table is rendered from :data:`FIELD_VIEW_PARAMETERS`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ekf_localization.ros.parameters import (
    Check,
    Entry,
    Schema,
    at_least,
    non_empty,
    positive,
    raise_problems,
    timer_rate,
)

NODE_NAME = "field_view"
_TOPIC = non_empty("a non-empty topic name")

FIELD_VIEW_PARAMETERS = Schema(NODE_NAME, "docs/field_view.md", (
    Entry("host", "str", "127.0.0.1", "", "address the page is served on (127.0.0.1: this machine only)",
          non_empty("an address, e.g. 127.0.0.1")),
    Entry("port", "int", 8765, "", "TCP port of the page and its WebSocket (0 = any free port)",
          Check(lambda v: 0 <= v <= 65535, "a port number from 0 to 65535")),
    Entry("rate", "float", 20.0, "Hz", "how often the state is pushed to each page", timer_rate()),
    Entry("sim_params_file", "str", "config/sim.yaml", "",
          "sim_node's parameter YAML whose field (preset, wall images, ramp) is drawn: absolute, or relative "
          "to the cwd, the package share directory, the source tree", non_empty("a path to a YAML file")),
    Entry("odom_topic", "str", "odometry/filtered", "", "the estimate (nav_msgs/Odometry) and its covariance",
          _TOPIC),
    Entry("ground_truth_topic", "str", "ground_truth/odom", "", "the simulator's truth (drawn when present)",
          _TOPIC),
    Entry("ekf_node_name", "str", "ekf_node", "",
          "the ekf_node whose markers (camera fixes), diagnostics, set_pose and reset the page uses",
          non_empty("a node name")),
    Entry("history", "float", 30.0, "s", "span of the plots (position error, NIS per input)", positive()),
    Entry("set_pose_position_variance", "float", 0.0025, "m²", "x and y variance of a set_pose from the page",
          positive()),
    Entry("set_pose_yaw_variance", "float", 0.01, "rad²", "yaw variance of a set_pose from the page",
          positive()),
    Entry("max_clients", "int", 8, "", "pages served at once (more are refused)",
          at_least(1, "an integer >= 1")),
))


@dataclass(frozen=True)
class FieldViewSettings:
    host: str
    port: int
    rate: float
    sim_params_file: str
    odom_topic: str
    ground_truth_topic: str
    ekf_node_name: str
    history: float
    set_pose_position_variance: float
    set_pose_yaw_variance: float
    max_clients: int


def parse_field_view_settings(values: Mapping[str, Any]) -> FieldViewSettings:
    """Validate parameter values (missing ones take their defaults); raises one ParameterError."""
    parsed = FIELD_VIEW_PARAMETERS.parse(values)
    raise_problems(parsed.problems + FIELD_VIEW_PARAMETERS.unknown_problems(parsed.others))
    v = parsed.values
    v["ekf_node_name"] = v["ekf_node_name"].strip("/ ")
    return FieldViewSettings(**v)
