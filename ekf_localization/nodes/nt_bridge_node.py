"""nt_bridge: an FRC roboRIO's swerve module states and gyro from NetworkTables 4 -> ROS.

An NT4 client (pyntcore, an optional extra) subscribes to ``nt_module_states``
(``struct:SwerveModuleState[]``), ``nt_gyro`` and ``nt_gyro_rate``, and every
``1 / poll_frequency`` s reads their queues (every value the robot sent) and publishes
``joint_states`` (sensor_msgs/JointState, the ``joint`` input's swerve shape) and ``imu/data``
(sensor_msgs/Imu), each stamped at the ROS time of the robot's own timestamp (frc/nt_time.py).
The struct schemas are the robot's (``/.schema/struct:<Name>``), else WPILib's. Every value is
counted on /diagnostics (1 Hz): published, or refused with its reason; a configured topic the
server does not have is named there (WARN). The node never raises on a value.
Logic: ekf_localization/frc (no ROS); parameters: ros/nt_bridge_parameters.py, docs/frc_bridge.md.
"""

from __future__ import annotations

import sys
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState

from ekf_localization.core.units import ns_to_sec_nanosec
from ekf_localization.frc.nt_time import NtClock
from ekf_localization.frc.swerve_bridge import (
    REASONS,
    DtypeCache,
    Gyro,
    GyroSample,
    InputStats,
    JointSample,
    ModuleStates,
)
from ekf_localization.frc.wpilib_struct import SCHEMA_TOPIC_PREFIX, STRUCT_PREFIX, WPILIB_SCHEMAS
from ekf_localization.ros import extras
from ekf_localization.ros.due_timer import create_due_timer
from ekf_localization.ros.node_parameters import declare_unset, given_values, refuse_changes
from ekf_localization.ros.node_runner import run_node
from ekf_localization.ros.nt_bridge_parameters import NODE_NAME, NT_BRIDGE_PARAMETERS, parse_settings
from ekf_localization.ros.throttled_log import ThrottledLog

QUEUE_DEPTH = 100  # values kept per topic between two polls (NT's pollStorage)
MIN_PERIODIC_S = 0.005


def _stamp(t_ns: int) -> Time:
    sec, nanosec = ns_to_sec_nanosec(t_ns)
    return Time(sec=sec, nanosec=nanosec)


