"""The FRC bridge's logic without ROS or ntcore: WPILib struct decoding, NT4 time -> ROS time, module
states -> swerve joint states, gyro values -> Imu samples, and every bad value counted."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from ekf_localization.core.angles import quaternion_to_rpy
from ekf_localization.core.units import NS_PER_S
from ekf_localization.frc import swerve_bridge as sb
from ekf_localization.frc.nt_time import NtClock
from ekf_localization.frc.wpilib_struct import (
    WPILIB_SCHEMAS,
    StructError,
    decode,
    float_field,
    struct_dtype,
    struct_name,
)
from ekf_localization.ros.nt_bridge_parameters import parse_settings
from ekf_localization.ros.parameters import ParameterError

MS = NS_PER_S // 1000
STATES = "struct:SwerveModuleState[]"


def pack_states(*pairs: tuple[float, float]) -> bytes:
    """SwerveModuleState[] as the spec packs it: per state <speed double><angle double>, little-endian."""
    return b"".join(struct.pack("<dd", s, a) for s, a in pairs)


# --- WPILib structs ---------------------------------------------------------------------------------


def test_module_states_decode_by_the_schema() -> None:
    dt = struct_dtype("SwerveModuleState", WPILIB_SCHEMAS)
    assert dt.itemsize == 16 and dt.names == ("speed", "angle")
    states = decode(pack_states((1.5, 0.25), (-2.0, -3.0)), dt)
    assert float_field(states, "speed").tolist() == [1.5, -2.0]
    assert float_field(states, "angle.value").tolist() == [0.25, -3.0]


def test_the_schema_parser_reads_the_specs_forms() -> None:
    schemas = {"Inner": "int16 i; int8 x", "Outer": " char c;Inner s; bool b;;",
               "Arr": "double a[ 3 ];char name[4]", "E": "enum {a=1, b=2} int8 val; float32 f;"}
    outer = struct_dtype("Outer", schemas)
    assert outer.itemsize == 5  # the spec's example: no padding around the nested struct
    raw = b"c" + struct.pack("<hb", -300, 7) + b"\x01"
    v = decode(raw, outer)[0]
    assert (v["c"], int(v["s"]["i"]), int(v["s"]["x"]), bool(v["b"])) == (b"c", -300, 7, True)
    arr = struct_dtype("Arr", schemas)
    assert arr.itemsize == 28 and arr["name"] == np.dtype("S4")
    assert struct_dtype("E", schemas).itemsize == 5
    for bad, text in [({"B": "int8 a:2"}, "bit-field"), ({"B": "Missing m"}, "no schema"),
                      ({"B": "double"}, "cannot read"), ({"B": ""}, "empty"), ({"B": "B b"}, "nested"),
                      ({"B": "double a;double a"}, "B")]:
        with pytest.raises(StructError, match=text):
            struct_dtype("B", bad)


def test_type_strings_and_sizes() -> None:
    assert struct_name(STATES) == ("SwerveModuleState", True)
    assert struct_name("struct:Rotation2d") == ("Rotation2d", False)
    assert struct_name("double") is None
    dt = struct_dtype("SwerveModuleState", WPILIB_SCHEMAS)
    with pytest.raises(StructError, match="whole number"):
        decode(b"\0" * 17, dt)
    with pytest.raises(StructError, match="no member 'angle.value'"):
        float_field(decode(b"\0" * 16, struct_dtype("P", {"P": "double speed;double angle"})), "angle.value")


# --- NT4 time -> ROS time ---------------------------------------------------------------------------


def test_server_time_becomes_ros_time_through_both_offsets() -> None:
    clock = NtClock()
    assert clock.to_ros_ns(5) is None  # before the time sync
    # the roboRIO's clock is 1000 s ahead of the local NT clock; ROS time is 1.7e9 s ahead of that
    clock.server_offset_us = 1_000_000_000
    clock.sample(2_000_000, 1_700_000_002 * NS_PER_S, 2_000_010)  # bracket of 10 µs, ROS read in the middle
    assert clock.bracket_us == 10
    assert clock.ros_minus_local_ns == 1_700_000_002 * NS_PER_S - 2_000_005_000
    # a value the robot stamped 1002.0 s into its clock (= local 2.0 s) is ROS 1.7e9 + 2 s - 5 µs
    assert clock.to_ros_ns(1_002_000_000) == 1_700_000_002 * NS_PER_S - 5_000
    clock.server_offset_us = -3  # the server 3 µs behind: the same server time is 3 µs later locally
    assert clock.to_ros_ns(1_002_000_000) - clock.to_ros_ns(1_001_999_999) == 1000
    assert clock.to_ros_ns(0) == (0 + 3) * 1000 + clock.ros_minus_local_ns


# --- module states -> joint states ------------------------------------------------------------------


def robot(stamp_ns: int) -> int:
    """The robot's timestamp (µs, its own clock: 1000 s ahead) of a value stamped ``stamp_ns`` in ROS time."""
    return stamp_ns // 1000 + 1_000_000_000


