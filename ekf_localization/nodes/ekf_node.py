"""ekf_node: fuse odometry, poses, twists, IMUs and cmd_vel into /odometry/filtered.

A thin rclpy adapter around :class:`ekf_localization.core.localizer.Localizer`: it reads the
parameters (:mod:`ekf_localization.ros.ekf_parameters`), converts messages
(:mod:`ekf_localization.ros.conversions`), hands them to the localizer with the node's
clock (ROS time, so ``use_sim_time`` works), and publishes the estimate at ``frequency``,
diagnostics once a second, and TF (``ekf_localization.ros.tf_io``: /tf and /tf_static in, /tf out).

    ros2 run ekf_localization ekf_node --ros-args --params-file config/ekf.yaml
"""

from __future__ import annotations

import copy
import sys
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from std_srvs.srv import Empty

from ekf_localization.core.ellipse import ellipse_points
from ekf_localization.core.localizer import CONTROL_SOURCE, SET_POSE_SOURCE, WHEEL_COMMAND_SOURCE, Estimate
from ekf_localization.core.measurements import REJECT_GATED
from ekf_localization.core.units import ns_to_sec_nanosec
from ekf_localization.inputs import KINDS
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros import fusion_log, markers
from ekf_localization.ros.conversions import (
    UNREADABLE_ERRORS,
    control_from_message,
    estimate_to_odometry,
    map_to_odom,
    message_class,
    message_to_measurement,
    planar_pose,
    planar_transform,
)
from ekf_localization.ros.due_timer import create_due_timer
from ekf_localization.ros.ekf_diagnostics import EkfDiagnostics
from ekf_localization.ros.ekf_parameters import EKF_PARAMETERS, effective_values, parse_ekf_settings
from ekf_localization.ros.node_parameters import (
    declare_unset,
    given_qos_overrides,
    given_values,
    refuse_changes,
)
from ekf_localization.ros.node_runner import run_node
from ekf_localization.ros.parameters import ParameterError, expected
from ekf_localization.ros.scheduling import HOW_TO_ALLOW, use_fifo
from ekf_localization.ros.static_tf import StaticTransforms
from ekf_localization.ros.tf_io import TfBroadcaster, TfListener, tf_message_class
from ekf_localization.ros.throttled_log import ThrottledLog

OUTPUT_TOPIC = "odometry/filtered"
SLOW_CALLBACK_S = 0.1
DIAGNOSTICS_PERIOD_S = 1.0


