"""The packages' layers and the one direction of their imports.

Three top-level packages: ``ekf_localization`` (the product) <- ``sim_robot`` (the simulator;
it may import ekf_localization) <- ``seed_experiments`` (the paper reproductions; it imports
both, nothing imports it). ``ekf_localization`` never imports ``sim_robot`` or
``seed_experiments``. Inside them, subpackages in layers: core <- models <- control <- ros <-
nodes <- tools; sim_robot.world (ROS-free) <- sim_robot.ros.

Two checks: the ROS-free layers import with every ROS package blocked, and every import
statement between subpackages (read with ast, function-level ones too) points down a layer,
with no cycle between packages or subpackages.
"""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("ekf_localization", "sim_robot", "seed_experiments")
# top-level package -> the other top-level packages it may import
PACKAGE_DEPENDS: dict[str, frozenset[str]] = {
    "ekf_localization": frozenset(),
    "sim_robot": frozenset({"ekf_localization"}),
    "seed_experiments": frozenset({"ekf_localization", "sim_robot"}),
}

# subpackage -> the subpackages its modules may import (besides itself)
_CORE = ("ekf_localization.core",)
_BASE = _CORE + ("ekf_localization.models",)
_CONTROL = _BASE + ("ekf_localization.control",)
_ROS = _CONTROL + ("ekf_localization.ros",)
_NODES = _ROS + ("ekf_localization.nodes",)
_EKF = _NODES + ("ekf_localization.tools",)
ALLOWED: dict[str, frozenset[str]] = {
    "ekf_localization.core": frozenset(),
    "ekf_localization.models": frozenset(_CORE),
    "ekf_localization.control": frozenset(_BASE),
    "ekf_localization.ros": frozenset(_CONTROL),
    "ekf_localization.nodes": frozenset(_ROS),
    "ekf_localization.tools": frozenset(_NODES),
    "sim_robot.world": frozenset(_CONTROL),
    "sim_robot.ros": frozenset(_ROS + ("sim_robot.world",)),
    "seed_experiments.models": frozenset(_EKF),
    "seed_experiments.experiments": frozenset(_EKF + ("sim_robot.world", "sim_robot.ros",
                                                      "seed_experiments.models")),
}
ROS_FREE = ("ekf_localization.core", "ekf_localization.models", "ekf_localization.control", "sim_robot.world")
# Imports of sim_robot from ekf_localization that predate the rule; these modules are to move
# out of ekf_localization. The test fails on any other such import, and on an entry whose
# module is still in ekf_localization but no longer imports sim_robot.
PENDING: dict[str, str] = {
    "ekf_localization.tools.parameter_docs": "sim_robot.ros",
    "ekf_localization.tools.sim_bag": "sim_robot.ros sim_robot.world",
    "ekf_localization.tools.view_export": "sim_robot.ros sim_robot.world",
}


def _modules(subpackage: str) -> list[str]:
    """Every module of ``subpackage``, from its files (importing nothing)."""
    root = REPO.joinpath(*subpackage.split("."))
    names = []
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(REPO).with_suffix("").parts
        names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


def _imported(module: str) -> set[str]:
    """The absolute names every import statement in ``module`` names."""
    parts = module.split(".")
    path = REPO.joinpath(*parts)
    if path.is_dir():
        return _imported_names((path / "__init__.py").read_text(), parts)
    return _imported_names(path.with_suffix(".py").read_text(), parts[:-1])