def _config(**kw) -> sb.BridgeConfig:
    return sb.BridgeConfig(module_names=("fl", "fr", "bl", "br"), wheel_radius=0.05, **kw)


def test_module_states_become_the_swerve_joint_shape() -> None:
    cfg, dtypes = _config(), sb.DtypeCache(WPILIB_SCHEMAS)
    ms = sb.ModuleStates(cfg)
    now = 100 * NS_PER_S
    first = pack_states((1.0, 0.5), (-0.5, 3.1), (0.0, -0.2), (2.0, 0.0))
    s1 = ms.read(STATES, first, robot(now - 40 * MS), now - 40 * MS, now, dtypes)
    assert s1 is not None and s1.stamp_ns == now - 40 * MS
    assert s1.names == ("fl_steer", "fl_drive", "fr_steer", "fr_drive", "bl_steer", "bl_drive",
                        "br_steer", "br_drive")
    np.testing.assert_allclose(s1.positions[0::2], [0.5, 3.1, -0.2, 0.0])  # steer: the angles
    np.testing.assert_allclose(s1.velocities[1::2], [20.0, -10.0, 0.0, 40.0])  # drive: speed / r
    assert np.all(s1.positions[1::2] == 0.0) and np.all(s1.velocities[0::2] == 0.0)  # first: no interval
    # 20 ms later: the steer rates are the wrapped angle changes (3.1 -> -3.1 is +0.083 rad, not -6.2)
    s2 = ms.read(STATES, pack_states((1.0, 0.6), (-0.5, -3.1), (1.0, -0.2), (2.0, 0.0)),
                 robot(now - 20 * MS), now - 20 * MS + 3_000, now + MS, dtypes)  # the ROS stamps jitter
    dt = 0.02
    np.testing.assert_allclose(s2.velocities[0::2], [0.1 / dt, (2 * math.pi - 6.2) / dt, 0.0, 0.0], rtol=1e-9)
    # the drive positions: the wheel rates integrated over the robot's interval (trapezoid)
    np.testing.assert_allclose(s2.positions[1::2], [20 * dt, -10 * dt, 0.5 * (0 + 20) * dt, 40 * dt])
    assert ms.stats.published == 2 and not ms.stats.rejected


