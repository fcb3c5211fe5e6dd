"""ekf_node's and pure_pursuit_node's MarkerArray over real DDS (publish_markers).

The test publishes camera fixes itself (some far from the estimate, so gated) and odometry
for the follower, and checks what the markers draw against what the nodes publish.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from helpers.ros_helpers import REPO, node_command, running_process, spin_until, wait_for_subscribers

from ekf_localization.core.ellipse import chi2_2dof_quantile
from ekf_localization.ros import markers

pytestmark = [pytest.mark.ros, pytest.mark.slow]
CONFIG = [True, True, False, False, False, True] + [False] * 9
NEAR, FAR = (0.5, 0.2), (2.0, -1.0)


def _node(ros_context, name: str):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    node = Node(name, context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    return node, ex


def _fix(node, xy: tuple[float, float], var: float = 1e-4):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = "map"
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.pose.pose.position.x, msg.pose.pose.position.y = xy
    msg.pose.pose.orientation.w = 1.0
    cov = np.zeros(36)
    cov[0] = cov[7] = var
    cov[14] = cov[21] = cov[28] = 1e-3
    cov[35] = 1e-3
    msg.pose.covariance = cov.tolist()
    return msg


def test_ekf_node_markers(ros_context, tmp_path) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from visualization_msgs.msg import MarkerArray

    params = {"model": "mecanum", "frequency": 30.0, "world_frame": "map", "publish_tf": False,
              "pose0": "camera/pose", "pose0_config": CONFIG, "pose0_rejection_threshold": 3.0,
              "publish_markers": True, "marker_frequency": 20.0, "marker_fix_count": 50}
    path = tmp_path / "ekf.yaml"
    path.write_text(yaml.safe_dump({"ekf_node": {"ros__parameters": params}}))
    node, ex = _node(ros_context, "marker_test")
    got: dict[str, object] = {}
    pub = node.create_publisher(PoseWithCovarianceStamped, "camera/pose", 10)
    node.create_subscription(MarkerArray, markers.EKF_MARKER_TOPIC_OUTSIDE,
                             lambda m: got.__setitem__("markers", m), 10)
    odoms: dict[tuple[int, int], Odometry] = {}  # by stamp

    def on_odom(m) -> None:
        got["odom"] = m
        odoms[(m.header.stamp.sec, m.header.stamp.nanosec)] = m

    node.create_subscription(Odometry, "odometry/filtered", on_odom, 10)
    nis: list[dict[str, str]] = []  # pose0's diagnostic values with a NIS of the last period

    def on_diag(msg) -> None:
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            if st.name == "ekf_node: pose0" and values.get("nis_pose", "none") != "none":
                nis.append(values)

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    with running_process(node_command("ekf_node") + ["--ros-args", "--params-file", str(path)],
                         tmp_path / "ekf.log"):
        assert wait_for_subscribers(ex, pub, timeout=20.0), (tmp_path / "ekf.log").read_text()
        for _ in range(8):
            pub.publish(_fix(node, NEAR))
            spin_until(ex, lambda: False, timeout=0.05)
        pub.publish(_fix(node, FAR))

        def drawn() -> bool:
            m = got.get("markers")
            return m is not None and bool(markers.points_of(m, markers.NS_FIXES_GATED))

        assert spin_until(ex, drawn, timeout=10.0), (tmp_path / "ekf.log").read_text()[-2000:]
        accepted = markers.points_of(got["markers"], markers.NS_FIXES_ACCEPTED)
        gated = markers.points_of(got["markers"], markers.NS_FIXES_GATED)
        # best effort (sensor data QoS): a fix may be lost on a loaded machine, none invented
        assert 1 <= len(accepted) <= 8 and all(np.allclose(p, NEAR) for p in accepted)
        assert gated == [FAR]
        # the ellipse: the 95 % contour of the published x-y covariance around the estimate
        got.pop("markers")

        def ellipse_stamp() -> tuple[int, int] | None:
            m = got.get("markers")
            el = [k for k in (m.markers if m else ()) if k.ns == markers.NS_ELLIPSE]
            return (el[0].header.stamp.sec, el[0].header.stamp.nanosec) if el else None

        # the ellipse is stamped as the estimate it is drawn from: the output of that stamp
        assert spin_until(ex, lambda: ellipse_stamp() in odoms, timeout=5.0)
        odom = odoms[ellipse_stamp()]
        ring = np.array(markers.points_of(got["markers"], markers.NS_ELLIPSE))
        centre = np.array([odom.pose.pose.position.x, odom.pose.pose.position.y])
        cov = np.asarray(odom.pose.covariance).reshape(6, 6)[:2, :2]
        d = ring[:-1] - centre
        d2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
        np.testing.assert_allclose(d2, chi2_2dof_quantile(0.95), rtol=0.05)
        # the diagnostics carry the period's mean NIS of the fixes (the gated one's is huge)
        assert spin_until(ex, lambda: bool(nis), timeout=5.0)
        assert nis[0]["nis_pose_dof"] == "3" and float(nis[0]["nis_pose"]) > 0.0


def test_pure_pursuit_node_markers(ros_context, tmp_path) -> None:
    from nav_msgs.msg import Odometry
    from visualization_msgs.msg import MarkerArray

    from ekf_localization.control.field_path import load_path

    node, ex = _node(ros_context, "pp_marker_test")
    got: dict[str, object] = {}
    pub = node.create_publisher(Odometry, "odometry/filtered", 10)
    node.create_subscription(MarkerArray, markers.PURE_PURSUIT_MARKER_TOPIC,
                             lambda m: got.__setitem__("markers", m), 10)
    cmd = node_command("pure_pursuit_node") + [
        "--ros-args", "--params-file", str(REPO / "config" / "pure_pursuit.yaml"),
        "-p", "publish_markers:=true", "-p", "marker_frequency:=20.0", "-p", "lookahead_distance:=0.25"]
    path = load_path(REPO / "config" / "paths" / "seed000_test_path.yaml")
    x0, y0 = float(path.xs[0]), float(path.ys[0])

    def odom() -> Odometry:
        m = Odometry()
        m.header.frame_id = "map"
        m.header.stamp = node.get_clock().now().to_msg()
        m.pose.pose.position.x, m.pose.pose.position.y = x0, y0
        m.pose.pose.orientation.w = 1.0
        return m

    def with_target() -> bool:
        pub.publish(odom())
        m = got.get("markers")
        return m is not None and bool(markers.points_of(m, markers.NS_TARGET))

    with running_process(cmd, tmp_path / "pp.log"):
        assert wait_for_subscribers(ex, pub, timeout=20.0), (tmp_path / "pp.log").read_text()
        assert spin_until(ex, with_target, timeout=10.0), (tmp_path / "pp.log").read_text()[-2000:]
    m = got["markers"]
    line = np.array(markers.points_of(m, markers.NS_PATH))
    np.testing.assert_allclose(line, np.column_stack([path.xs, path.ys]), atol=1e-9)
    ring = np.array(markers.points_of(m, markers.NS_LOOKAHEAD))
    np.testing.assert_allclose(np.hypot(ring[:, 0] - x0, ring[:, 1] - y0), 0.25, rtol=1e-9)
    (tx, ty), = markers.points_of(m, markers.NS_TARGET)
    assert math.hypot(tx - x0, ty - y0) == pytest.approx(0.25, abs=0.05)


def test_shipped_rviz_and_foxglove_layouts_show_the_markers() -> None:
    """config/field_view.rviz and config/foxglove_layout.json name the topics and namespaces the
    nodes publish (ros/markers.py), on the map frame."""
    import json

    rviz = yaml.safe_load((REPO / "config" / "field_view.rviz").read_text())
    vm = rviz["Visualization Manager"]
    assert vm["Global Options"]["Fixed Frame"] == "map"
    arrays = {d["Topic"]["Value"]: d for d in vm["Displays"]
              if d["Class"] == "rviz_default_plugins/MarkerArray"}
    assert set(arrays) == {"/" + markers.EKF_MARKER_TOPIC_OUTSIDE, "/" + markers.PURE_PURSUIT_MARKER_TOPIC,
                           "/" + markers.TAG_LOCALIZER_MARKER_TOPIC_OUTSIDE}
    assert set(arrays["/" + markers.TAG_LOCALIZER_MARKER_TOPIC_OUTSIDE]["Namespaces"]) == {
        markers.NS_CAMERA_FOV, markers.NS_TAGS_SEEN}
    assert set(arrays["/" + markers.EKF_MARKER_TOPIC_OUTSIDE]["Namespaces"]) == {
        markers.NS_ELLIPSE, markers.NS_FIXES_ACCEPTED, markers.NS_FIXES_GATED}
    assert set(arrays["/" + markers.PURE_PURSUIT_MARKER_TOPIC]["Namespaces"]) == {
        markers.NS_PATH, markers.NS_LOOKAHEAD, markers.NS_TARGET}
    fox = json.loads((REPO / "config" / "foxglove_layout.json").read_text())
    panel = fox["configById"]["3D!field"]
    assert panel["followTf"] == "map"
    ekf_topic = "/" + markers.EKF_MARKER_TOPIC_OUTSIDE
    assert {ekf_topic, "/" + markers.PURE_PURSUIT_MARKER_TOPIC,
            "/" + markers.TAG_LOCALIZER_MARKER_TOPIC_OUTSIDE} <= set(panel["topics"])
    ids = json.dumps(fox["layout"])
    assert all(k in ids for k in fox["configById"])
