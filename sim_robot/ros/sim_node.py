"""sim_node: the simulated robot on ROS 2 (a thin adapter around ``sim_robot.world.world.World``).

Subscribes ``cmd_vel`` (geometry_msgs/Twist or TwistStamped; a command acts from its stamp plus
``cmd_vel_latency``, as a drive with that response time would, the receipt time for a Twist;
``cmd_vel_late`` in diagnostics counts those that arrived after that and acted at once);
publishes ``odometry/dead_wheels``
(nav_msgs/Odometry, odom -> base_link), with ``dead_wheels.publish_joint_states`` also
``joint_states`` (sensor_msgs/JointState, the encoder positions in rad; with
``wheel_encoders.publish_joint_states`` instead the drive's own wheels, quantised, at jittered
intervals), ``camera/pose``
(PoseWithCovarianceStamped, map, stamped at capture time and published after the latency),
``imu/data`` (sensor_msgs/Imu, base_link), with ``camera_images.enabled`` ``camera/image_raw``
(sensor_msgs/Image, mono8, the layout's AprilTags as the camera sees them) and
``camera/camera_info`` (sensor_msgs/CameraInfo), both stamped at capture time (mid-exposure)
and published after ``camera_images.latency``, plus the static TF base_link -> the camera's
optical frame on /tf_static; with ``camera1.enabled`` a second camera at its own mount does the
same on ``camera1/pose``, ``camera1/image_raw`` and ``camera1/camera_info`` (its own frame, both
static transforms in one /tf_static message), ``ground_truth/odom`` (nav_msgs/Odometry,
map -> base_link), TF odom -> base_link from the dead-wheel odometry (``publish_odom_tf``, as
a drive controller does), ``/clock`` when ``publish_clock`` is true, and ``/diagnostics`` once
a second. All parameters come from config/sim.yaml (``sim_robot.ros.sim_params``; a bad value
exits with status 2 at start-up naming the parameter). Details in docs/simulator.md.

Time: with ``publish_clock`` the stamps are sim time (0 at start, published on /clock
before the readings of each batch, so other nodes must set use_sim_time); without it the
sim runs at real time and stamps are the wall time when simulated time starts plus the sim
clock. The physics runs in batches on a steady-clock timer, ``real_time_factor`` sim seconds
per wall second; 0.0 runs as fast as possible (a batch per spin). A stall (the process
stopped, the CPU starved) of more than 100 ms: on sim time the sim slows down (everyone
follows /clock); at real time it drops the missed ticks (the robot is frozen through the
stall, as the process was) so that its stamps are the wall time again, and says so in a
warning and in diagnostics (``dropped_ticks``, ``dropped_s``).
"""

from __future__ import annotations

import math
import sys
import time
from collections import deque
from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import Imu, JointState

from ekf_localization.core.units import NS_PER_S, ns_to_seconds, stamp_to_ns
from ekf_localization.ros.node_parameters import declare_unset, given_values, refuse_changes
from ekf_localization.ros.node_runner import run_node, running, spin_forever
from ekf_localization.ros.tf_io import TfBroadcaster
from ekf_localization.ros.throttled_log import ThrottledLog
from sim_robot.ros import sim_messages as msgs
from sim_robot.ros.sim_params import SIM_PARAMETERS, parse_parameters
from sim_robot.world.camera_image_sensor import CameraImageSensor, ImageReading
from sim_robot.world.camera_sensor import CameraReading
from sim_robot.world.dead_wheel_sensor import DeadWheelReading
from sim_robot.world.imu_sensor import ImuReading
from sim_robot.world.wheel_encoder_sensor import WheelEncoderReading
from sim_robot.world.world import TruthReading, World

_MAX_BATCH_NS = 100_000_000  # at most 100 ms of sim time per timer callback
_MIN_TIMER_NS, _MAX_TIMER_NS = 1_000_000, 20_000_000
_MAX_COMMAND_LEAD_NS = NS_PER_S  # a cmd_vel stamped further ahead acts from its receipt


@dataclass
class _ImageCamera:
    """One rendering camera and where its images go."""

    sensor: CameraImageSensor
    frame: str
    pub_image: object
    pub_info: object
    next_ns: int = 0  # its next capture (sim ns)


