"""No input kind's name is branched on outside ekf_localization/inputs/: each kind's behaviour
lives in its own module there (its handler, its settings), so a new kind is one file plus one
registry line. Checked on the code with ast: no ``kind`` or ``x.kind`` is compared with a string."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
INPUTS = REPO / "ekf_localization" / "inputs"


def _is_kind(node: ast.AST) -> bool:
    return (isinstance(node, ast.Name) and node.id == "kind") or (
        isinstance(node, ast.Attribute) and node.attr == "kind")


def _has_string(node: ast.AST) -> bool:
    if isinstance(node, ast.Constant):
        return isinstance(node.value, str)
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return any(_has_string(e) for e in node.elts)
    return False


def kind_comparisons(source: str) -> list[int]:
    """Lines where ``kind`` (a name or an attribute) is compared with a string literal."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            if any(_is_kind(o) for o in operands) and any(_has_string(o) for o in operands):
                lines.append(node.lineno)
    return lines


def test_the_check_finds_a_comparison() -> None:
    assert kind_comparisons('if inp.kind == "odom":\n    pass\n') == [1]
    assert kind_comparisons('x = kind in ("odom", "twist")\n') == [1]
    assert kind_comparisons('x = KINDS[inp.kind].absolute_pose\n') == []


def test_no_kind_is_compared_with_a_string_outside_inputs() -> None:
    found = []
    files = [p for pkg in ("ekf_localization", "sim_robot") for p in (REPO / pkg).rglob("*.py")]
    assert len(files) > 100
    for path in files:
        if INPUTS in path.parents:
            continue
        found += [f"{path.relative_to(REPO)}:{line}" for line in kind_comparisons(path.read_text())]
    assert found == []
