"""package.xml declares a rosdep key for every module the code imports at run time, and only keys
that resolve for ROS 2 Jazzy on Ubuntu 24.04 (noble).

The imports of ekf_localization/, sim_robot/ and seed_experiments/ are read with ast (function-level
ones too) and mapped to keys through :data:`ROSDEP_KEYS`: a new third-party import without an entry
fails here, and so does an imported module whose key package.xml does not declare. Every key is
checked against a snapshot of ros/rosdistro in ../shared/reference/rosdistro (skipped without it)."""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml
from helpers.ros_helpers import REPO

from ekf_localization.ros.extras import EXTRAS

SCANNED = ("ekf_localization", "sim_robot", "seed_experiments")  # what setup.py installs
# Jazzy packages: each is released in rosdistro's jazzy/distribution.yaml (ament_index_python and
# ament_flake8 looked up there; the rest are ros_base's core packages: rclpy, rcl_interfaces
# (builtin_interfaces, rosgraph_msgs), common_interfaces, geometry2 (tf2_msgs), launch, launch_ros).
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "ament_index_python", "builtin_interfaces", "std_msgs",
                "nav_msgs", "geometry_msgs", "sensor_msgs", "std_srvs", "diagnostic_msgs", "rosgraph_msgs",
                "tf2_msgs", "visualization_msgs", "launch", "launch_ros", "ament_flake8"}
# System keys, each with an ubuntu entry for noble in rosdistro's rosdep/python.yaml
# (test_every_key_resolves_in_the_rosdistro_snapshot checks every key against a snapshot).
SYSTEM_KEYS = {
    "python3-numpy": "ubuntu: [python3-numpy]",
    "python3-scipy": "ubuntu: [python3-scipy]",
    "python3-matplotlib": "ubuntu: [python3-matplotlib]",
    "python3-yaml": "ubuntu: [python3-yaml]",
    "python3-aiohttp": "ubuntu: [python3-aiohttp]",
    "python3-opencv": "ubuntu: [python3-opencv]",
    # a pip key (rosdep installs it with pip): "ubuntu: pip: [dt-apriltags]"
    "python-dt-apriltags-pip": "ubuntu: pip: [dt-apriltags]",
    "python3-rosbags-pip": "ubuntu: pip: packages: [rosbags]",
    "python3-pytest": "ubuntu: [python3-pytest]",
    "python3-pytest-timeout": "ubuntu: [python3-pytest-timeout]",
}
# imported top-level module -> its rosdep key (the optional extras of ekf_localization/ros/extras.py
# included: declared as exec_depends, so rosdep installs them, and their tools still say what to install)
ROSDEP_KEYS: dict[str, str] = {
    **{name: name for name in ROS_PACKAGES - {"ament_flake8"}},
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "matplotlib": "python3-matplotlib",
    "yaml": "python3-yaml",
    "aiohttp": "python3-aiohttp",
    "cv2": "python3-opencv",
    "dt_apriltags": "python-dt-apriltags-pip",
    "rosbags": "python3-rosbags-pip",
}
# optional extras that no rosdep rule covers (checked against the snapshot below): package.xml names each
# in a comment instead of an exec_depend, with how to install it
NO_ROSDEP_KEY: dict[str, str] = {"ntcore": "pyntcore"}
# numba (and llvmlite) are no run-time dependency any more: not in the table, so an import fails here
# a snapshot of ros/rosdistro (its README names the commit): rosdep's base.yaml and python.yaml
# and jazzy/distribution.yaml, flat as jazzy-distribution.yaml or in rosdistro's own layout
ROSDISTRO = REPO.parent / "shared" / "reference" / "rosdistro"
UBUNTU = "noble"  # Jazzy's Ubuntu, 24.04
INSTALLERS = {"apt", "pip", "source"}
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
    unmapped = {m: sorted(files) for m, files in imported_modules().items()
                if m not in ROSDEP_KEYS and m not in NO_ROSDEP_KEY}
    assert not unmapped, (f"imports without a rosdep key in ROSDEP_KEYS: {unmapped}; add the module's key "
                          "(verified in rosdistro) here and to package.xml")


def test_every_imported_module_with_a_key_is_declared() -> None:
    run = _declared("depend", "exec_depend")
    imported = imported_modules()
    missing = {m: ROSDEP_KEYS[m] for m in imported if m in ROSDEP_KEYS and ROSDEP_KEYS[m] not in run}
    assert not missing, f"imported, but their keys are not exec_depends in package.xml: {missing}"


