"""Every topic and service name the nodes create is relative or private, except /tf, /tf_static,
/clock and /diagnostics, so ``namespace:=r1`` moves all of a robot's traffic under /r1 (read from
the sources with ast; test_multi_robot.py checks the running graph)."""

from __future__ import annotations

import ast

from helpers.ros_helpers import REPO

NODE_SOURCES = ("ekf_localization/nodes/ekf_node.py", "ekf_localization/nodes/pure_pursuit_node.py",
                "sim_robot/ros/sim_node.py", "ekf_localization/tools/field_view.py",
                "ekf_localization/ros/tf_io.py")
CONSTANTS = ("ekf_localization/ros/markers.py",)  # topic names other modules use
GLOBAL = {"/tf", "/tf_static", "/clock", "/diagnostics"}
CREATE = {"create_publisher", "create_subscription", "create_service", "create_client"}


def _string_constants(path: str) -> dict[str, str]:
    tree = ast.parse((REPO / path).read_text())
    return {t.id: n.value.value for n in tree.body if isinstance(n, ast.Assign)
            and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str)
            for t in n.targets if isinstance(t, ast.Name)}


def names_created() -> dict[str, list[str]]:
    """file -> the name argument of each create_* call (constants resolved; '?' when computed)."""
    shared = {f"markers.{k}": v for path in CONSTANTS for k, v in _string_constants(path).items()}
    out: dict[str, list[str]] = {}
    for path in NODE_SOURCES:
        local = _string_constants(path)
        for n in ast.walk(ast.parse((REPO / path).read_text())):
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr in CREATE \
                    and len(n.args) >= 2:
                arg = n.args[1]
                if isinstance(arg, ast.Constant):
                    name = arg.value
                elif isinstance(arg, ast.Name):
                    name = local.get(arg.id, "?")
                elif isinstance(arg, ast.Attribute):
                    name = shared.get(ast.unparse(arg), "?")
                else:
                    name = "?"
                out.setdefault(path, []).append(name)
    return out


def test_every_created_name_is_relative_or_private() -> None:
    created = names_created()
    assert set(created) == set(NODE_SOURCES)
    absolute = {p: [n for n in names if isinstance(n, str) and n.startswith("/") and n not in GLOBAL]
                for p, names in created.items()}
    assert not any(absolute.values()), absolute
    everything = {n for names in created.values() for n in names}
    assert {"~/reset", "~/markers", "set_pose", "odometry/filtered"} <= everything


def test_the_shipped_yamls_name_relative_topics() -> None:
    """The '?' above are topic parameters (inputs, odom_topic, ...): relative in every shipped YAML."""
    import re

    from ekf_localization.ros.parameters import read_parameter_yaml

    topic = re.compile(r"^((odom|pose|twist|imu|joint)\d+|\w*_topic)$")
    seen = 0
    for path in sorted((REPO / "config").glob("*.yaml")):
        for body in read_parameter_yaml(path).values():
            for name, value in body["ros__parameters"].items():
                if topic.match(name) and isinstance(value, str) and value:
                    seen += 1
                    assert not value.startswith("/"), (path.name, name, value)
    assert seen >= 10
