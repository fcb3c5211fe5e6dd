"""The nodes of ``launch/ekf_localization.launch.py`` and their parameters, in one place.

The launch file turns these specs into ``launch_ros`` Nodes; the launch test starts exactly
the same processes (:meth:`NodeSpec.command`) over real DDS, since ``launch`` is not on
PyPI. No ROS imports here.

* ``use_sim`` (default true): start sim_node with ``sim_params``; false: the robot's drivers
  publish the inputs and consume ``cmd_vel``.
* ``use_sim_time`` follows ``use_sim`` unless given. With simulated time the simulator
  publishes ``/clock`` (``publish_clock: true`` is set on it), so the other nodes run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

PACKAGE = "ekf_localization"
ARGUMENTS: dict[str, str] = {  # launch argument -> description
    "use_sim": "start sim_node (false on a real robot: its drivers publish the inputs)",
    "use_sim_time": "run on /clock (default: the value of use_sim; sim_node then publishes /clock)",
    "sim_params": "sim_node parameter file",
    "ekf_params": "ekf_node parameter file",
    "pure_pursuit_params": "pure_pursuit_node parameter file",
    "path_file": "path for pure_pursuit_node to follow",
}


@dataclass(frozen=True)
class NodeSpec:
    """One node: executable, node name, parameter files (in order) and parameter overrides."""

    executable: str
    name: str
    param_files: tuple[str, ...]
    overrides: dict[str, object] = field(default_factory=dict)

    def command(self, executable_path: list[str] | None = None) -> list[str]:
        """The process a launch_ros Node with these settings runs (``ros2 run`` form)."""
        args = list(executable_path or [self.executable]) + ["--ros-args", "-r", f"__node:={self.name}"]
        for path in self.param_files:
            args += ["--params-file", path]
        for key, value in self.overrides.items():
            args += ["-p", f"{key}:={_yaml(value)}"]
        return args


def _yaml(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _flag(value: str | bool | None, name: str) -> bool | None:
    if value is None or value == "":
        return None
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "1", "yes", "on"):
        return True
    if text in ("false", "0", "no", "off"):
        return False
    raise ValueError(f"launch argument '{name}': expected true or false, got {value!r}")


def default_arguments(share_dir: str) -> dict[str, str]:
    """Default value of each launch argument ('' = derived: use_sim_time follows use_sim)."""
    config = os.path.join(share_dir, "config")
    return {"use_sim": "true", "use_sim_time": "",
            "sim_params": os.path.join(config, "sim.yaml"),
            "ekf_params": os.path.join(config, "ekf.yaml"),
            "pure_pursuit_params": os.path.join(config, "pure_pursuit.yaml"),
            "path_file": os.path.join(config, "paths", "seed000_test_path.yaml")}


def node_specs(share_dir: str, **arguments: str | bool) -> list[NodeSpec]:
    """The nodes to start for these launch arguments (unknown names are an error)."""
    unknown = set(arguments) - set(ARGUMENTS)
    if unknown:
        raise ValueError(f"unknown launch arguments {sorted(unknown)}; known: {sorted(ARGUMENTS)}")
    a = {**default_arguments(share_dir), **{k: v for k, v in arguments.items() if v is not None}}
    use_sim = _flag(a["use_sim"], "use_sim")
    use_sim_time = _flag(a["use_sim_time"], "use_sim_time")
    if use_sim_time is None:
        use_sim_time = bool(use_sim)
    clock = {"use_sim_time": use_sim_time}
    nodes = []
    if use_sim:
        # the clock's source runs on wall time; it publishes /clock when the others use it
        nodes.append(NodeSpec("sim_node", "sim_node", (str(a["sim_params"]),),
                              {"publish_clock": use_sim_time}))
    nodes.append(NodeSpec("ekf_node", "ekf_node", (str(a["ekf_params"]),), dict(clock)))
    nodes.append(NodeSpec("pure_pursuit_node", "pure_pursuit_node", (str(a["pure_pursuit_params"]),),
                          {**clock, "path_file": str(a["path_file"])}))
    return nodes
