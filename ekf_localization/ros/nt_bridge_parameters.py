"""nt_bridge's parameters: the schema and its parsing into :class:`NtBridgeSettings` (no rclpy).

Every problem is collected and raised as one :class:`~ekf_localization.ros.parameters.ParameterError`
naming the parameter; the node then exits with status 2 (``ros/node_runner.py``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ekf_localization.core.units import seconds_to_ns
from ekf_localization.frc.swerve_bridge import BridgeConfig
from ekf_localization.ros.parameters import (
    Check,
    Entry,
    Problem,
    Schema,
    expected,
    non_negative,
    positive,
    raise_problems,
    timer_rate,
)

NODE_NAME = "nt_bridge"
NT4_PORT = 5810  # NetworkTables 4's default port
_TOPIC = Check(lambda v: bool(v), "a non-empty topic name")
_FRAME = Check(lambda v: bool(v.strip("/ ")), "a non-empty frame id")
_NAMES = Check(lambda v: len(v) >= 1 and all(v) and len(set(v)) == len(v),
               "a list of distinct, non-empty names")
_SCALE = Check(lambda v: math.isfinite(v) and v != 0.0, "a finite, non-zero float")

NT_BRIDGE_PARAMETERS = Schema(NODE_NAME, "docs/frc_bridge.md", (
    Entry("team", "int", 0, "",
          "FRC team number: the roboRIO at 10.TE.AM.2 (and its mDNS names); 0: use server",
          Check(lambda v: 0 <= v <= 99999, "an integer from 0 to 99999")),
    Entry("server", "str", "", "",
          "NT4 server host or address when team is 0 (e.g. 127.0.0.1 for a simulated robot)"),
    Entry("port", "int", NT4_PORT, "", "the server's NT4 port",
          Check(lambda v: 1 <= v <= 65535, "an integer from 1 to 65535")),
    Entry("client_name", "str", "ekf_nt_bridge", "", "this client's identity on the server", _TOPIC),
    Entry("nt_module_states", "str", "", "",
          "NT topic of the measured module states, struct:SwerveModuleState[] (e.g. AdvantageKit's "
          "/AdvantageKit/RealOutputs/SwerveStates/Measured)", _TOPIC, default_doc="**required**"),
    Entry("module_names", "str_list", ["front_left", "front_right", "back_left", "back_right"], "",
          "the modules in the array's order; joints <module><steer_suffix> and <module><drive_suffix>",
          _NAMES),
    Entry("steer_suffix", "str", "_steer", "", "steer joint name after the module's", _TOPIC),
    Entry("drive_suffix", "str", "_drive", "", "drive joint name after the module's", _TOPIC),
    Entry("wheel_radius", "float", 0.0508, "m",
          "wheel radius: speed m/s -> drive joint rad/s (the EKF's jointN_wheel_radius)", positive()),
    Entry("nt_gyro", "str", "", "",
          "NT topic of the gyro's yaw (double or float times gyro_scale, struct:Rotation2d) or orientation "
          "(struct:Rotation3d); empty: no Imu"),
    Entry("gyro_scale", "float", 1.0, "rad/unit",
          "a double/float yaw's radians per unit, counter-clockwise positive (-π/180 for clockwise degrees)",
          _SCALE),
    Entry("nt_gyro_rate", "str", "", "",
          "NT topic of the yaw rate (double or float times gyro_rate_scale); empty: Imu without rate"),
    Entry("gyro_rate_scale", "float", 1.0, "(rad/s)/unit",
          "a yaw rate's rad/s per unit, counter-clockwise positive", _SCALE),
    Entry("pair_window", "float", 0.02, "s",
          "a yaw waits this long for the rate sample stamped within as long of it", non_negative()),
    Entry("joint_states_topic", "str", "joint_states", "", "sensor_msgs/JointState out", _TOPIC),
    Entry("imu_topic", "str", "imu/data", "", "sensor_msgs/Imu out", _TOPIC),
    Entry("imu_frame", "str", "base_link", "", "the Imu's frame_id (the gyro's mounting)", _FRAME),
    Entry("orientation_variance", "float", 1e-4, "rad²",
          "yaw variance in the Imu (roll and pitch too for a Rotation3d; else theirs is unknown_variance)",
          positive()),
    Entry("unknown_variance", "float", 1e6, "rad²", "variance of a roll and pitch the gyro does not give",
          positive()),
    Entry("yaw_rate_variance", "float", 1e-4, "(rad/s)²", "yaw-rate variance in the Imu", positive()),
    Entry("max_age", "float", 0.5, "s", "values older than this when they arrive are refused (stale)",
          positive()),
    Entry("max_future", "float", 0.05, "s", "values stamped further ahead of the ROS time are refused",
          non_negative()),
    Entry("poll_frequency", "float", 200.0, "Hz", "how often the NT queues are read", timer_rate()),
))


@dataclass(frozen=True)
class NtBridgeSettings:
    team: int
    server: str
    port: int
    client_name: str
    nt_module_states: str
    nt_gyro: str
    nt_gyro_rate: str
    joint_states_topic: str
    imu_topic: str
    imu_frame: str
    orientation_variance: float
    unknown_variance: float
    yaw_rate_variance: float
    poll_frequency: float
    bridge: BridgeConfig


def parse_settings(values: Mapping[str, Any]) -> NtBridgeSettings:
    """Validate parameter values (missing ones take their defaults); raises one ParameterError."""
    parsed = NT_BRIDGE_PARAMETERS.parse(values)
    problems = parsed.problems + NT_BRIDGE_PARAMETERS.unknown_problems(parsed.others)
    v = parsed.values
    if not v["nt_module_states"] and "nt_module_states" not in parsed.given:
        problems.append(expected("nt_module_states", "the NT topic of the module states (it is required)"))
    if v["team"] == 0 and not v["server"].strip():
        problems.append(Problem("team", "set team (the roboRIO) or server (a host), not neither"))
    if v["nt_gyro_rate"] and not v["nt_gyro"]:
        problems.append(Problem("nt_gyro_rate", "a yaw rate needs nt_gyro (the Imu's yaw)"))
    if v["steer_suffix"] == v["drive_suffix"]:
        problems.append(Problem("drive_suffix", "must differ from steer_suffix (the joints' names)"))
    raise_problems(problems)
    bridge = BridgeConfig(
        module_names=tuple(v["module_names"]), wheel_radius=v["wheel_radius"],
        steer_suffix=v["steer_suffix"], drive_suffix=v["drive_suffix"],
        max_age_ns=seconds_to_ns(v["max_age"]), max_future_ns=seconds_to_ns(v["max_future"]),
        gyro_scale=v["gyro_scale"], gyro_rate_scale=v["gyro_rate_scale"],
        pair_window_ns=seconds_to_ns(v["pair_window"]), has_rate=bool(v["nt_gyro_rate"]))
    return NtBridgeSettings(
        team=v["team"], server=v["server"].strip(), port=v["port"], client_name=v["client_name"],
        nt_module_states=v["nt_module_states"], nt_gyro=v["nt_gyro"],
        nt_gyro_rate=v["nt_gyro_rate"], joint_states_topic=v["joint_states_topic"],
        imu_topic=v["imu_topic"], imu_frame=v["imu_frame"].strip("/ "),
        orientation_variance=v["orientation_variance"], unknown_variance=v["unknown_variance"],
        yaw_rate_variance=v["yaw_rate_variance"], poll_frequency=v["poll_frequency"], bridge=bridge)
