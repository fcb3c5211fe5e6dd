"""The packages' layers: ekf_localization (core <- models <- vision <- inputs, control <- ros
<- nodes <- tools) <- sim_robot (world, ros) <- the seed papers' experiments.

Three checks: the ROS-free layers import with every ROS package blocked; every import
statement between subpackages (read with ast, function-level and TYPE_CHECKING ones too)
points down a layer, so ekf_localization never imports sim_robot; and no module imports
itself through others (no import cycle between modules, inside a layer too).
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

# subpackage -> the subpackages its modules may import (besides itself). ekf_localization is
# the estimator and the robot's software, complete without the simulator; sim_robot builds on it.
_EKF = ("ekf_localization.core", "ekf_localization.models", "ekf_localization.vision",
        "ekf_localization.inputs", "ekf_localization.frc",
        "ekf_localization.control", "ekf_localization.ros", "ekf_localization.nodes",
        "ekf_localization.tools")
ALLOWED: dict[str, frozenset[str]] = {layer: frozenset(_EKF[:i]) for i, layer in enumerate(_EKF)}
ALLOWED["ekf_localization.control"] = frozenset(_EKF[:2])
ALLOWED["ekf_localization.frc"] = frozenset(_EKF[:1])  # WPILib structs, NT4 time: core only
ALLOWED["sim_robot.world"] = frozenset(_EKF[:3])
ALLOWED["sim_robot.ros"] = frozenset(_EKF + ("sim_robot.world",))
# the seed papers' experiments (the top-level package seed_experiments) sit on top of both
ALLOWED["seed_experiments"] = frozenset(ALLOWED)
ROS_FREE = ("ekf_localization.core", "ekf_localization.models", "ekf_localization.vision",
            "ekf_localization.inputs", "ekf_localization.frc",
            "ekf_localization.control", "sim_robot.world")
PACKAGES = ("ekf_localization", "sim_robot", "seed_experiments")


def _modules(subpackage: str) -> list[str]:
    """Every module of ``subpackage``, from its files (importing nothing; none if it is absent)."""
    root = REPO.joinpath(*subpackage.split("."))
    names = []
    for path in sorted(root.rglob("*.py")) if root.is_dir() else []:
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


def _module_graph() -> dict[str, set[str]]:
    """module -> the modules of the packages it imports (``from pkg import module`` names the
    module; ``from module import name`` the module)."""
    modules = {m for pkg in PACKAGES for m in _modules(pkg)}
    return {m: {n for n in _imported(m) if n in modules and n != m} for m in modules}


def test_every_module_belongs_to_a_layer() -> None:
    layers = {p.parent.relative_to(REPO).as_posix().replace("/", ".")
              for pkg in ("ekf_localization", "sim_robot") for p in REPO.joinpath(pkg).glob("*/__init__.py")}
    layers |= {pkg for pkg in PACKAGES if (REPO / pkg).is_dir() and pkg in ALLOWED}
    assert layers == {layer for layer in ALLOWED if _modules(layer)}
    loose = [m for pkg in PACKAGES for m in _modules(pkg) if _layer(m) is None and m not in PACKAGES]
    assert not loose, f"modules outside every layer: {loose}"


def test_the_allowed_directions_form_no_cycle() -> None:
    assert _cycle({k: set(v) for k, v in ALLOWED.items()}) is None


def test_cycle_finder_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}}) is None


def test_ekf_localization_never_imports_sim_robot() -> None:
    wrong = [f"{m} imports {n}" for m in _modules("ekf_localization")
             for n in _imported(m) if n.split(".")[0] in ("sim_robot", "seed_experiments")]
    assert not wrong, "\n".join(wrong)
    assert not [layer for layer, allowed in ALLOWED.items()
                if layer.startswith("ekf_localization.") and any(a.startswith("sim_robot") for a in allowed)]


def _batched_classes(source: str) -> list[str]:
    """Names of the classes (nested ones too) in ``source`` that start with "Batched"."""
    return [node.name for node in ast.walk(ast.parse(source))
            if isinstance(node, ast.ClassDef) and node.name.startswith("Batched")]


def test_ekf_localization_defines_no_batched_class() -> None:
    # the robot runs one filter and one follower; the versions over N trials at once serve the
    # seed papers' tables and live in seed_experiments.batched
    found = [f"{path.relative_to(REPO)}: {name}"
             for path in sorted((REPO / "ekf_localization").rglob("*.py"))
             for name in _batched_classes(path.read_text())]
    nested = "class A:\n    class BatchedB:\n        pass\nclass BatchedC(A): pass\nBatchedD = A\n"
    assert sorted(_batched_classes(nested)) == ["BatchedB", "BatchedC"]  # the check can fail
    assert not found, "\n".join(found)


def test_no_import_cycle_between_modules() -> None:
    graph = _module_graph()
    assert len(graph) > 50 and any(graph.values())
    cycle = _cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_the_checks_see_a_cycle_through_a_function_level_import_and_a_sim_robot_import() -> None:
    # how ekf_tune and tune_report imported each other: one at the top, one inside main()
    top = "from ekf_localization.tools.tune_report import write_report\n"
    inner = "def main():\n    from ekf_localization.tools.ekf_tune import Tuner\n"
    graph = {"ekf_localization.tools.ekf_tune": _imported_names(top, ["ekf_localization", "tools"]),
             "ekf_localization.tools.tune_report": _imported_names(inner, ["ekf_localization", "tools"])}
    names = set(graph)
    assert _cycle({m: v & names for m, v in graph.items()}) is not None
    typed = ("from typing import TYPE_CHECKING\n"
             "if TYPE_CHECKING:\n    from sim_robot.world.field import Field\n")
    assert {_layer(n) for n in _imported_names(typed, ["ekf_localization", "tools"])} >= {"sim_robot.world"}


def test_imports_point_down_the_layers() -> None:
    graph = _layer_graph()
    cycle = _cycle({k: set(v) for k, v in graph.items()})
    assert cycle is None, "import cycle between subpackages: " + " -> ".join(cycle or [])
    wrong = [f"{layer} -> {target}: " + "; ".join(graph[layer][target])
             for layer in graph for target in graph[layer] if target not in ALLOWED[layer]]
    assert not wrong, "\n".join(wrong)


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