class NtBridgeNode(Node):
    """Thin adapter: ntcore subscriptions in, frc.swerve_bridge, ROS messages out."""

    def __init__(self, **kwargs: Any) -> None:
        import ntcore

        super().__init__(NODE_NAME, **kwargs)
        self.settings = s = parse_settings(given_values(self))
        declare_unset(self, NT_BRIDGE_PARAMETERS, NT_BRIDGE_PARAMETERS.defaults())
        refuse_changes(self, NT_BRIDGE_PARAMETERS)
        self._log = ThrottledLog(self.get_logger())
        self._nt_now = ntcore._now  # the NT clock of the values' local timestamps, µs
        self.clock = NtClock()
        self.dtypes = DtypeCache(WPILIB_SCHEMAS)
        self.modules = ModuleStates(s.bridge)
        self.gyro = Gyro(s.bridge)
        inst = self._inst = ntcore.NetworkTableInstance.create()
        # every value, sent on as often as the queues are read (NT's default batches 100 ms)
        opts = ntcore.PubSubOptions(pollStorage=QUEUE_DEPTH, sendAll=True, keepDuplicates=True,
                                    periodic=max(MIN_PERIODIC_S, 1.0 / s.poll_frequency))
        self._subs: list[tuple[str, Any, Any]] = []  # (input, topic, subscriber)
        for key, name in (("modules", s.nt_module_states), ("gyro", s.nt_gyro),
                          ("gyro_rate", s.nt_gyro_rate)):
            if name:
                topic = inst.getTopic(name)
                self._subs.append((key, topic, topic.genericSubscribe(opts)))
        self._schema_subs = {n: inst.getTopic(f"{SCHEMA_TOPIC_PREFIX}{STRUCT_PREFIX}{n}").genericSubscribe()
                             for n in WPILIB_SCHEMAS}
        inst.startClient4(s.client_name)
        if s.team:
            inst.setServerTeam(s.team, s.port)
        else:
            inst.setServer(s.server, s.port)
        # reliable (as joint_state_broadcaster's): best-effort subscribers such as ekf_node's match it too
        self._pub_joints = self.create_publisher(JointState, s.joint_states_topic, 10)
        self._pub_imu = self.create_publisher(Imu, s.imu_topic, 10) if s.nt_gyro else None
        self._refused_before = 0  # refused values at the last diagnostics
        self.internal_errors = 0  # polls that raised (logged; the next poll goes on)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        create_due_timer(self, 1.0 / s.poll_frequency, self._poll)
        create_due_timer(self, 1.0, self._publish_diagnostics)
        where = f"team {s.team}" if s.team else s.server
        self.get_logger().info(f"NT4 client '{s.client_name}' -> {where}:{s.port}; "
                               f"module states {s.nt_module_states}, gyro {s.nt_gyro or '(none)'}")

    def destroy_node(self) -> None:
        self._inst.stopClient()
        type(self._inst).destroy(self._inst)
        super().destroy_node()

    # --- polling -------------------------------------------------------------------------------

    def _poll(self) -> None:
        try:
            self._read_queues()
        except Exception as exc:  # noqa: BLE001 - a value never takes the node down
            self.internal_errors += 1
            self._log.warning("internal_error", f"poll failed: {type(exc).__name__}: {exc}")

    def _read_queues(self) -> None:
        before = self._nt_now()
        now_ns = self.get_clock().now().nanoseconds
        self.clock.sample(before, now_ns, self._nt_now())
        self.clock.server_offset_us = self._inst.getServerTimeOffset()
        for name, sub in self._schema_subs.items():
            value = sub.get()
            if value.isValid() and isinstance(value.value(), (bytes, bytearray)):
                self.dtypes.update(name, bytes(value.value()).decode("utf-8", "replace"))
        by_key = {key: (topic, sub) for key, topic, sub in self._subs}
        for key in ("gyro_rate", "gyro", "modules"):  # rates first: a yaw pairs with this poll's rate
            if key not in by_key:
                continue
            topic, sub = by_key[key]
            type_string = topic.getTypeString()
            for value in sub.readQueue():
                data, server_us = value.value(), value.server_time()
                stamp = self.clock.to_ros_ns(server_us)
                if key == "modules":
                    sample = self.modules.read(type_string, data, server_us, stamp, now_ns, self.dtypes)
                    if sample is not None:
                        self._pub_joints.publish(self._joint_state(sample))
                elif key == "gyro":
                    self.gyro.add_orientation(type_string, data, server_us, stamp, now_ns, self.dtypes)
                else:
                    self.gyro.add_rate(type_string, data, server_us, stamp, now_ns)
        if self._pub_imu is not None:
            for sample in self.gyro.ready(now_ns):
                self._pub_imu.publish(self._imu(sample))

    def _joint_state(self, sample: JointSample) -> JointState:
        msg = JointState()
        msg.header.stamp = _stamp(sample.stamp_ns)
        msg.name = list(sample.names)
        msg.position = sample.positions.tolist()
        msg.velocity = sample.velocities.tolist()
        return msg

    def _imu(self, sample: GyroSample) -> Imu:
        s = self.settings
        msg = Imu()
        msg.header.stamp = _stamp(sample.stamp_ns)
        msg.header.frame_id = s.imu_frame
        x, y, z, w = sample.quaternion
        msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = x, y, z, w
        tilt = s.orientation_variance if (x, y) != (0.0, 0.0) else s.unknown_variance
        cov = [0.0] * 9
        cov[0], cov[4], cov[8] = tilt, tilt, s.orientation_variance
        msg.orientation_covariance = cov
        rate = [0.0] * 9
        if sample.yaw_rate is None:
            rate[0] = -1.0  # REP-145: no angular velocity in this message
        else:
            msg.angular_velocity.z = sample.yaw_rate
            rate[0], rate[4], rate[8] = s.unknown_variance, s.unknown_variance, s.yaw_rate_variance
        msg.angular_velocity_covariance = rate
        accel = [0.0] * 9
        accel[0] = -1.0  # no acceleration from the roboRIO
        msg.linear_acceleration_covariance = accel
        return msg

    # --- diagnostics ---------------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        s = self.settings
        connected = self._inst.isConnected()
        values: dict[str, Any] = {"connected": connected, "server_offset_us": self.clock.server_offset_us,
                                  "ros_minus_nt_ns": self.clock.ros_minus_local_ns,
                                  "internal_errors": self.internal_errors}
        absent = []
        inputs: dict[str, InputStats] = {"modules": self.modules.stats, "gyro": self.gyro.stats,
                                         "gyro_rate": self.gyro.rate_stats}
        for key, topic, _sub in self._subs:
            type_string = topic.getTypeString()
            values[f"{key}_topic"] = topic.getName()
            values[f"{key}_type"] = type_string or "absent"
            if connected and not type_string:
                absent.append(topic.getName())
            stats = inputs[key]
            values[f"{key}_received"] = stats.received
            values[f"{key}_published"] = stats.published
            values[f"{key}_rejected"] = sum(stats.rejected.values())
            values.update({f"{key}_rejected_{r}": stats.rejected[r] for r in REASONS if stats.rejected[r]})
            if stats.clock_restarts:
                values[f"{key}_clock_restarts"] = stats.clock_restarts
        st = DiagnosticStatus(name=f"{self.get_name()}: NetworkTables", hardware_id="roboRIO")
        if not connected:
            where = f"team {s.team}" if s.team else s.server
            st.level = DiagnosticStatus.ERROR
            st.message = f"not connected to the NT4 server ({where}:{s.port})"
        elif absent:
            st.level, st.message = DiagnosticStatus.WARN, "no such topic on the server: " + ", ".join(absent)
        elif (refused := sum(sum(v.rejected.values()) for v in inputs.values())) > self._refused_before:
            st.level = DiagnosticStatus.WARN
            st.message = f"{refused - self._refused_before} values refused in the last second (*_rejected_*)"
        else:
            st.level, st.message = DiagnosticStatus.OK, f"{self.modules.stats.published} module states"
        self._refused_before = sum(sum(v.rejected.values()) for v in inputs.values())
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [st]
        self._pub_diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    code = extras.check(NODE_NAME, "ntcore")
    if code:
        return code
    return run_node(NODE_NAME, NtBridgeNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