class SimNode(Node):
    """Steps the world with the wall clock (or as fast as possible) and publishes its readings."""

    def __init__(self, **kwargs) -> None:
        super().__init__("sim_node", **kwargs)
        self.world_config, self.settings = parse_parameters(given_values(self))
        declare_unset(self, SIM_PARAMETERS, SIM_PARAMETERS.defaults())
        refuse_changes(self, SIM_PARAMETERS)
        s = self.settings
        self._throttled = ThrottledLog(self.get_logger())  # warnings on the cmd_vel and tick paths
        self.world = World(self.world_config, n_trials=1, seed=s.seed)
        self.world.reset(s.initial_pose)
        self._epoch_ns = 0 if s.publish_clock else time.time_ns()
        sensor_qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self._pub_odom = self.create_publisher(Odometry, "odometry/dead_wheels", sensor_qos)
        self._pub_cameras = [self.create_publisher(PoseWithCovarianceStamped, f"{name}/pose", sensor_qos)
                             for name, cam in (("camera", self.world_config.camera),
                                               ("camera1", self.world_config.camera1))
                             if name == "camera" or cam.enabled]  # by CameraReading.camera
        self._pub_imu = self.create_publisher(Imu, "imu/data", sensor_qos)
        self._pub_joints = (self.create_publisher(JointState, "joint_states", sensor_qos)
                            if s.publish_joint_states or s.driven_joint_names else None)
        self._pub_truth = self.create_publisher(Odometry, "ground_truth/odom", sensor_qos)
        self._pub_clock = (self.create_publisher(ClockMsg, "/clock", QoSProfile(depth=10))
                           if s.publish_clock else None)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", QoSProfile(depth=10))
        self._images: list[_ImageCamera] = []
        self._pending_images: deque[tuple[_ImageCamera, ImageReading]] = deque()
        if s.camera_images is not None:
            self._setup_images(sensor_qos)
        self._tf = None
        if s.publish_odom_tf:
            try:
                self._tf = TfBroadcaster(self)
            except ImportError:
                self.get_logger().info("tf2_msgs is not importable: odom->base_link is not broadcast")
        self.create_subscription(TwistStamped if s.stamped_cmd_vel else Twist, "cmd_vel",
                                 self._on_cmd_vel, QoSProfile(depth=10))
        self._last_cmd_ns: int | None = None
        self._cmd_received = 0
        self._cmd_rejected = 0
        self._cmd_late = 0  # arrived after stamp + cmd_vel_latency: acted at once
        self._lag_events = 0
        self._dropped_ns = 0  # sim time skipped to catch up with the wall clock (real time only)
        self._drops = 0
        self._diag_prev = (0, 0)  # (lag events, drops) at the previous diagnostics
        self._published = 0
        self._wall_origin_ns: int | None = None
        self._sim_origin_ns = 0
        self._created_ns = time.monotonic_ns()
        self._started = not s.wait_for_topics
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        periods = [p for p in self.world_config.sensor_periods_ns().values()]
        self.batch_ns = min(periods)
        if s.real_time_factor > 0.0:
            timer_ns = min(max(round(self.batch_ns / s.real_time_factor), _MIN_TIMER_NS), _MAX_TIMER_NS)
            self.create_timer(ns_to_seconds(timer_ns), self._on_timer, clock=steady)
        self.create_timer(1.0, self._publish_diagnostics, clock=steady)
        self.get_logger().info(
            f"sim_node: {self.world_config.drive} drive, real_time_factor {s.real_time_factor}, "
            f"publish_clock {s.publish_clock}, seed {s.seed}")

    def _setup_images(self, qos: QoSProfile) -> None:
        """Image and CameraInfo publishers of each camera and the static TF base_link -> each
        camera's optical frame (one /tf_static message: a latched topic keeps only the last)."""
        from sensor_msgs.msg import CameraInfo, Image

        from ekf_localization.ros.tf_io import TF_STATIC_QOS, TF_STATIC_TOPIC, tf_message_class

        s = self.settings
        cameras = [("camera", s.camera_images, s.camera_frame, s.seed),
                   ("camera1", s.camera1_images, s.camera1_frame, (s.seed, 1))]
        for name, config, frame, seed in cameras:
            if config is not None:
                self._images.append(_ImageCamera(
                    CameraImageSensor(config, seed=seed), frame,
                    self.create_publisher(Image, f"{name}/image_raw", qos),
                    self.create_publisher(CameraInfo, f"{name}/camera_info", qos), config.phase_ns))
        tf_type = tf_message_class()
        if tf_type is None:
            self.get_logger().warning("tf2_msgs is not importable: base_link -> camera is not broadcast")
            return
        self._pub_tf_static = self.create_publisher(tf_type, TF_STATIC_TOPIC, TF_STATIC_QOS)
        self._pub_tf_static.publish(tf_type(transforms=[
            msgs.static_transform(c.sensor.base_to_optical(), self._epoch_ns, s.base_link_frame, c.frame)
            for c in self._images]))

    # -- input ---------------------------------------------------------------------------
    def _on_cmd_vel(self, msg: Twist | TwistStamped) -> None:
        """A command acts from its stamp + ``cmd_vel_latency`` (as ekf_node's drive model assumes),
        an unstamped one (or one stamped 0) from its receipt + the latency."""
        stamp = None
        if isinstance(msg, TwistStamped):
            t = stamp_to_ns(msg.header.stamp)
            stamp = t - self._epoch_ns if t > 0 else None
            if stamp is not None and stamp - self.world.t_ns > _MAX_COMMAND_LEAD_NS:
                stamp = None  # a clock far ahead of the sim's: from its receipt, not held back
            msg = msg.twist
        v = (msg.linear.x, msg.linear.y, msg.angular.z)
        self._cmd_received += 1
        if not all(math.isfinite(x) for x in v):
            self._cmd_rejected += 1
            self._throttled.warning("cmd_vel", f"cmd_vel rejected (non-finite): {v}")
            return
        if not self.world.set_command(v, stamp):
            self._cmd_late += 1
        self._last_cmd_ns = self.world.t_ns

    # -- time ----------------------------------------------------------------------------
    def ready(self) -> bool:
        """True once simulated time may run: every ``wait_for_topics`` topic has a publisher."""
        if self._started:
            return True
        missing = [t for t in self.settings.wait_for_topics if self.count_publishers(t) < 1]
        waited = ns_to_seconds(time.monotonic_ns() - self._created_ns)
        if not missing or waited >= self.settings.wait_timeout_s:
            self._started = True
            what = "peers up" if not missing else f"still no publisher on {missing} after {waited:.1f} s"
            self.get_logger().info(f"sim_node: starting simulated time ({what})")
        return self._started

    def _on_timer(self) -> None:
        if not self.ready():
            return
        now = time.monotonic_ns()
        if self._wall_origin_ns is None:
            self._wall_origin_ns, self._sim_origin_ns = now, self.world.t_ns
            if not self.settings.publish_clock:  # stamps are the wall time from the first tick on
                self._epoch_ns = time.time_ns() - self.world.t_ns
        P = self.world.physics_period_ns
        target = self._sim_origin_ns + int((now - self._wall_origin_ns) * self.settings.real_time_factor)
        target -= (target - self.world.t_ns) % P
        behind = target - self.world.t_ns
        if behind > _MAX_BATCH_NS and not self.settings.publish_clock:
            self._drop_ticks(behind - behind % P)
            target = self.world.t_ns
        elif behind > _MAX_BATCH_NS:  # fell behind on sim time: slow down instead of spiralling
            self._lag_events += 1
            self._throttled.warning("behind", "simulation cannot keep up with real_time_factor "
                                    f"{self.settings.real_time_factor}")
            target = self.world.t_ns + _MAX_BATCH_NS
            self._wall_origin_ns, self._sim_origin_ns = now, target
        if target > self.world.t_ns:
            self.run(target - self.world.t_ns)

    def _drop_ticks(self, skip_ns: int) -> None:
        """Real time after a stall: skip ``skip_ns`` of ticks so the stamps are the wall time again."""
        self._epoch_ns += skip_ns
        self._sim_origin_ns -= skip_ns
        self._dropped_ns += skip_ns
        self._drops += 1
        self.get_logger().warning(f"stalled for {ns_to_seconds(skip_ns):.3f} s (process stopped or CPU "
                                  f"starved): dropped {skip_ns // self.world.physics_period_ns} ticks to "
                                  "catch up with wall time")

    def run(self, duration_ns: int) -> None:
        """Advance the world by ``duration_ns`` and publish everything that became due."""
        s = self.settings
        if (self._last_cmd_ns is not None and s.cmd_vel_timeout_ns > 0
                and self.world.t_ns - self._last_cmd_ns > s.cmd_vel_timeout_ns):
            self.world.set_command((0.0, 0.0, 0.0))
            self._last_cmd_ns = None
        readings = self._advance(duration_ns)
        w = self.world
        if s.truth_at_clock and not any(isinstance(r, TruthReading) and r.stamp_ns == w.t_ns
                                        for r in readings):  # the truth at the /clock stamp too
            readings.append(TruthReading(w.t_ns, w.truth, w.truth_accel, w.attitude))
        if self._pub_clock is not None:
            self._pub_clock.publish(msgs.clock(self._epoch_ns + self.world.t_ns))
        for r in readings:
            self._publish(r)
        while self._pending_images and self._pending_images[0][1].arrival_ns <= self.world.t_ns:
            self._publish_image(*self._pending_images.popleft())

    def _advance(self, duration_ns: int) -> list:
        """world.advance, stopping at each image capture time to render from the true state."""
        if not self._images:
            return self.world.advance(duration_ns)
        end, readings = self.world.t_ns + duration_ns, []
        while (nxt := min(c.next_ns for c in self._images)) <= end:
            if nxt > self.world.t_ns:
                readings += self.world.advance(nxt - self.world.t_ns)
            t, truth = self.world.t_ns, self.world.truth[0]
            for c in self._images:  # same latency: the pending images stay in arrival order
                if c.next_ns == t:
                    self._pending_images.append((c, c.sensor.capture(t, truth)))
                if c.next_ns <= t:
                    c.next_ns = c.sensor.next_capture_ns(t)
        if end > self.world.t_ns:
            readings += self.world.advance(end - self.world.t_ns)
        return readings

    def _publish_image(self, camera: _ImageCamera, r: ImageReading) -> None:
        t = self._epoch_ns + r.stamp_ns
        camera.pub_image.publish(msgs.image(r, t, camera.frame))
        camera.pub_info.publish(msgs.camera_info(camera.sensor.config.camera, t, camera.frame))
        self._published += 1

    def _publish(self, r) -> None:
        s, t = self.settings, self._epoch_ns + r.stamp_ns
        if isinstance(r, DeadWheelReading):
            drop = s.odom_dropout_ns
            if drop is not None and drop[0] <= r.stamp_ns < drop[1]:  # dead_wheels.dropout
                return
            odom = msgs.dead_wheel_odometry(r, t, s.odom_frame, s.base_link_frame)
            self._pub_odom.publish(odom)
            if self._tf is not None and r.pose is not None:
                x, y, yaw = (float(v) for v in r.pose[0])
                self._tf.send_planar(t, s.odom_frame, s.base_link_frame, (x, y, yaw))
            if s.publish_joint_states:
                self._pub_joints.publish(msgs.joint_states(r, t, s.joint_names,
                                                           self.world_config.dead_wheels.wheel_radius))
        elif isinstance(r, CameraReading):
            if not r.visible[0]:
                return
            self._pub_cameras[r.camera].publish(msgs.camera_pose(r, t, s.map_frame))
        elif isinstance(r, ImuReading):
            self._pub_imu.publish(msgs.imu(r, t, s.base_link_frame))
        elif isinstance(r, WheelEncoderReading):
            self._pub_joints.publish(msgs.wheel_joint_states(r, t, s.driven_joint_names))
        elif isinstance(r, TruthReading):
            self._pub_truth.publish(msgs.ground_truth(r, t, s.map_frame, s.base_link_frame))
        self._published += 1

    def _publish_diagnostics(self) -> None:
        lagged, dropped = self._lag_events - self._diag_prev[0], self._drops - self._diag_prev[1]
        self._diag_prev = (self._lag_events, self._drops)
        problems = []
        if self._cmd_rejected:
            problems.append(f"{self._cmd_rejected} cmd_vel messages rejected")
        if lagged:
            problems.append("lagging behind real_time_factor")
        if dropped:
            problems.append("stalled: dropped ticks to catch up with wall time "
                            f"({ns_to_seconds(self._dropped_ns):.3f} s dropped so far)")
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if problems else DiagnosticStatus.OK, name="sim_node: simulator",
            hardware_id="sim_robot", message="; ".join(problems) or "running",
            values=[KeyValue(key=k, value=str(v)) for k, v in (
                ("sim_time_ns", self.world.t_ns), ("cmd_vel_received", self._cmd_received),
                ("cmd_vel_rejected", self._cmd_rejected), ("cmd_vel_late", self._cmd_late),
                ("lag_events", self._lag_events),
                ("dropped_ticks", self._dropped_ns // self.world.physics_period_ns),
                ("dropped_s", f"{ns_to_seconds(self._dropped_ns):.3f}"),
                ("stamp_lag_s", f"{ns_to_seconds(self._stamp_lag_ns()):.3f}"),
                ("messages_published", self._published))])
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = msgs.stamp(self._epoch_ns + self.world.t_ns)
        self._pub_diag.publish(arr)

    def _stamp_lag_ns(self) -> int:
        """Wall time minus the newest stamp (real time; 0 on sim time or before the start)."""
        if self.settings.publish_clock or self._wall_origin_ns is None:
            return 0
        return time.time_ns() - (self._epoch_ns + self.world.t_ns)


def _spin(executor, node: SimNode) -> None:
    """Real time on the executor's timers, or as fast as possible between spins."""
    if node.settings.real_time_factor > 0.0:
        spin_forever(executor)
        return
    while running(executor):
        if node.ready():
            executor.spin_once(timeout_sec=0.0)
            node.run(node.batch_ns)
        else:
            executor.spin_once(timeout_sec=0.01)


def main(args: list[str] | None = None) -> int:
    return run_node("sim_node", SimNode, spin=_spin, args=args)


if __name__ == "__main__":
    sys.exit(main())
