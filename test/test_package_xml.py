"""package.xml names only rosdep keys that resolve for ROS 2 Jazzy on Ubuntu 24.04."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from helpers.ros_helpers import REPO

# Jazzy packages (rosdistro jazzy/distribution.yaml) and the system keys checked in rosdistro's
# rosdep/python.yaml (each has an unconditional ubuntu entry). Not keys: ament_python (a build
# type, no package); python3-numba (ubuntu: bionic and focal only); rosbags (no key).
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "ament_index_python", "builtin_interfaces", "std_msgs",
                "nav_msgs", "geometry_msgs", "sensor_msgs", "std_srvs", "diagnostic_msgs", "rosgraph_msgs",
                "tf2_msgs", "visualization_msgs", "launch", "launch_ros", "ament_flake8"}
SYSTEM_KEYS = {"python3-numpy", "python3-scipy", "python3-matplotlib", "python3-yaml", "python3-pytest"}
DEPENDS = ("depend", "build_depend", "buildtool_depend", "exec_depend", "test_depend", "build_export_depend")


def test_every_dependency_is_a_resolvable_key() -> None:
    root = ET.parse(REPO / "package.xml").getroot()
    keys = [e.text.strip() for tag in DEPENDS for e in root.iter(tag)]
    assert keys and set(keys) <= ROS_PACKAGES | SYSTEM_KEYS, sorted(set(keys) - ROS_PACKAGES - SYSTEM_KEYS)
    assert root.find("export/build_type").text == "ament_python"


def test_imported_ros_packages_are_declared() -> None:
    """Every ROS package the code imports is an exec_depend (ament_index_python was missing)."""
    import re

    root = ET.parse(REPO / "package.xml").getroot()
    declared = {e.text.strip() for e in root.iter("exec_depend")}
    sources = [p for d in ("ekf_localization", "sim_robot", "launch") for p in (REPO / d).rglob("*.py")]
    imported = set()
    for path in sources:
        imported |= set(re.findall(r"^\s*(?:from|import) (\w+)", path.read_text(), re.M))
    assert (imported & ROS_PACKAGES) <= declared, sorted((imported & ROS_PACKAGES) - declared)
