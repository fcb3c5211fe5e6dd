"""ekf_node (config/ekf.yaml) against the faults of issue 35, over real DDS.

* Case 3: cmd_vel stamped 200 ms ahead of the clock is rejected as ``future_stamp``; no
  output is ever stamped ahead of the clock.
* Case 1: a camera pose with an empty frame_id, while a TF tree exists, is rejected as
  ``no_frame`` (not read as base_link); ``pose0_default_frame_id`` names a frame for it.
* Case 6: a thousand frame ids make a few throttled warnings, and the per-frame state is an
  LRU whose size, cap and evictions are on /diagnostics.
* Case 5: every odometry message delivered twice is fused once, the copy counted as
  ``duplicate``, and the counters add up (received = applied + rejected).
* A value not yet known (the command guard's before any command) is left out of /diagnostics,
  never "nan".
* ``reset`` is answered within 100 ms during a 20,000-message, 10 kHz odometry burst and after it.
* 50 camera poses with an empty frame_id, the TF tree complete: one outcome (no_frame) for all.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import pytest
from helpers.ros_helpers import (
    REPO,
    node_command,
    running_process,
    spin_until,
    twist_odometry,
    wait_for_publishers,
    wait_for_subscribers,
)

from ekf_localization.core.units import NS_PER_S, stamp_to_ns

pytestmark = pytest.mark.ros

PERIOD_NS = 20_000_000  # 50 Hz inputs


class Harness:
    """A probe node next to ekf_node: publishes inputs, keeps outputs and the latest diagnostics."""

    def __init__(self, ctx) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import TwistStamped
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import qos_profile_sensor_data

        self.node = Node("fault_probe", context=ctx)
        self.ex = SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.outputs: list[tuple[int, int]] = []  # (output stamp, receive time on the clock) ns
        self.diag: dict[str, dict[str, str]] = {}
        self.out_sub = self.node.create_subscription(Odometry, "odometry/filtered", self._on_output, 1000)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.odom = self.node.create_publisher(Odometry, "odometry/dead_wheels", qos_profile_sensor_data)
        self.cmd = self.node.create_publisher(TwistStamped, "cmd_vel", qos_profile_sensor_data)

    def now(self) -> int:
        return self.node.get_clock().now().nanoseconds

    def _on_output(self, msg) -> None:
        self.outputs.append((stamp_to_ns(msg.header.stamp), self.now()))

    def _on_diag(self, msg) -> None:
        for st in msg.status:
            self.diag[st.name] = {kv.key: kv.value for kv in st.values}

    def ready(self) -> None:
        assert wait_for_subscribers(self.ex, self.odom, 1, timeout=20.0)
        if self.cmd is not None:
            assert wait_for_subscribers(self.ex, self.cmd, 1, timeout=20.0)

    def run(self, seconds: float, step) -> int:
        """Call ``step(now)`` every PERIOD_NS for ``seconds``, spinning in between; the steps."""
        t_end = self.now() + int(seconds * NS_PER_S)
        due = self.now()
        steps = 0
        while (now := self.now()) < t_end:
            if now >= due:
                step(now)
                steps += 1
                due += PERIOD_NS
            self.ex.spin_once(timeout_sec=0.001)
        return steps

    def value(self, status: str, key: str) -> int:
        return int(self.diag.get(f"ekf_node: {status}", {}).get(key, "-1"))


@contextmanager
def ekf_node(ctx, tmp_path):
    h = Harness(ctx)
    cmd = [*node_command("ekf_node"), "--ros-args", "--params-file", str(REPO / "config" / "ekf.yaml")]
    with running_process(cmd, tmp_path / "ekf.log"):
        h.ready()
        assert wait_for_publishers(h.ex, h.out_sub, 1, timeout=20.0)
        yield h


def test_cmd_vel_stamped_200ms_ahead_is_rejected_and_output_never_leads(ros_context, tmp_path):
    from geometry_msgs.msg import TwistStamped

    with ekf_node(ros_context, tmp_path) as h:
        def step(now: int) -> None:
            h.odom.publish(twist_odometry(now, 0.5))
            cmd = TwistStamped()
            cmd.header.frame_id = "base_link"
            cmd.header.stamp.sec, cmd.header.stamp.nanosec = divmod(now + 200_000_000, NS_PER_S)
            cmd.twist.linear.x = 0.5
            h.cmd.publish(cmd)

        sent = h.run(3.0, step)
        assert spin_until(h.ex, lambda: h.value("cmd_vel", "received") >= 0.9 * sent, timeout=5.0), h.diag
    assert len(h.outputs) > 50
    ahead = [(s - r) / 1e6 for s, r in h.outputs if s > r]
    assert not ahead, f"{len(ahead)} outputs stamped ahead of the clock, up to {max(ahead):.1f} ms"
    # Ahead of the node's clock by 200 ms minus the delivery delay: rejected (tolerance 100 ms)
    # unless a message took over 100 ms to arrive (once in 138 on a loaded CI machine,
    # 2026-12-06), when it is rightly within the tolerance. Nothing else happens to them.
    received, future = h.value("cmd_vel", "received"), h.value("cmd_vel", "rejected_future_stamp")
    applied = h.value("cmd_vel", "applied")
    assert future + applied == received, h.diag["ekf_node: cmd_vel"]
    assert future >= 0.95 * received, (future, received)
    assert h.value("filter", "rewinds") < 5, h.diag["ekf_node: filter"]


def test_a_message_delivered_twice_is_fused_once(ros_context, tmp_path):
    with ekf_node(ros_context, tmp_path) as h:
        h.node.destroy_publisher(h.cmd)  # no cmd_vel: only the odometry

        def step(now: int) -> None:
            msg = twist_odometry(now, 0.3)
            h.odom.publish(msg)
            h.odom.publish(msg)  # the same message again (a redelivery, a second bridge)

        sent = h.run(2.0, step)

        def counted() -> bool:
            return h.value("odom0", "received") >= 1.8 * sent

        assert spin_until(h.ex, counted, timeout=5.0), h.diag.get("ekf_node: odom0")
        # the next diagnostics: every message taken
        spin_until(h.ex, lambda: False, timeout=1.2)
    received = h.value("odom0", "received")
    applied = h.value("odom0", "applied")
    duplicates = h.value("odom0", "rejected_duplicate")
    assert applied <= sent, (applied, sent)
    assert duplicates >= 0.9 * sent, (duplicates, sent)
    assert received == applied + h.value("odom0", "rejected"), h.diag["ekf_node: odom0"]


def _camera_pose(stamp_ns: int, frame_id: str):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, NS_PER_S)
    msg.pose.pose.position.x, msg.pose.pose.position.y = 0.05, -0.02
    msg.pose.pose.orientation.w = 1.0
    msg.pose.covariance = [1e-2 if i % 7 == 0 else 0.0 for i in range(36)]
    return msg


def _static_tree(node):
    """map -> odom -> base_link on /tf_static (a TF tree in which base_link is 1.6 m from map)."""
    from geometry_msgs.msg import TransformStamped
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from tf2_msgs.msg import TFMessage

    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub = node.create_publisher(TFMessage, "/tf_static", qos)
    links = []
    for parent, child, x in (("map", "odom", 1.6), ("odom", "base_link", 0.0)):
        t = TransformStamped()
        t.header.frame_id, t.child_frame_id = parent, child
        t.transform.translation.x = x
        t.transform.rotation.w = 1.0
        links.append(t)
    pub.publish(TFMessage(transforms=links))
    return pub


@pytest.mark.parametrize("default_frame", ["", "map"], ids=["no_default", "default_map"])
def test_an_empty_frame_id_is_rejected_unless_a_default_is_named(ros_context, tmp_path, default_frame):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.qos import qos_profile_sensor_data

    h = Harness(ros_context)
    h.node.destroy_publisher(h.cmd)
    h.cmd = None
    tf = _static_tree(h.node)
    cam = h.node.create_publisher(PoseWithCovarianceStamped, "camera/pose", qos_profile_sensor_data)
    cmd = [*node_command("ekf_node"), "--ros-args", "--params-file", str(REPO / "config" / "ekf.yaml")]
    if default_frame:
        cmd += ["-p", f"pose0_default_frame_id:={default_frame}"]
    with running_process(cmd, tmp_path / "ekf.log"):
        h.ready()
        assert wait_for_subscribers(h.ex, cam, 1, timeout=20.0)
        assert wait_for_subscribers(h.ex, tf, 1, timeout=20.0)

        def step(now: int) -> None:
            h.odom.publish(twist_odometry(now, 0.0))
            if (now // PERIOD_NS) % 5 == 0:
                cam.publish(_camera_pose(now, ""))  # a camera driver that leaves frame_id empty

        h.run(2.0, step)
        assert spin_until(h.ex, lambda: h.value("pose0", "received") > 5, timeout=5.0), h.diag
        spin_until(h.ex, lambda: False, timeout=1.2)  # the next diagnostics
    received = h.value("pose0", "received")
    if default_frame:  # named explicitly: taken in map, fused
        assert h.value("pose0", "rejected_no_frame") == 0
        assert h.value("pose0", "applied") == received, h.diag["ekf_node: pose0"]
    else:  # never read as base_link (1.6 m off through the tree): rejected, counted
        assert h.value("pose0", "rejected_no_frame") == received, h.diag["ekf_node: pose0"]
        assert h.value("pose0", "applied") == 0


def test_a_thousand_frame_ids_make_few_warnings_and_bounded_state(ros_context, tmp_path):
    """Case 6: camera poses each in a new frame (no transform to any of them), and /tf links to
    1500 new frames: the transform buffer keeps its 1000 newest time-stamped links."""
    from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
    from rclpy.qos import qos_profile_sensor_data
    from tf2_msgs.msg import TFMessage

    from ekf_localization.ros.tf_io import TF_QOS

    h = Harness(ros_context)
    h.node.destroy_publisher(h.cmd)
    h.cmd = None
    cam = h.node.create_publisher(PoseWithCovarianceStamped, "camera/pose", qos_profile_sensor_data)
    log = tmp_path / "ekf.log"
    cmd = [*node_command("ekf_node"), "--ros-args", "--params-file", str(REPO / "config" / "ekf.yaml")]
    frames = 0
    with running_process(cmd, log):
        h.ready()
        assert wait_for_subscribers(h.ex, cam, 1, timeout=20.0)

        def step(now: int) -> None:
            nonlocal frames
            h.odom.publish(twist_odometry(now, 0.0))
            for _ in range(5):  # 250 new frame ids a second
                cam.publish(_camera_pose(now, f"camera_{frames}"))
                frames += 1

        h.run(4.0, step)
        tf_pub = h.node.create_publisher(TFMessage, "/tf", TF_QOS)
        assert wait_for_subscribers(h.ex, tf_pub, 1, timeout=20.0)
        links = [TransformStamped() for _ in range(1500)]
        for k, t in enumerate(links):
            t.header.stamp.sec, t.header.frame_id, t.child_frame_id = 1, "map", f"tag_{k}"
            t.transform.rotation.w = 1.0
        tf_pub.publish(TFMessage(transforms=links))
        assert spin_until(h.ex, lambda: h.value("filter", "tf_frames_evicted") >= 500, timeout=5.0), \
            h.diag.get("ekf_node: filter")
        assert spin_until(h.ex, lambda: h.value("pose0", "rejected_no_transform") >= 0.9 * frames,
                          timeout=5.0), h.diag.get("ekf_node: pose0")
        spin_until(h.ex, lambda: False, timeout=1.2)  # the next diagnostics
    warnings = [line for line in log.read_text().splitlines() if "no transform" in line]
    assert frames >= 900
    assert len(warnings) <= 3, f"{len(warnings)} warnings for {frames} frame ids"
    size, cap = h.value("filter", "frame_cache_size"), h.value("filter", "frame_cache_cap")
    assert 0 < size <= cap, h.diag["ekf_node: filter"]
    assert h.value("filter", "frame_cache_evictions") >= 0.9 * frames - cap
    assert 1000 <= h.value("filter", "tf_frames") <= h.value("filter", "tf_frames_cap") == 2000


def test_diagnostics_leave_out_values_not_yet_known(ros_context, tmp_path):
    """Before any command has been checked the command guard has no statistic: its keys are left
    out of /diagnostics, and no value anywhere reads as nan or inf."""
    with ekf_node(ros_context, tmp_path) as h:
        h.node.destroy_publisher(h.cmd)  # no command: the guard never checks one
        h.run(2.5, lambda now: h.odom.publish(twist_odometry(now, 0.2)))
        assert spin_until(h.ex, lambda: "ekf_node: cmd_vel" in h.diag, timeout=5.0), h.diag
    bad = {(name, k): v for name, values in h.diag.items() for k, v in values.items()
           if v.strip().lower().lstrip("+-") in ("nan", "inf", "infinity")}
    assert not bad, f"non-finite values on /diagnostics: {bad}"
    assert "guard_nis_sum" not in h.diag["ekf_node: cmd_vel"], h.diag["ekf_node: cmd_vel"]
    assert h.diag["ekf_node: cmd_vel"]["guard_trips"] == "0"


BURST = str(REPO / "test" / "helpers" / "odometry_burst.py")


@contextmanager
def _at_the_nodes_priority():
    """This process's threads under SCHED_FIFO at config/ekf.yaml's ``thread_priority`` (the
    node's), back to the normal policy after; nothing where that is not allowed (then the node
    runs at normal priority too)."""
    import os

    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.ros.scheduling import thread_ids, use_fifo

    priority = int(parameters_from_yaml(REPO / "config" / "ekf.yaml", "ekf_node")["thread_priority"])
    raised = use_fifo(priority) is None
    try:
        yield
    finally:
        if raised:
            for tid in thread_ids():
                try:
                    os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                except OSError:  # a thread that has ended meanwhile
                    continue


def test_reset_is_answered_during_and_after_an_odometry_burst(ros_context, tmp_path):
    """20,000 odometry messages at 10 kHz from another process (several times what ekf_node
    takes, so that its queue of events grows by thousands): a call of ``reset`` every 100 ms
    during the burst, and one 2 s after it, is each answered within 100 ms. The burst is a
    process of its own, as any client is: a thread of this test would hold the GIL that the
    test's executor needs to take the answers, and a burst faster than 10 kHz would take a
    whole core of the two, which the answers then wait for. The calls are timed at the node's
    own priority: the shipped config runs ekf_node under SCHED_FIFO, and during the burst it
    takes one core whole, so a caller at normal priority shares the other with the burst and
    the other test worker and measures its own turn on the CPU."""
    import subprocess
    import sys

    from std_srvs.srv import Empty

    with ekf_node(ros_context, tmp_path) as h:
        h.node.destroy_publisher(h.cmd)
        client = h.node.create_client(Empty, "ekf_node/reset")
        assert client.wait_for_service(timeout_sec=10.0)
        calls: list[list] = []  # [when, sent, answered] (time.monotonic() s; answered None: not yet)

        def call(when: str) -> None:
            record = [when, time.monotonic(), None]
            calls.append(record)
            client.call_async(Empty.Request()).add_done_callback(
                lambda _f, r=record: r.__setitem__(2, time.monotonic()))

        call("idle")  # the first call also sets up the reply path
        assert spin_until(h.ex, lambda: calls[-1][2] is not None, timeout=5.0)
        burst = subprocess.Popen([sys.executable, BURST, "20000", "10000.0"],  # at normal priority
                                 stdout=subprocess.PIPE, text=True)
        try:
            with _at_the_nodes_priority():
                assert burst.stdout.readline().strip() == "burst"
                while burst.poll() is None:
                    call("burst")
                    spin_until(h.ex, lambda: burst.poll() is not None, timeout=0.1, step=0.001)
                done = burst.stdout.read().split()
                spin_until(h.ex, lambda: False, timeout=2.0, step=0.001)
                call("2 s after")
                spin_until(h.ex, lambda: all(c[2] is not None for c in calls), timeout=2.0, step=0.001)
        finally:
            if burst.poll() is None:
                burst.kill()
            burst.wait(timeout=5)
    waits = [(when, None if answered is None else round((answered - sent) * 1e3, 1))
             for when, sent, answered in calls]
    print(f"burst of 20000: {done}; reset answered after (ms): {waits}")
    assert burst.returncode == 0 and done[0] == "done", done
    assert sum(when == "burst" for when, _ in waits) >= 3, waits
    slow = [(when, ms) for when, ms in waits[1:] if ms is None or ms > 100.0]
    assert not slow, f"{len(slow)} of {len(waits) - 1} calls answered after 100 ms or not (None): {waits}"


def test_an_empty_frame_id_gets_one_outcome_with_a_complete_tree(ros_context, tmp_path):
    """50 camera poses with an empty frame_id while map -> odom -> base_link -> camera_link is
    on /tf_static: every one is rejected as no_frame (no pose0_default_frame_id), none applied."""
    from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
    from rclpy.qos import qos_profile_sensor_data
    from tf2_msgs.msg import TFMessage

    h = Harness(ros_context)
    h.node.destroy_publisher(h.cmd)
    h.cmd = None
    tf = _static_tree(h.node)
    camera = TransformStamped()
    camera.header.frame_id, camera.child_frame_id = "base_link", "camera_link"
    camera.transform.translation.x, camera.transform.rotation.w = 0.1, 1.0
    cam = h.node.create_publisher(PoseWithCovarianceStamped, "camera/pose", qos_profile_sensor_data)
    cmd = [*node_command("ekf_node"), "--ros-args", "--params-file", str(REPO / "config" / "ekf.yaml")]
    sent = 0
    with running_process(cmd, tmp_path / "ekf.log"):
        h.ready()
        assert wait_for_subscribers(h.ex, cam, 1, timeout=20.0)
        assert wait_for_subscribers(h.ex, tf, 1, timeout=20.0)
        tf.publish(TFMessage(transforms=[camera]))

        def step(now: int) -> None:
            nonlocal sent
            h.odom.publish(twist_odometry(now, 0.0))
            if (now // PERIOD_NS) % 2 == 0 and sent < 50:
                cam.publish(_camera_pose(now, ""))
                sent += 1

        h.run(2.5, step)
        assert spin_until(h.ex, lambda: h.value("pose0", "received") >= 45, timeout=5.0), h.diag
        spin_until(h.ex, lambda: False, timeout=1.2)  # the next diagnostics
    pose0 = h.diag["ekf_node: pose0"]
    received = h.value("pose0", "received")  # best effort (sensor data QoS): one may be lost
    assert sent == 50 and 45 <= received <= 50, pose0
    assert h.value("pose0", "rejected_no_frame") == received and h.value("pose0", "applied") == 0, pose0