class EkfNode(Node):
    """The ROS face of the localizer. Raises ParameterError on a bad parameter."""

    def __init__(self, node_name: str = "ekf_node", **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        self.settings = settings = parse_ekf_settings(given_values(self), MODELS)
        self.config = cfg = settings.config  # the Localizer's
        log = self.get_logger()
        self._throttled = ThrottledLog(log)  # every warning on a message or timer path
        for text in settings.warnings:
            log.warning(text)
        declare_unset(self, EKF_PARAMETERS, effective_values(settings))
        refuse_changes(self, EKF_PARAMETERS)
        self.localizer = make_localizer(cfg, warn=self._localizer_warning)
        self._diagnostics = EkfDiagnostics(self.localizer, bool(settings.wheel_command_topic))
        self._sim_time = bool(self.get_parameter("use_sim_time").value)  # ROS time runs on /clock
        self.add_post_set_parameters_callback(self._follow_use_sim_time)
        self._published = 0
        self._internal_errors = 0
        self._slow_callbacks = 0
        self._guard_reported = (0, 0)  # command_guard (trips, recoveries) last on /diagnostics
        # (x, y, accepted) of the recent pose fixes, kept with publish_markers
        self._fixes: deque | None = (deque(maxlen=settings.marker_fix_count) if settings.publish_markers
                                     else None)
        overridable = QoSOverridingOptions.with_default_policies()  # qos_overrides.<topic>.* apply here
        self._pub = self.create_publisher(Odometry, OUTPUT_TOPIC, 10, qos_overriding_options=overridable)
        self._odometry = Odometry()  # the output message, refilled for each publish
        self._log: list[int] | None = None  # fusion log rows since the last output (ros/fusion_log.py)
        if settings.publish_fusion_log:
            from std_msgs.msg import Int64MultiArray

            self._log = []
            self._log_pub = self.create_publisher(Int64MultiArray, "~/" + fusion_log.TOPIC, 100)
        self._subs = []
        for inp in cfg.inputs:
            qos = copy.copy(qos_profile_sensor_data)
            qos.depth = inp.queue_size
            self._subs.append(self.create_subscription(
                message_class(inp.kind), inp.topic, self._measurement_callback(inp.name, inp.kind),
                qos, qos_overriding_options=overridable))
            log.info(f"{inp.name}: {inp.kind} on '{inp.topic}'")
        if cfg.use_control:
            self._subs.append(self.create_subscription(
                TwistStamped if settings.stamped_cmd_vel else Twist, settings.cmd_vel_topic,
                self._guarded("cmd_vel", self._on_cmd_vel), qos_profile_sensor_data,
                qos_overriding_options=overridable))
            log.info(f"commands on '{self._subs[-1].topic_name}'")
        if cfg.use_control and settings.wheel_command_topic:
            from std_msgs.msg import Float64MultiArray

            self._subs.append(self.create_subscription(
                Float64MultiArray, settings.wheel_command_topic,
                self._guarded(WHEEL_COMMAND_SOURCE, self._on_wheel_command), qos_profile_sensor_data))
            log.info(f"wheel commands ({', '.join(cfg.wheel_order)}) on '{settings.wheel_command_topic}'")
        self._check_qos_overrides(given_qos_overrides(self),
                                  [(s.topic_name, "subscription") for s in self._subs]
                                  + [(self._pub.topic_name, "publisher")])
        self._subs.append(self.create_subscription(PoseWithCovarianceStamped, "set_pose",
                                                   self._guarded("set_pose", self._on_set_pose), 10))
        self._reset_srv = self.create_service(Empty, "~/reset", self._on_reset)
        self.urgent_services = (self._reset_srv,)  # node_runner answers it ahead of queued messages
        self._period_ns = settings.publish_period_ns
        self._last_output_ns: int | None = None  # stamp of the newest /odometry/filtered
        self._timer = create_due_timer(self, 1.0 / settings.frequency, self._guarded("timer", self._on_timer))
        self._diag_pub = None
        if settings.print_diagnostics:
            self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self._diag_timer = create_due_timer(self, DIAGNOSTICS_PERIOD_S,
                                                self._guarded("diagnostics", self._publish_diagnostics),
                                                clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._tf = self._tf_listener = self._static = None
        self._setup_tf()
        self._last_estimate = None  # the newest published estimate (for the markers)
        self._marker_pub = None
        if settings.publish_markers:
            from visualization_msgs.msg import MarkerArray

            self._marker_pub = self.create_publisher(MarkerArray, markers.EKF_MARKER_TOPIC, 1)
            self._marker_timer = create_due_timer(self, 1.0 / settings.marker_frequency,
                                                  self._guarded("markers", self._publish_markers),
                                                  clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._scheduling = "default"  # on /diagnostics: what thread_priority gave
        if settings.thread_priority:  # last: every thread (DDS, TF) exists by now
            refused = use_fifo(settings.thread_priority)
            self._scheduling = refused or f"SCHED_FIFO {settings.thread_priority}"
            if refused:
                log.warning(f"thread_priority {settings.thread_priority}: {refused}; the filter runs at the "
                            f"default priority, where busy processes can delay it: {HOW_TO_ALLOW}")
        log.info(f"ready: model '{cfg.model}', world frame '{cfg.world_frame}', {settings.frequency:g} Hz, "
                 f"{len(cfg.inputs)} inputs, history {cfg.history_length:g} s"
                 f"{'' if cfg.smooth_lagged_data else ' (smoothing off)'}, scheduling {self._scheduling}")

    # --- helpers -----------------------------------------------------------------------------

    def _localizer_warning(self, text: str) -> None:
        """The localizer's warnings, throttled per input (the text's first word): a stream of
        messages each with a new frame id makes one line a period, not one per frame. A filter
        reset is keyed by its cause too, so a bag loop right after a reset service still says so."""
        head, _, rest = text.partition(":")
        cause = rest.split()[0] if head == "filter reset" and rest.split() else ""
        self._throttled.warning(("localizer", head, cause), text)

    def _now_ns(self) -> int | None:
        """ROS time in ns; None while simulated time has not started (no /clock yet). Without
        simulated time ROS time is the system clock: read directly (rclpy's now(), and its
        ``ros_time_is_active``, a locked call into rcl, cost ten times more)."""
        if not self._sim_time:
            return time.time_ns()
        t = self.get_clock().now().nanoseconds
        return t if t > 0 else None

    def _follow_use_sim_time(self, parameters: list) -> None:
        """Keep ``_sim_time`` equal to ``use_sim_time`` once a change of it has been applied."""
        for p in parameters:
            if p.name == "use_sim_time":
                self._sim_time = bool(p.value)

    def _note(self, now: int | None, stamp_ns: int, code: int) -> None:
        """A row of the fusion log: the Localizer is about to be given this (ros/fusion_log.py)."""
        if self._log is not None:
            self._log += (fusion_log.NO_CLOCK if now is None else now, int(stamp_ns), code)

    @staticmethod
    def _check_qos_overrides(values: dict, endpoints: list[tuple[str, str]]) -> None:
        """qos_overrides.<topic>.<subscription|publisher>.<policy> is applied (rclpy) to the inputs,
        cmd_vel and odometry/filtered; one naming anything else is refused, never ignored."""
        allowed = {f"qos_overrides.{topic}.{entity}." for topic, entity in endpoints}
        for key in values:
            if key.startswith("qos_overrides.") and not any(key.startswith(a) for a in allowed):
                form = "a QoS override of one of this node's topics: " + ", ".join(
                    sorted(a + "<policy>" for a in allowed))
                raise ParameterError(expected(key, form, values[key]))

    def _setup_tf(self) -> None:
        """Listen to /tf and /tf_static for the inputs' frames; broadcast with publish_tf; publish
        static_transforms on /tf_static (ros/static_tf.py: another node's value for one of them is a WARN)."""
        msg_type = tf_message_class()
        try:
            if msg_type is None:
                raise ImportError("tf2_msgs")
            self._static = StaticTransforms(self, msg_type, self.config.static_transforms,
                                            self.get_clock().now().nanoseconds, self._static_conflict)
            self._tf_listener = TfListener(self, self.localizer.transforms, self._guarded,
                                           self._static.filter)
            if self.settings.publish_tf:
                self._tf = TfBroadcaster(self)
        except ImportError:
            self.get_logger().info("tf2_msgs is not importable: no TF is read or broadcast (inputs must be "
                                   "in the filter's frames or covered by static_transforms)")

    def _static_conflict(self, text: str) -> None:
        """Another node's /tf_static value for a static_transforms frame (once per frame): said at once."""
        self.get_logger().warning(text)
        if self._diag_pub is not None:
            self._publish_diagnostics()

    def _guarded(self, source: str, fn: Callable[..., None]) -> Callable[..., None]:
        """``fn`` as a subscription callback that logs and counts an exception instead of dying."""
        log = self._throttled

        def callback(*msg) -> None:  # a subscription passes the message, a timer nothing
            t0 = time.perf_counter()
            try:
                fn(*msg)
            except Exception as exc:  # never die on a message
                self._internal_errors += 1
                log.error((source, "exception"), f"{source}: message could not be processed: {exc!r}")
            took = time.perf_counter() - t0
            if took > SLOW_CALLBACK_S:  # a stall delays every other callback, /clock included
                self._slow_callbacks += 1
                log.warning((source, "slow"), f"{source}: callback took {took * 1e3:.0f} ms")
            if source != "timer":
                self._publish_if_overdue()

        return callback

    def _publish_if_overdue(self) -> None:
        """Publish from a message callback once a publish period has passed without output: a
        burst of messages queued ahead of the timer's event (the EventsExecutor runs them in
        order) then never silences /odometry/filtered for longer than about two periods."""
        now = self._now_ns()
        last = self._last_output_ns
        if now is not None and last is not None and now - last >= self._period_ns:
            try:
                self._publish_estimate(now)
            except Exception as exc:  # never die on a message
                self._internal_errors += 1
                self._throttled.error(("publish", "exception"), f"publish: {exc!r}")

    def _measurement_callback(self, source: str, kind: str) -> Callable[..., None]:
        """The callback of input ``source``: its message converted (conversions.message_to_measurement),
        then fused; one that does not convert is counted as unreadable."""
        localizer = self.localizer
        log = self._throttled

        fixes = self._fixes if KINDS[kind].absolute_pose else None

        publish_now = self.settings.publish_on_measurement
        code = fusion_log.source_code(source)

        def on_message(msg: Any) -> None:
            now = self._now_ns()
            try:
                measurement = message_to_measurement(kind, msg)
            except UNREADABLE_ERRORS as exc:  # counted as bag_replay counts it
                localizer.note_unreadable(source)
                log.warning((source, "unreadable"), f"{source}: rejected an unreadable message ({exc})")
                return
            self._note(now, measurement.stamp_ns, code)
            result = localizer.add_measurement(source, measurement, now)
            if publish_now and result.applied and now is not None:
                self._publish_estimate(now)
            if fixes is not None:  # a bounded append; the markers are built on their own timer
                accepted = "pose" in result.applied
                if accepted or ("pose", REJECT_GATED) in result.rejected:
                    fixes.append((float(measurement.pose[0]), float(measurement.pose[1]), accepted))
            if result.rejected:
                part, reason = result.rejected[0]
                log.warning((source, part, reason), f"{source}: rejected {part} ({reason})")

        return self._guarded(source, on_message)

    # --- callbacks ---------------------------------------------------------------------------

    def _on_cmd_vel(self, msg: Twist | TwistStamped) -> None:
        now = self._now_ns()
        if now is None:
            return
        command = control_from_message(msg, now)
        self._note(now, command.stamp_ns, fusion_log.source_code(CONTROL_SOURCE))
        reason = self.localizer.add_control(command, now)
        if reason is not None:
            self._throttled.warning(("cmd_vel", reason), f"cmd_vel: rejected ({reason})")

    def _on_wheel_command(self, msg: Any) -> None:
        """std_msgs/Float64MultiArray wheel speeds (ros2_control's forward command), stamped on receipt."""
        now = self._now_ns()
        if now is None:
            return
        self._note(now, now, fusion_log.source_code(WHEEL_COMMAND_SOURCE))
        reason = self.localizer.add_wheel_command(now, msg.data, now)
        if reason is not None:
            self._throttled.warning((WHEEL_COMMAND_SOURCE, reason),
                                    f"{WHEEL_COMMAND_SOURCE}: rejected ({reason})")

    def _on_set_pose(self, msg: PoseWithCovarianceStamped) -> None:
        now = self._now_ns()
        pose = message_to_measurement("pose", msg)
        self._note(now, pose.stamp_ns, fusion_log.source_code(SET_POSE_SOURCE))
        reason = self.localizer.set_pose(pose, now)
        if reason is None:
            x, y, yaw = msg.pose.pose.position.x, msg.pose.pose.position.y, \
                planar_pose(self.localizer.committed())[2]
            self.get_logger().info(f"set_pose: x={x:.3f} y={y:.3f} yaw={yaw:.3f}")
        else:
            self.get_logger().warning(f"set_pose rejected ({reason})")

    def _on_reset(self, request, response):
        self._note(self._now_ns(), 0, fusion_log.RESET)
        self.localizer.reset("reset service called")
        return response

    def _on_timer(self) -> None:
        now = self._now_ns()
        if now is not None:
            self._publish_estimate(now)
        guard = self.localizer.command_guard
        if guard is not None and self._diag_pub is not None \
                and (guard.trips, guard.recoveries) != self._guard_reported:  # say so at once
            self._guard_reported = (guard.trips, guard.recoveries)
            self._publish_diagnostics()

    def _publish_estimate(self, now: int) -> None:
        """Publish the estimate for ``now`` (and TF) when there is a new one."""
        suppressed = self.localizer.nonfinite_outputs
        est = self.localizer.advance_to(now)
        if self.localizer.nonfinite_outputs != suppressed:
            self._throttled.error("nonfinite", "non-finite estimate suppressed")
        if est is None:
            return
        self._odometry = estimate_to_odometry(est, self.config.world_frame, self.config.base_link_frame,
                                              self._odometry)  # one message, refilled: publish serialises it
        self._pub.publish(self._odometry)
        self._published += 1
        self._last_output_ns = est.stamp_ns
        if self._log is not None:
            self._note(now, est.stamp_ns, fusion_log.OUTPUT)
            self._log_pub.publish(fusion_log.to_message(self._log))
            self._log = []
        self._last_estimate = est
        if self._tf is not None:
            self._broadcast_tf(est)

    def _broadcast_tf(self, est: Estimate) -> None:
        cfg, settings = self.config, self.settings
        pose = planar_pose(est)
        if cfg.world_frame == settings.odom_frame:
            self._tf.send_planar(est.stamp_ns, settings.odom_frame, cfg.base_link_frame, pose)
            return
        # world = map: publish map->odom given someone else's odom->base_link (as RL does)
        odom_base = self.localizer.transforms.lookup(settings.odom_frame, cfg.base_link_frame, est.stamp_ns)
        if odom_base is None:
            self._throttled.warning("no odom->base_link", f"no {settings.odom_frame}->{cfg.base_link_frame} "
                                    "transform on /tf, map->odom not published")
            return
        self._tf.send_planar(est.stamp_ns, settings.map_frame, settings.odom_frame,
                             map_to_odom(pose, planar_transform(odom_base)))

    def _publish_markers(self) -> None:
        """The 95 % position ellipse of the newest estimate and the recent pose fixes."""
        cfg = self.config
        stamp = self.get_clock().now().to_msg()
        frame = cfg.world_frame
        out = []
        est = self._last_estimate
        if est is not None and 0 in est.state_fields and 1 in est.state_fields:
            i, j = est.state_fields.index(0), est.state_fields.index(1)
            cov = est.covariance[np.ix_((i, j), (i, j))]
            if np.all(np.isfinite(cov)):
                pts = ellipse_points((est.state[i], est.state[j]), cov)
                at = type(stamp)()  # stamped as its estimate (the /odometry/filtered of that stamp)
                at.sec, at.nanosec = ns_to_sec_nanosec(est.stamp_ns)
                out.append(markers.line_strip(markers.NS_ELLIPSE, frame, at, pts, markers.ELLIPSE_RGBA, 0.01))
        fixes = list(self._fixes)
        out.append(markers.sphere_list(markers.NS_FIXES_ACCEPTED, frame, stamp,
                                       [(x, y) for x, y, ok in fixes if ok], markers.ACCEPTED_RGBA, 0.04))
        out.append(markers.sphere_list(markers.NS_FIXES_GATED, frame, stamp,
                                       [(x, y) for x, y, ok in fixes if not ok], markers.GATED_RGBA, 0.05))
        self._marker_pub.publish(markers.marker_array(out))

    # --- diagnostics -------------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        counters = (("internal_errors", self._internal_errors), ("slow_callbacks", self._slow_callbacks),
                    ("scheduling", self._scheduling), ("published", self._published))
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = self._diagnostics.statuses(self.get_name(), self._steady.now().nanoseconds,
                                                self._now_ns(), self._internal_errors, counters)
        if self._static is not None:
            arr.status += self._static.status(self.get_name())
        self._diag_pub.publish(arr)


def main(argv: list[str] | None = None) -> int:
    return run_node("ekf_node", EkfNode, args=argv)


if __name__ == "__main__":
    sys.exit(main())