@pytest.mark.parametrize(("type_string", "value", "stamp_offset_ms", "reason"), [
    (STATES, pack_states((1.0, 0.0)) * 3, -10, sb.WRONG_LENGTH),
    (STATES, pack_states((1.0, 0.0)) * 5, -10, sb.WRONG_LENGTH),
    (STATES, pack_states((math.nan, 0.0)) + pack_states((1.0, 0.0)) * 3, -10, sb.NONFINITE),
    (STATES, pack_states((1.0, math.inf)) * 4, -10, sb.NONFINITE),
    (STATES, b"\0" * 17, -10, sb.BAD_STRUCT),
    ("struct:SwerveModulePosition[]", pack_states((1.0, 0.0)) * 4, -10, sb.WRONG_TYPE),
    ("double[]", [1.0] * 8, -10, sb.WRONG_TYPE),
    (STATES, pack_states((1.0, 0.0)) * 4, None, sb.NO_TIME_SYNC),
    (STATES, pack_states((1.0, 0.0)) * 4, -600, sb.STALE),
    (STATES, pack_states((1.0, 0.0)) * 4, 60, sb.IN_FUTURE),
])
def test_bad_module_states_are_counted_with_their_reason(type_string, value, stamp_offset_ms, reason) -> None:
    ms, now = sb.ModuleStates(_config()), 100 * NS_PER_S
    stamp = None if stamp_offset_ms is None else now + stamp_offset_ms * MS
    assert ms.read(type_string, value, robot(now - MS), stamp, now, sb.DtypeCache(WPILIB_SCHEMAS)) is None
    assert ms.stats.rejected == {reason: 1} and ms.stats.received == 1 and ms.stats.published == 0
    # and the next good value is published
    good = pack_states((1.0, 0.0)) * 4
    assert ms.read(STATES, good, robot(now), now, now, sb.DtypeCache(WPILIB_SCHEMAS)) is not None


def test_a_repeated_stamp_and_the_robots_own_schema() -> None:
    ms, now = sb.ModuleStates(_config()), 100 * NS_PER_S
    dtypes = sb.DtypeCache(WPILIB_SCHEMAS)
    good = pack_states((1.0, 0.0)) * 4
    assert ms.read(STATES, good, robot(now), now, now, dtypes) is not None
    assert ms.read(STATES, good, robot(now), now + 1, now, dtypes) is None  # the robot's stamp repeats
    assert ms.stats.rejected == {sb.STAMP_NOT_INCREASING: 1}
    # a robot whose schema has no angle.value: refused as bad_struct, not misread
    dtypes.update("SwerveModuleState", "double speed;double angle")
    assert ms.read(STATES, good, robot(now + MS), now + MS, now + MS, dtypes) is None
    assert ms.stats.rejected[sb.BAD_STRUCT] == 1


def test_a_rebooted_robot_clock_is_followed() -> None:
    """A roboRIO that reboots starts its clock again: its values are fresh in ROS time but far
    behind the last robot timestamp. They are taken (counted as a restart), with no interval across."""
    ms, now, dtypes = sb.ModuleStates(_config()), 100 * NS_PER_S, sb.DtypeCache(WPILIB_SCHEMAS)
    moving = pack_states((1.0, 0.0)) * 4
    assert ms.read(STATES, moving, 900_000_000, now, now, dtypes) is not None
    assert ms.read(STATES, moving, 900_020_000, now + 20 * MS, now + 20 * MS, dtypes) is not None
    # a value 0.1 s behind the last: a repeat, refused; 10 s into a new clock: a restart
    assert ms.read(STATES, moving, 899_920_000, now + 30 * MS, now + 30 * MS, dtypes) is None
    s = ms.read(STATES, moving, 10_000_000, now + 5 * NS_PER_S, now + 5 * NS_PER_S, dtypes)
    assert s is not None and ms.stats.clock_restarts == 1
    assert np.all(s.velocities[0::2] == 0.0)  # no steer rate across the restart
    np.testing.assert_allclose(s.positions[1::2], 20.0 * 0.02)  # the drive positions go on from there
    assert ms.stats.rejected == {sb.STAMP_NOT_INCREASING: 1}


# --- gyro -> Imu samples ----------------------------------------------------------------------------


