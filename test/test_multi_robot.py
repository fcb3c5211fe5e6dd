"""Two simulated robots (sim.launch.py with namespace:=r1 / r2, frame_prefix:=r1/ / r2/) on one
ROS domain: each robot's nodes publish and subscribe only in their own namespace (besides /tf,
/tf_static, /diagnostics), each estimate is of its own robot's frames, and /tf carries both trees
apart."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.launch_runner import alive, launch_problem, launched, layout_prefix, started
from helpers.ros_helpers import spin_until

ROBOTS = ("r1", "r2")
NODES = {"sim_node", "ekf_node", "pure_pursuit_node"}
SHARED = {"/tf", "/tf_static", "/diagnostics", "/rosout", "/parameter_events", "/clock"}

pytestmark = [pytest.mark.ros, pytest.mark.slow]


@pytest.fixture(scope="module")
def prefix(tmp_path_factory) -> Path:
    problem = launch_problem()
    if problem:
        pytest.skip(problem)
    return layout_prefix(tmp_path_factory.mktemp("install"))


def _endpoints(node, ns: str, name: str) -> set[str]:
    """Every topic the node ``ns/name`` publishes or subscribes."""
    pubs = node.get_publisher_names_and_types_by_node(name, ns)
    subs = node.get_subscriber_names_and_types_by_node(name, ns)
    return {t for t, _ in pubs} | {t for t, _ in subs}


def test_two_namespaced_robots_do_not_see_each_other(prefix, ros_context, tmp_path) -> None:
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from tf2_msgs.msg import TFMessage

    from ekf_localization.ros.tf_io import TF_QOS

    node = Node("multi_robot_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    odom: dict[str, list[Odometry]] = {r: [] for r in ROBOTS}
    for r in ROBOTS:
        node.create_subscription(Odometry, f"/{r}/odometry/filtered", odom[r].append, 10)
    links: set[tuple[str, str]] = set()
    node.create_subscription(TFMessage, "/tf", lambda m: links.update(
        (t.header.frame_id, t.child_frame_id) for t in m.transforms), TF_QOS)
    # wall time: two simulators publishing /clock on one domain would mix their clocks
    with launched(prefix, tmp_path, "sim.launch.py", "r1", namespace="r1", frame_prefix="r1/",
                  use_sim_time="false") as log1, \
            launched(prefix, tmp_path, "sim.launch.py", "r2", namespace="r2", frame_prefix="r2/",
                     use_sim_time="false") as log2:
        logs = {"r1": log1, "r2": log2}

        def tails() -> str:
            return "\n".join(f"--- {r}\n{logs[r].read_text()[-2500:]}" for r in ROBOTS)

        names = lambda: set(node.get_node_names_and_namespaces())  # noqa: E731
        want = {(n, f"/{r}") for n in NODES for r in ROBOTS}
        ok = spin_until(ex, lambda: all(set(started(logs[r])) == NODES for r in ROBOTS)
                        and want <= names() and all(len(odom[r]) >= 10 for r in ROBOTS)
                        and {("map", "r1/odom"), ("r1/odom", "r1/base_link"), ("map", "r2/odom"),
                             ("r2/odom", "r2/base_link")} <= links, timeout=240.0, step=0.1)
        assert ok, (sorted(names()), {r: len(odom[r]) for r in ROBOTS}, sorted(links), tails())
        assert all(alive(p) for r in ROBOTS for p in started(logs[r]).values()), tails()

        # what each robot's nodes can see: their own namespace and the shared topics only
        for r in ROBOTS:
            for n in NODES:
                seen = _endpoints(node, f"/{r}", n)
                assert seen, (r, n)
                foreign = {t for t in seen if not t.startswith(f"/{r}/")} - SHARED
                assert not foreign, (r, n, sorted(foreign))
                services = {s for s, _ in node.get_service_names_and_types_by_node(n, f"/{r}")}
                assert services and all(s.startswith(f"/{r}/{n}/") for s in services - {f"/{r}/set_pose"}), \
                    (r, n, sorted(services))
        # every endpoint on a robot's topics belongs to that robot (or to this probe)
        topics = {t for t, _ in node.get_topic_names_and_types()}
        for r in ROBOTS:
            for t in (t for t in topics if t.startswith(f"/{r}/")):
                for info in (*node.get_publishers_info_by_topic(t), *node.get_subscriptions_info_by_topic(t)):
                    assert info.node_namespace == f"/{r}" or info.node_name == "multi_robot_probe", (t, info)
        assert {t for t in topics if not t.startswith(("/r1/", "/r2/"))} <= SHARED, sorted(topics)
        assert not node.get_publishers_info_by_topic("/clock")
        assert not any("has no section for this node" in logs[r].read_text() for r in ROBOTS), tails()
    for r in ROBOTS:
        est = odom[r][-1]
        assert (est.header.frame_id, est.child_frame_id) == ("map", f"{r}/base_link")
    assert not {("map", "odom"), ("odom", "base_link")} & links, sorted(links)  # no unprefixed frames