def test_the_optional_extras_have_declared_keys() -> None:
    run = _declared("depend", "exec_depend")
    keyed = set(EXTRAS) - set(NO_ROSDEP_KEY)
    assert {m: ROSDEP_KEYS.get(m) for m in keyed if ROSDEP_KEYS.get(m) not in run} == {}
    assert set(NO_ROSDEP_KEY) <= set(EXTRAS) and not set(NO_ROSDEP_KEY) & set(ROSDEP_KEYS)


def test_extras_without_a_key_are_named_in_package_xml() -> None:
    """An extra with no rosdep rule is said so in package.xml (a comment naming its pip package)."""
    comments = "".join(c.text or "" for c in ET.parse(REPO / "package.xml",
                                                      ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
                       .getroot().iter(ET.Comment))
    assert all(f"pip install {pip}" in comments for pip in NO_ROSDEP_KEY.values()), comments
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


def _rosdistro_snapshot(folder: Path) -> tuple[dict, set[str]]:
    """(rosdep rules by key, the package names released in Jazzy) from a rosdistro snapshot."""
    rules: dict = {}
    for path in sorted([*folder.glob("*.yaml"), *folder.glob("rosdep/*.yaml")]):
        if path.name not in ("jazzy-distribution.yaml", "distribution.yaml"):
            rules.update(yaml.safe_load(path.read_text()) or {})
    dist = next(p for p in (folder / "jazzy-distribution.yaml", folder / "jazzy" / "distribution.yaml")
                if p.is_file())
    released = set()
    for name, repo in yaml.safe_load(dist.read_text())["repositories"].items():
        if "release" in repo:
            released.update(repo["release"].get("packages", [name]))
    return rules, released


def _resolves_on_ubuntu(rule: object) -> bool:
    """Whether a rosdep rule gives Ubuntu ``UBUNTU`` something to install (apt or pip)."""
    if not isinstance(rule, dict) or "ubuntu" not in rule:
        return False
    entry = rule["ubuntu"]
    if isinstance(entry, dict) and not INSTALLERS & set(entry):  # per release: noble, else '*'
        entry = entry.get(UBUNTU, entry.get("*"))
    if isinstance(entry, dict):  # {installer: [packages]} or {installer: {packages: [...]}}
        return any(bool(v.get("packages") if isinstance(v, dict) else v) for v in entry.values())
    return bool(entry)


@pytest.fixture(scope="module")
def rosdistro() -> tuple[dict, set[str]]:
    if not (ROSDISTRO / "python.yaml").is_file() and not (ROSDISTRO / "rosdep" / "python.yaml").is_file():
        pytest.skip(f"no ros/rosdistro snapshot at {ROSDISTRO}")
    return _rosdistro_snapshot(ROSDISTRO)


def test_every_key_resolves_in_the_rosdistro_snapshot(rosdistro) -> None:
    """Each build/exec/test key of package.xml is a Jazzy package or a rosdep rule for noble."""
    rules, released = rosdistro
    keys = _declared(*DEPENDS)
    unresolved = sorted(k for k in keys if k not in released and not _resolves_on_ubuntu(rules.get(k)))
    assert not unresolved, (f"keys that rosdep cannot resolve for Jazzy on Ubuntu {UBUNTU}: {unresolved} "
                            f"(checked against {ROSDISTRO}; see its README for the commit)")
    # the tables above agree with the snapshot: ROS packages are released, system keys are rules
    assert released >= ROS_PACKAGES and not set(SYSTEM_KEYS) & released
    assert all(_resolves_on_ubuntu(rules.get(k)) for k in SYSTEM_KEYS)
    # the extras without a key have none in the snapshot either (else package.xml should declare it)
    candidates = {f"python3-{p}{tail}" for p in NO_ROSDEP_KEY.values() for tail in ("", "-pip")}
    assert not candidates & set(rules), sorted(candidates & set(rules))


def test_the_rosdep_rule_reader_refuses_what_noble_cannot_install() -> None:
    """Rules from the snapshot's shapes: plain list, per-release, pip with packages, and misses."""
    assert _resolves_on_ubuntu({"ubuntu": ["python3-x"]})
    assert _resolves_on_ubuntu({"ubuntu": {"pip": {"packages": ["x"]}}})
    assert _resolves_on_ubuntu({"ubuntu": {"jammy": None, "*": ["python3-x"]}})
    assert not _resolves_on_ubuntu({"ubuntu": {"bionic": ["python3-x"], "focal": ["python3-x"]}})
    assert not _resolves_on_ubuntu({"ubuntu": {"noble": None, "*": ["python3-x"]}})
    assert not _resolves_on_ubuntu({"debian": ["python3-x"]}) and not _resolves_on_ubuntu(None)