def test_gyro_yaw_pairs_with_its_rate_or_goes_alone_after_the_window() -> None:
    cfg = _config(has_rate=True, gyro_rate_scale=math.pi / 180)
    gyro, dtypes, now = sb.Gyro(cfg), sb.DtypeCache(WPILIB_SCHEMAS), 100 * NS_PER_S
    yaw = struct.pack("<d", 0.75)
    gyro.add_orientation("struct:Rotation2d", yaw, robot(now - 30 * MS), now - 30 * MS, now, dtypes)
    assert gyro.ready(now) == []  # waits for its rate
    gyro.add_rate("double", 90.0, robot(now - 29 * MS), now - 29 * MS, now + MS)
    (s,) = gyro.ready(now + MS)
    assert s.stamp_ns == now - 30 * MS and s.yaw_rate == pytest.approx(math.pi / 2)
    assert quaternion_to_rpy(*s.quaternion)[2] == pytest.approx(0.75)
    gyro.add_orientation("struct:Rotation2d", struct.pack("<d", 0.8), robot(now), now, now + 2 * MS, dtypes)
    assert gyro.ready(now + 21 * MS) == []
    (s,) = gyro.ready(now + 22 * MS)  # no rate within 20 ms: published without one
    assert s.yaw_rate is None and gyro.stats.published == 2


def test_gyro_types_and_bad_values() -> None:
    cfg = _config(gyro_scale=-math.pi / 180)  # clockwise degrees (a NavX's getAngle)
    gyro, dtypes, now = sb.Gyro(cfg), sb.DtypeCache(WPILIB_SCHEMAS), 100 * NS_PER_S
    q, reason = gyro.orientation("double", 90.0, dtypes)
    assert reason is None and quaternion_to_rpy(*q)[2] == pytest.approx(-math.pi / 2)
    # Rotation3d: a quaternion (w, x, y, z), normalised
    r3 = struct.pack("<4d", 2 * math.cos(0.2), 0.0, 0.0, 2 * math.sin(0.2))
    q, reason = gyro.orientation("struct:Rotation3d", r3, dtypes)
    assert reason is None and quaternion_to_rpy(*q)[2] == pytest.approx(0.4)
    for type_string, value, why in [("double", math.nan, sb.NONFINITE), ("string", "x", sb.WRONG_TYPE),
                                    ("struct:Rotation2d", b"\0" * 7, sb.BAD_STRUCT),
                                    ("struct:Rotation2d", b"\0" * 16, sb.BAD_STRUCT),
                                    ("struct:Rotation3d", b"\0" * 32, sb.BAD_STRUCT),
                                    ("struct:Rotation3d", struct.pack("<4d", math.inf, 0, 0, 0),
                                     sb.NONFINITE),
                                    ("boolean", True, sb.WRONG_TYPE)]:
        gyro.add_orientation(type_string, value, robot(now), now, now, dtypes)
        assert gyro.stats.rejected[why] >= 1, (type_string, value)
    gyro.add_rate("double", math.inf, robot(now), now, now)
    gyro.add_rate("struct:Rotation2d", b"\0" * 8, robot(now), now, now)
    assert gyro.rate_stats.rejected == {sb.NONFINITE: 1, sb.WRONG_TYPE: 1}
    assert gyro.ready(now) == []


# --- parameters -------------------------------------------------------------------------------------


def test_the_shipped_yaml_parses() -> None:
    from helpers.ros_helpers import REPO

    from ekf_localization.ros.parameters import read_parameter_yaml

    (body,) = read_parameter_yaml(REPO / "config" / "nt_bridge.yaml").values()
    s = parse_settings(body["ros__parameters"])
    assert s.server == "127.0.0.1" and s.nt_module_states.endswith("SwerveStates/Measured")
    assert s.bridge.wheel_radius == 0.0508 and s.nt_gyro == ""


def test_parameters_name_each_problem() -> None:
    s = parse_settings({"server": "127.0.0.1", "nt_module_states": "/Drive/States"})
    assert s.bridge.module_names == ("front_left", "front_right", "back_left", "back_right")
    assert s.port == 5810 and s.bridge.has_rate is False
    with pytest.raises(ParameterError) as err:
        parse_settings({"nt_gyro_rate": "/r", "wheel_radius": -1.0, "drive_suffix": "_steer",
                        "module_names": ["a", "a"]})
    text = str(err.value)
    for name in ("nt_module_states", "team", "nt_gyro_rate", "wheel_radius", "drive_suffix",
                 "module_names"):
        assert name in text, (name, text)
