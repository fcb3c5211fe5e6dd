"""nt_bridge over a real NetworkTables 4 connection and real DDS: an NT4 server in this process plays
the roboRIO (module states as WPILib's struct:SwerveModuleState[], the gyro's Rotation2d yaw and its
rate as a double, each value stamped 40 ms before it is sent), nt_bridge runs as a process, and the
test reads its JointState, Imu and /diagnostics.

The stamps must be the robot's (40 ms before sending, in ROS time), not the arrival's; bad values
(wrong array length, NaN, a cut-off struct) and a topic the server lacks are counted on /diagnostics,
and the node goes on."""

from __future__ import annotations

import math
import socket
import struct
import time

import numpy as np
import pytest
from helpers.ros_helpers import Diagnostics, node_command, running_process

from ekf_localization.core.angles import quaternion_to_rpy
from ekf_localization.core.units import stamp_to_ns

ntcore = pytest.importorskip("ntcore", reason="pyntcore (requirements.txt) is not installed")

pytestmark = pytest.mark.ros

STATES_TOPIC, YAW_TOPIC, RATE_TOPIC = "/Drive/ModuleStates", "/Drive/Gyro/Yaw", "/Drive/Gyro/YawRate"
MODULES = ("fl", "fr", "bl", "br")
WHEEL_RADIUS = 0.05
AGE_US = 40_000  # the robot stamps each value this long before it sends it
STAMP_TOLERANCE_NS = 5_000_000  # NT4's time sync over loopback, and the ROS/NT clock pairing
SAMPLES = 25
STATUS = "nt_bridge: NetworkTables"


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _states(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Sample k's speeds (m/s) and angles (rad); the fr module crosses ±π at k = 10."""
    speeds = np.array([1.0, -0.5, 0.25, 2.0]) + 0.01 * k
    angles = np.array([0.1 + 0.02 * k, 3.0 + 0.02 * k, -0.2, -1.0])
    return speeds, (angles + math.pi) % (2 * math.pi) - math.pi


def _pack(speeds, angles) -> bytes:
    return b"".join(struct.pack("<dd", s, a) for s, a in zip(speeds, angles, strict=True))


class Robot:
    """The roboRIO's NT4 server with its publishers (WPILib's schemas announced as a robot does)."""

    def __init__(self, port4: int, port3: int, persist) -> None:
        self.port4 = port4
        self.inst = ntcore.NetworkTableInstance.create()
        self.inst.startServer(str(persist), "127.0.0.1", port3, port4)
        self.inst.addSchema("struct:Rotation2d", "structschema", b"double value")
        self.inst.addSchema("struct:SwerveModuleState", "structschema", b"double speed;Rotation2d angle")
        opts = ntcore.PubSubOptions(keepDuplicates=True, sendAll=True)
        self.states = self.inst.getRawTopic(STATES_TOPIC).publish("struct:SwerveModuleState[]", opts)
        self.yaw = self.inst.getRawTopic(YAW_TOPIC).publish("struct:Rotation2d", opts)
        self.rate = None
        self._opts = opts

    def add_rate_topic(self) -> None:
        self.rate = self.inst.getDoubleTopic(RATE_TOPIC).publish(self._opts)

    def send(self, states: bytes | None = None, yaw: float | None = None,
             rate: float | None = None) -> tuple[int, int]:
        """Publish at NT time now - AGE_US and flush: (the ROS (system) time it corresponds to, ns;
        the robot's timestamp, µs)."""
        wall_ns = time.time_ns()
        t = ntcore._now() - AGE_US
        if states is not None:
            self.states.set(states, t)
        if yaw is not None:
            self.yaw.set(struct.pack("<d", yaw), t)
        if rate is not None:
            self.rate.set(rate, t)
        self.inst.flush()
        return wall_ns - AGE_US * 1000, t

    def close(self) -> None:
        self.inst.stopServer()
        ntcore.NetworkTableInstance.destroy(self.inst)


@pytest.fixture
def robot(tmp_path):
    r = Robot(*_free_ports(2), tmp_path / "networktables.json")
    yield r
    r.close()


def test_nt_bridge_publishes_the_robots_states_at_the_robots_stamps(ros_context, robot, tmp_path) -> None:
    from sensor_msgs.msg import Imu, JointState

    diag = Diagnostics(ros_context)
    joints: list = []
    imus: list = []
    diag.node.create_subscription(JointState, "joint_states", joints.append, 100)
    diag.node.create_subscription(Imu, "imu/data", imus.append, 100)
    cmd = node_command("nt_bridge") + [
        "--ros-args", "-p", "server:=127.0.0.1", "-p", f"port:={robot.port4}",
        "-p", f"nt_module_states:={STATES_TOPIC}", "-p", f"nt_gyro:={YAW_TOPIC}",
        "-p", f"nt_gyro_rate:={RATE_TOPIC}", "-p", f"wheel_radius:={WHEEL_RADIUS}",
        "-p", f"module_names:=[{', '.join(MODULES)}]"]
    try:
        with running_process(cmd, tmp_path / "nt_bridge.log") as proc:
            # connected and time-synchronised; the rate topic is not on the server yet: named (WARN)
            assert diag.spin_until(lambda: diag.get(STATUS, "connected") == "True"
                                   and diag.get(STATUS, "server_offset_us") not in ("", "None")
                                   and RATE_TOPIC in diag.get(STATUS, "_message"), 30.0), \
                (diag.latest, (tmp_path / "nt_bridge.log").read_text())
            assert diag.get(STATUS, "_level") == b"\x01" and diag.get(STATUS, "gyro_rate_type") == "absent"
            robot.add_rate_topic()
            assert diag.spin_until(lambda: diag.get(STATUS, "gyro_rate_type") == "double"
                                   and diag.get(STATUS, "_level") == b"\x00", 10.0), diag.latest

            sent = []
            for k in range(SAMPLES):
                speeds, angles = _states(k)
                sent.append(robot.send(_pack(speeds, angles), yaw=0.3 + 0.01 * k, rate=0.5 + 0.01 * k))
                diag.spin_for(0.02)
            assert diag.spin_until(lambda: len(joints) >= SAMPLES and len(imus) >= SAMPLES, 10.0), \
                (len(joints), len(imus))
            _check_joints(joints[:SAMPLES], sent)
            _check_imus(imus[:SAMPLES], sent)

            # bad values: counted with their reasons, and the next good one is published
            speeds, angles = _states(SAMPLES)
            diag.spin_for(0.02)
            robot.send(_pack(speeds[:3], angles[:3]))
            diag.spin_for(0.02)
            robot.send(_pack([math.nan, *speeds[1:]], angles))
            diag.spin_for(0.02)
            robot.send(b"\0" * 17)
            diag.spin_for(0.02)
            good, _ = robot.send(_pack(speeds, angles))
            keys = [f"modules_rejected_{r}" for r in ("wrong_length", "nonfinite", "bad_struct")]
            assert diag.spin_until(lambda: all(diag.get(STATUS, k) == "1" for k in keys), 10.0), diag.latest
            assert diag.spin_until(lambda: len(joints) == SAMPLES + 1, 5.0), len(joints)
            assert abs(stamp_to_ns(joints[-1].header.stamp) - good) < STAMP_TOLERANCE_NS
            assert diag.get(STATUS, "modules_published") == str(SAMPLES + 1)
            assert diag.get(STATUS, "internal_errors") == "0"
            assert proc.poll() is None, (tmp_path / "nt_bridge.log").read_text()
    finally:
        diag.close()


def _check_joints(msgs: list, sent: list[tuple[int, int]]) -> None:
    """Stamps, names, angles and wheel rates; the steer rates and drive positions over the robot's
    own intervals (the ROS stamps carry the clock pairing's jitter of some µs)."""
    names = [f"{m}{s}" for m in MODULES for s in ("_steer", "_drive")]
    drive = np.zeros(len(MODULES))
    for k, (msg, (expected_ns, robot_us)) in enumerate(zip(msgs, sent, strict=True)):
        assert list(msg.name) == names
        stamp = stamp_to_ns(msg.header.stamp)
        assert abs(stamp - expected_ns) < STAMP_TOLERANCE_NS, (k, (stamp - expected_ns) / 1e6)
        speeds, angles = _states(k)
        np.testing.assert_allclose(msg.position[0::2], angles, atol=1e-12)
        np.testing.assert_allclose(msg.velocity[1::2], speeds / WHEEL_RADIUS, rtol=1e-12)
        if k:
            dt = (robot_us - sent[k - 1][1]) / 1e6
            turned = (angles - _states(k - 1)[1] + math.pi) % (2 * math.pi) - math.pi  # fr wraps: +0.02
            np.testing.assert_allclose(msg.velocity[0::2], turned / dt, rtol=1e-9, atol=1e-12)
            drive += 0.5 * (speeds + _states(k - 1)[0]) / WHEEL_RADIUS * dt
        np.testing.assert_allclose(msg.position[1::2], drive, rtol=1e-9, atol=1e-12)


def _check_imus(msgs: list, sent: list[tuple[int, int]]) -> None:
    for k, (msg, (expected_ns, _)) in enumerate(zip(msgs, sent, strict=True)):
        assert abs(stamp_to_ns(msg.header.stamp) - expected_ns) < STAMP_TOLERANCE_NS
        q = msg.orientation
        assert quaternion_to_rpy(q.x, q.y, q.z, q.w)[2] == pytest.approx(0.3 + 0.01 * k, abs=1e-12)
        assert msg.angular_velocity.z == pytest.approx(0.5 + 0.01 * k, abs=1e-12)
        assert msg.header.frame_id == "base_link" and msg.linear_acceleration_covariance[0] == -1.0
        assert msg.angular_velocity_covariance[8] > 0 and msg.orientation_covariance[8] > 0

