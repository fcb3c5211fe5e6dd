"""config/ekf_mecanum_drive_controller.yaml and config/ekf_diff_drive_controller.yaml over real
DDS, behind a stand-in for each ros2_controllers controller (helpers/controller_standin.py):
exactly its topics, message types, frame ids, placeholder covariances and TF.

The stand-in's drive follows the commands the test sends on the controller's command topic
(constant-twist arcs) through the config's time constant, but reaches only 80 % of them (a
drive under load), and its wheels measure the twist with the noise the config's
``odom0_twist_covariance`` declares. ekf_node, started from the config alone (mecanum's as a process,
diff's through ekf.launch.py where launch is available), must track the stand-in's truth:

* within a bound from that twist covariance and the duration: 4 σ of the position error of
  integrating noisy twists (σ_v² T/f for the speed, v² σ_ω² T³/(3f) through the heading),
  plus 20 ms of travel for stamps and latency. The commands alone would miss the truth by
  20 % of the distance, over twice the bound: the estimate must follow the wheels (with the
  controllers' placeholder covariance instead of the config's, it does not);
* each TF link with exactly one publisher: odom->base_link only the controller (every one on
  /tf is a transform the stand-in sent, none twice), map->odom only ekf_node (the stand-in
  sends none), and nothing else publishes on /tf. mecanum_drive_controller's ~/tf_odometry is
  remapped to /tf, as the config tells the user to do.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from helpers.controller_standin import DIFF, MECANUM, UPDATE_RATE, make_standin, truth_at
from helpers.launch_runner import launch_problem, launched, layout_prefix
from helpers.ros_helpers import REPO, node_command, running_process, spin_until

from ekf_localization.ros.parameters import parameters_from_yaml

pytestmark = pytest.mark.ros

CONFIGS = {"mecanum": (MECANUM, REPO / "config" / "ekf_mecanum_drive_controller.yaml"),
           "diff": (DIFF, REPO / "config" / "ekf_diff_drive_controller.yaml")}
GAIN = 0.8  # the drive reaches 80 % of each command
# (seconds, command vx vy vyaw): at rest, three constant-twist arcs, at rest
SEGMENTS = ((1.0, (0.0, 0.0, 0.0)), (3.0, (0.4, 0.15, 0.3)), (3.0, (0.3, -0.1, -0.4)),
            (3.0, (0.45, 0.0, 0.1)), (1.0, (0.0, 0.0, 0.0)))
COMMAND_RATE = 20.0  # Hz


def _config(path: Path) -> dict:
    return parameters_from_yaml(path, "ekf_node")


def _bound(twist_variance: np.ndarray, rate: float, duration: float, speed: float) -> float:
    """4 σ of the position error after integrating ``duration`` s of twists at ``rate`` Hz with
    variances (vx, vy, vyaw) at ``speed`` m/s, plus 20 ms of travel."""
    var_v = float(max(twist_variance[0], twist_variance[1]))
    var_w = float(twist_variance[2])
    sigma = math.sqrt(var_v * duration / rate + speed ** 2 * var_w * duration ** 3 / (3.0 * rate))
    return 4.0 * sigma + 0.02 * speed


def _command_only_miss(holonomic: bool) -> float:
    """How far the commands alone would put the robot from the truth at the end (m)."""
    def run(gain: float) -> np.ndarray:
        pose = np.zeros(3)
        for seconds, cmd in SEGMENTS:
            v = np.array(cmd) * gain
            if not holonomic:
                v[1] = 0.0
            for _ in range(int(seconds * 1000)):
                mid = pose[2] + 0.5 * v[2] * 1e-3
                pose += np.array([math.cos(mid) * v[0] - math.sin(mid) * v[1],
                                  math.sin(mid) * v[0] + math.cos(mid) * v[1], v[2]]) * 1e-3
        return pose
    return float(np.hypot(*(run(1.0) - run(GAIN))[:2]))


class _Probe:
    """The commander (the controller's command topic) and the listener (/odometry/filtered, /tf)."""

    def __init__(self, context, controller) -> None:
        from geometry_msgs.msg import TwistStamped
        from nav_msgs.msg import Odometry
        from rclpy.node import Node
        from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy
        from tf2_msgs.msg import TFMessage

        self.node = Node("ros2_control_probe", context=context)
        self.estimates: list[tuple[int, float, float, float]] = []
        self.tf: list[tuple[str, str, int]] = []
        command_topic = f"/{controller.name}/{controller.command_topic.removeprefix('~/')}"
        self.cmd = self.node.create_publisher(TwistStamped, command_topic, 10)
        self.out = self.node.create_subscription(Odometry, "/odometry/filtered", self._on_estimate, 50)
        tf_qos = QoSProfile(depth=100, reliability=QoSReliabilityPolicy.RELIABLE,
                            durability=QoSDurabilityPolicy.VOLATILE)  # tf2's listener QoS
        self.tf_sub = self.node.create_subscription(TFMessage, "/tf", self._on_tf, tf_qos)
        self._TwistStamped = TwistStamped

    def _on_estimate(self, msg) -> None:
        q = msg.pose.pose.orientation
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        t = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.estimates.append((t, msg.pose.pose.position.x, msg.pose.pose.position.y, yaw))

    def _on_tf(self, msg) -> None:
        for tf in msg.transforms:
            t = tf.header.stamp.sec * 1_000_000_000 + tf.header.stamp.nanosec
            self.tf.append((tf.header.frame_id, tf.child_frame_id, t))

    def command(self, v) -> None:
        msg = self._TwistStamped()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.header.frame_id = "base_link"
        msg.twist.linear.x, msg.twist.linear.y, msg.twist.angular.z = (float(x) for x in v)
        self.cmd.publish(msg)


def _drive(kind: str, ros_context, run_ekf) -> None:
    from rclpy.executors import SingleThreadedExecutor

    controller, path = CONFIGS[kind]
    params = _config(path)
    cov = np.array(params["odom0_twist_covariance"], dtype=float)
    twist_variance = cov[[0, 1, 5]] if cov.size == 6 else np.diag(cov.reshape(6, 6))[[0, 1, 5]]
    tau = np.array(params["control_time_constant"], dtype=float)[[0, 1, 5]]
    # the user's remap (the config's comment): the controller's TF onto /tf
    remap = None
    if controller is MECANUM:
        remap = ["--ros-args", "-r", "/mecanum_drive_controller/tf_odometry:=/tf"]
    standin = make_standin(ros_context, controller, twist_variance, tau, GAIN, seed=7, cli_args=remap)
    probe = _Probe(ros_context, controller)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(standin)
    ex.add_node(probe.node)
    try:
        with run_ekf() as log_text:
            # ekf_node listens to the odometry and the commands, publishes its estimate and TF
            ready = spin_until(ex, lambda: standin.odom_pub.get_subscription_count() >= 1
                               and standin.tf_pub.get_subscription_count() >= 2  # ekf_node, probe
                               and probe.cmd.get_subscription_count() >= 2
                               and probe.out.get_publisher_count() >= 1
                               and len(probe.node.get_publishers_info_by_topic("/tf")) >= 2
                               and probe.tf_sub.get_publisher_count() >= 2, timeout=60.0)  # matched
            assert ready, log_text()[-3000:]
            standin.running = True
            spin_until(ex, lambda: False, timeout=0.5)  # the filter starts on the first odometry
            start = time.monotonic()
            for seconds, v in SEGMENTS:
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    if not controller.holonomic:
                        v = (v[0], 0.0, v[2])
                    probe.command(v)
                    spin_until(ex, lambda: False, timeout=1.0 / COMMAND_RATE, step=0.005)
            duration = time.monotonic() - start
            standin.running = False
            spin_until(ex, lambda: False, timeout=0.3)
            tf_publishers = sorted(i.node_name for i in probe.node.get_publishers_info_by_topic("/tf"))
            private_tf = len(probe.node.get_publishers_info_by_topic(f"/{controller.name}/tf_odometry"))
            text = log_text()
    finally:
        ex.shutdown()
        probe.node.destroy_node()
        standin.destroy_node()

    # --- tracking --------------------------------------------------------------------------------
    errors, yaw_errors, odom_errors = [], [], []
    for t, x, y, yaw in probe.estimates:
        truth = truth_at(standin.truth_log, t)
        if truth is None or t < standin.truth_log[0][0] + 0.5e9:
            continue
        errors.append(math.hypot(x - truth[0], y - truth[1]))
        yaw_errors.append(abs(math.remainder(yaw - truth[2], math.tau)))
        odom = truth_at(standin.odom_log, t)
        if odom is not None:
            odom_errors.append(math.hypot(odom[0] - truth[0], odom[1] - truth[1]))
    assert len(errors) >= 0.5 * 50.0 * duration, (len(errors), text[-3000:])
    rate = UPDATE_RATE / controller.publish_every
    speed = max(math.hypot(v[0], v[1] if controller.holonomic else 0.0) for _, v in SEGMENTS)
    bound = _bound(twist_variance, rate, duration, speed)
    miss = _command_only_miss(controller.holonomic)
    final = standin.truth_log[-1][1:]
    travelled = sum(math.hypot(*np.subtract(b[1:3], a[1:3])) for a, b in
                    zip(standin.truth_log, standin.truth_log[1:], strict=False))
    print(f"{kind}: {len(errors)} estimates over {duration:.1f} s, {travelled:.2f} m travelled, end at "
          f"({final[0]:.2f}, {final[1]:.2f}); position error max {max(errors):.3f} m, RMS "
          f"{math.sqrt(np.mean(np.square(errors))):.3f} m, final {errors[-1]:.3f} m (bound {bound:.3f} m; "
          f"the controller's own odometry: max {max(odom_errors):.3f} m); yaw error max "
          f"{max(yaw_errors):.4f} rad; commands alone would miss by {miss:.2f} m")
    assert miss > 2.0 * bound  # the test can tell wheels from commands
    assert max(errors) <= bound, (max(errors), bound)
    assert max(yaw_errors) <= 4.0 * math.sqrt(twist_variance[2] * duration / rate) + 0.02 * 0.4

    # --- each TF link has exactly one publisher -----------------------------------------------
    links = Counter((parent, child) for parent, child, _ in probe.tf)
    assert set(links) == {("map", "odom"), ("odom", "base_link")}, links
    odom_base = Counter(t for parent, child, t in probe.tf if (parent, child) == ("odom", "base_link"))
    sent = set(standin.tf_sent)
    assert set(odom_base) <= sent, "an odom->base_link transform the controller did not send"
    assert max(odom_base.values()) == 1, "an odom->base_link stamp published twice"
    assert len(odom_base) >= 0.9 * len(sent), (len(odom_base), len(sent))
    map_odom = Counter(t for parent, child, t in probe.tf if (parent, child) == ("map", "odom"))
    assert len(map_odom) >= 0.5 * 50.0 * duration and max(map_odom.values()) == 1, map_odom.most_common(3)
    assert tf_publishers == sorted(["ekf_node", controller.name]), tf_publishers
    assert private_tf == 0  # mecanum: remapped to /tf; diff_drive_controller has no such topic
    # map->odom from the first estimate on (the first outputs may precede the odom->base_link they
    # need by a few messages), and the first estimate soon after the first odometry's stamp:
    # ekf_node starts on it. Under load (four busy loops, or CI's other worker) that has taken
    # 0.34 s while the TF still followed the first estimate at once (the stand-in and the probe
    # run in the test's own process, at normal priority), so that bound is looser.
    first_estimate = min(t for t, *_ in probe.estimates)
    assert min(map_odom) - first_estimate <= 200_000_000, (min(map_odom) - first_estimate) / 1e9
    assert first_estimate - min(sent) <= 1_000_000_000, (first_estimate - min(sent)) / 1e9
    assert "Traceback" not in text, text[-3000:]


def test_ekf_node_from_the_mecanum_config_tracks_the_controller(ros_context, tmp_path: Path) -> None:
    """``ekf_node --ros-args --params-file config/ekf_mecanum_drive_controller.yaml``."""
    @contextmanager
    def run_ekf():
        log = tmp_path / "ekf.log"
        cmd = [*node_command("ekf_node"), "--ros-args", "--params-file", str(CONFIGS["mecanum"][1])]
        with running_process(cmd, log):
            yield log.read_text

    _drive("mecanum", ros_context, run_ekf)


def test_ekf_launch_with_the_diff_config_tracks_the_controller(ros_context, tmp_path: Path) -> None:
    """``ros2 launch ekf_localization ekf.launch.py params_file:=config/ekf_diff_drive_controller.yaml``
    with Jazzy's launch; where launch is absent, ekf_node as a process, so that the config is
    still run. The launch passes any params file alike: one config through it is enough."""
    problem = launch_problem()

    @contextmanager
    def run_ekf():
        if problem:
            log = tmp_path / "ekf.log"
            cmd = [*node_command("ekf_node"), "--ros-args", "--params-file", str(CONFIGS["diff"][1])]
            with running_process(cmd, log):
                yield log.read_text
        else:
            prefix = layout_prefix(tmp_path / "install")
            with launched(prefix, tmp_path, "ekf.launch.py", params_file=str(CONFIGS["diff"][1])) as log:
                yield log.read_text

    _drive("diff", ros_context, run_ekf)