def _imported_names(source: str, package: list[str]) -> set[str]:
    """Names imported anywhere in ``source`` (functions too), relative ones resolved in ``package``."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[:len(package) - node.level + 1] + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{alias.name}" for alias in node.names)  # "from pkg import module"
    return out


def _layer(name: str) -> str | None:
    for layer in ALLOWED:
        if name == layer or name.startswith(layer + "."):
            return layer
    return None


def _layer_graph() -> dict[str, dict[str, list[str]]]:
    """layer -> {imported layer: [the importing modules]}."""
    graph: dict[str, dict[str, list[str]]] = {layer: {} for layer in ALLOWED}
    for layer in ALLOWED:
        for module in _modules(layer):
            for name in _imported(module):
                target = _layer(name)
                if target is not None and target != layer:
                    graph[layer].setdefault(target, []).append(f"{module} imports {name}")
    return graph


def _cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the directed graph, or None."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(v: str) -> list[str] | None:
        state[v] = 1
        stack.append(v)
        for w in sorted(edges.get(v, ())):
            if state.get(w) == 1:
                return stack[stack.index(w):] + [w]
            if w not in state and (found := visit(w)) is not None:
                return found
        stack.pop()
        state[v] = 2
        return None

    for v in sorted(edges):
        if v not in state and (found := visit(v)) is not None:
            return found
    return None


def test_every_module_belongs_to_a_layer() -> None:
    top = {p.parent.relative_to(REPO).as_posix().replace("/", ".")
           for pkg in PACKAGES for p in REPO.joinpath(pkg).glob("*/__init__.py")}
    assert top == set(ALLOWED)
    loose = [p.relative_to(REPO).as_posix() for pkg in PACKAGES for p in REPO.joinpath(pkg).glob("*.py")
             if p.name != "__init__.py"]
    assert not loose, f"modules outside every layer: {loose}"


def test_the_allowed_directions_form_no_cycle() -> None:
    assert _cycle({k: set(v) for k, v in ALLOWED.items()}) is None
    assert _cycle({k: set(v) for k, v in PACKAGE_DEPENDS.items()}) is None
    for layer, targets in ALLOWED.items():  # the layers respect the packages' direction
        package = layer.split(".")[0]
        assert {t.split(".")[0] for t in targets} <= PACKAGE_DEPENDS[package] | {package}, layer


def test_cycle_finder_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}}) is None


def _package_imports() -> dict[str, dict[str, list[str]]]:
    """package -> {other package it imports: [the importing modules]} (every import statement)."""
    out: dict[str, dict[str, list[str]]] = {p: {} for p in PACKAGES}
    for package in PACKAGES:
        for module in _modules(package):
            for name in _imported(module):
                top = name.split(".")[0]
                if top in PACKAGES and top != package:
                    out[package].setdefault(top, []).append(f"{module} imports {name}")
    return out


def test_ekf_localization_never_imports_sim_robot_or_seed_experiments() -> None:
    found = _package_imports()
    wrong = [f"{package} -> {target}: {line}" for package, targets in found.items()
             for target, lines in targets.items() if target not in PACKAGE_DEPENDS[package]
             for line in lines if line.split(" ")[0] not in PENDING]
    assert not wrong, "\n".join(wrong)
    edges = {package: {t for t, lines in targets.items()
                       if any(m.split(" ")[0] not in PENDING for m in lines)}
             for package, targets in found.items()}
    cycle = _cycle(edges)
    assert cycle is None, "import cycle between packages: " + " -> ".join(cycle or [])
    # an exception whose module stays but imports no sim_robot any more is to be removed
    pending = {line.split(" ")[0] for line in found["ekf_localization"].get("sim_robot", [])}
    stale = {m for m in PENDING if m not in pending and m in _modules("ekf_localization")}
    assert not stale, f"remove from PENDING: {sorted(stale)}"
    assert "seed_experiments" not in found["ekf_localization"]
    assert not any(found[p].get("seed_experiments") for p in PACKAGES)


def test_imports_point_down_the_layers() -> None:
    graph = _layer_graph()
    cycle = _cycle({k: set(v) for k, v in graph.items()})
    assert cycle is None, "import cycle between subpackages: " + " -> ".join(cycle or [])
    wrong = [f"{layer} -> {target}: " + "; ".join(lines)
             for layer in graph for target in graph[layer] if target not in ALLOWED[layer]
             for lines in [[m for m in graph[layer][target] if m.split(" ")[0] not in PENDING]] if lines]
    assert not wrong, "\n".join(wrong)


def test_the_checker_sees_a_forbidden_import() -> None:
    # a module of ekf_localization importing sim_robot is a violation the rules catch
    names = _imported_names("import sim_robot.world.world\nfrom seed_experiments import models\n",
                            ["ekf_localization", "core"])
    assert {n.split(".")[0] for n in names} == {"sim_robot", "seed_experiments"}
    assert {_layer(n) for n in names} - {None} == {"sim_robot.world", "seed_experiments.models"}
    assert "sim_robot" not in PACKAGE_DEPENDS["ekf_localization"]
    assert "seed_experiments" not in PACKAGE_DEPENDS["sim_robot"]


def test_import_finder_sees_relative_nested_and_module_imports() -> None:
    # the checker must see what a module really imports, or the layer test cannot fail
    source = ("from . import kernels\nfrom ..models.mecanum import SPEC\n"
              "def f():\n    import ekf_localization.tools.demo\n")
    found = _imported_names(source, ["ekf_localization", "core"])
    assert {"ekf_localization.core.kernels", "ekf_localization.models.mecanum",
            "ekf_localization.tools.demo"} <= found
    assert {_layer(n) for n in found} == {"ekf_localization.core", "ekf_localization.models",
                                          "ekf_localization.tools"}
    assert _layer("ekf_localization_extra") is None
    assert {"ekf_localization.core.localizer", "ekf_localization.models.mecanum"} <= _imported(
        "ekf_localization.models.registry")


_BLOCKED_IMPORT = r"""
import importlib, importlib.abc, json, sys

def blocked(name):
    top = name.split(".")[0]
    return (top in ("rclpy", "rosbags", "launch", "launch_ros", "ament_index_python", "rosidl_runtime_py",
                    "builtin_interfaces", "rcl_interfaces")
            or top.startswith("tf2") or top.endswith("_msgs") or top.endswith("_srvs"))

class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if blocked(name):
            raise ImportError(f"{name} is blocked: this layer must not need ROS")
        return None

sys.meta_path.insert(0, Block())
failed = {}
for module in json.loads(sys.argv[1]):
    try:
        importlib.import_module(module)
    except Exception as exc:
        failed[module] = f"{type(exc).__name__}: {exc}"
loaded = sorted(m for m in sys.modules if blocked(m))
print(json.dumps({"failed": failed, "loaded": loaded}))
"""


def _import_blocked(modules: list[str]) -> dict:
    proc = subprocess.run([sys.executable, "-c", _BLOCKED_IMPORT, json.dumps(modules)], cwd=REPO,
                          capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_ros_free_layers_import_without_ros() -> None:
    modules = [m for layer in ROS_FREE for m in _modules(layer)]
    assert len(modules) > 20
    result = _import_blocked(modules)
    assert result == {"failed": {}, "loaded": []}


def test_the_blocker_blocks() -> None:
    pytest.importorskip("rclpy")  # a ROS layer fails to import under the blocker
    result = _import_blocked(["ekf_localization.nodes.ekf_node"])
    assert re.fullmatch(r"ImportError: \w+ is blocked: this layer must not need ROS",
                        result["failed"]["ekf_localization.nodes.ekf_node"])
