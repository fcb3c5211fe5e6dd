"""package.xml declares a rosdep key for every module the code imports at run time, and only keys
that resolve for ROS 2 Jazzy on Ubuntu 24.04 (noble).

The imports of ekf_localization/, sim_robot/ and seed_experiments/ are read with ast (function-level
ones too) and mapped to keys through :data:`ROSDEP_KEYS`: a new third-party import without an entry
fails here, and so does an imported module whose key package.xml does not declare."""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET

from helpers.ros_helpers import REPO

from ekf_localization.ros.extras import EXTRAS

SCANNED = ("ekf_localization", "sim_robot", "seed_experiments")  # what setup.py installs
# Jazzy packages: each is released in rosdistro's jazzy/distribution.yaml (ament_index_python and
# ament_flake8 looked up there; the rest are ros_base's core packages: rclpy, rcl_interfaces
# (builtin_interfaces, rosgraph_msgs), common_interfaces, geometry2 (tf2_msgs), launch, launch_ros).
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "ament_index_python", "builtin_interfaces", "std_msgs",
                "nav_msgs", "geometry_msgs", "sensor_msgs", "std_srvs", "diagnostic_msgs", "rosgraph_msgs",
                "tf2_msgs", "visualization_msgs", "launch", "launch_ros", "ament_flake8"}
# System keys, each looked up in rosdistro's rosdep/python.yaml (read at commit 000730dc5f91): an
# unconditional ubuntu entry, so they resolve on noble. Not keys there: python3-numba (ubuntu:
# bionic and focal only), anything for rosbags (no entry at all; only rosbag-metadata-pip).
SYSTEM_KEYS = {
    "python3-numpy": "ubuntu: [python3-numpy]",
    "python3-scipy": "ubuntu: [python3-scipy]",
    "python3-matplotlib": "ubuntu: [python3-matplotlib]",
    "python3-yaml": "ubuntu: [python3-yaml]",
    "python3-aiohttp": "ubuntu: [python3-aiohttp]",
    "python3-opencv": "ubuntu: [python3-opencv]",
    # a pip key (rosdep installs it with pip): "ubuntu: pip: [dt-apriltags]"
    "python-dt-apriltags-pip": "ubuntu: pip: [dt-apriltags]",
    "python3-pytest": "ubuntu: [python3-pytest]",
    "python3-pytest-timeout": "ubuntu: [python3-pytest-timeout]",
}
# imported top-level module -> its rosdep key; None: no key resolves on noble, an optional extra
# whose tools say what to install (ekf_localization/ros/extras.py)
ROSDEP_KEYS: dict[str, str | None] = {
    **{name: name for name in ROS_PACKAGES - {"ament_flake8"}},
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "matplotlib": "python3-matplotlib",
    "yaml": "python3-yaml",
    "aiohttp": "python3-aiohttp",
    "cv2": "python3-opencv",
    "dt_apriltags": "python-dt-apriltags-pip",
    "rosbags": None,
}
# numba (and llvmlite) are no run-time dependency any more: not in the table, so an import fails here
DEPENDS = ("depend", "build_depend", "buildtool_depend", "exec_depend", "test_depend", "build_export_depend")


def _root() -> ET.Element:
    return ET.parse(REPO / "package.xml").getroot()


def _declared(*tags: str) -> set[str]:
    root = _root()
    return {e.text.strip() for tag in tags for e in root.iter(tag)}


def imported_modules() -> dict[str, set[str]]:
    """Third-party top-level module -> the files of SCANNED importing it (stdlib and own left out)."""
    own = {p.parent.name for p in REPO.glob("*/__init__.py")}
    found: dict[str, set[str]] = {}
    for package in SCANNED:
        for path in sorted((REPO / package).rglob("*.py")):  # an absent package: none
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top not in own:
                        found.setdefault(top, set()).add(str(path.relative_to(REPO)))
    return found


def test_every_import_has_a_mapping() -> None:
    unmapped = {m: sorted(files) for m, files in imported_modules().items() if m not in ROSDEP_KEYS}
    assert not unmapped, (f"imports without a rosdep key in ROSDEP_KEYS: {unmapped}; add the module's key "
                          "(verified in rosdistro) here and to package.xml")


def test_every_imported_module_with_a_key_is_declared() -> None:
    run = _declared("depend", "exec_depend")
    imported = imported_modules()
    missing = {m: ROSDEP_KEYS[m] for m in imported if ROSDEP_KEYS.get(m) and ROSDEP_KEYS[m] not in run}
    assert not missing, f"imported, but their keys are not exec_depends in package.xml: {missing}"


def test_modules_without_a_key_are_extras_the_tools_explain() -> None:
    assert {m for m, key in ROSDEP_KEYS.items() if key is None} <= set(EXTRAS)
    assert not {"numba", "llvmlite"} & set(ROSDEP_KEYS) and "python3-numba" not in _declared(*DEPENDS)


def test_every_dependency_is_a_resolvable_key() -> None:
    keys = _declared(*DEPENDS)
    assert keys and keys <= ROS_PACKAGES | set(SYSTEM_KEYS), sorted(keys - ROS_PACKAGES - set(SYSTEM_KEYS))
    assert _root().find("export/build_type").text == "ament_python"


def test_the_mapping_catches_a_new_import(tmp_path, monkeypatch) -> None:
    """The scan sees function-level imports too: a module the table lacks is reported."""
    pkg = tmp_path / "ekf_localization"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "x.py").write_text("def f():\n    import requests.adapters\n    from numpy import array\n")
    monkeypatch.setattr(sys.modules[__name__], "REPO", tmp_path)
    found = imported_modules()
    assert set(found) == {"requests", "numpy"} and "requests" not in ROSDEP_KEYS
