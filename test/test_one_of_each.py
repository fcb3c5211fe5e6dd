"""One module for time, one for quaternions: a new inline conversion elsewhere fails here.

* Time is integer nanoseconds; ``core/units.py`` holds ``NS_PER_S`` and the only conversions
  (``ns_to_seconds``, ``seconds_to_ns``, ``stamp_to_ns``, ``ns_to_sec_nanosec``). Elsewhere no
  ``* 1e-9``, ``/ 1e9``, ``* 1e9`` or ``1_000_000_000``, and no ``stamp.sec * ...``.
* Quaternion maths lives in ``core/angles.py``. Elsewhere no product of a quaternion's w with a
  component (``w * z``, ``q.w * q.x``: a conversion or a norm), no half-angle sine or cosine
  (``sin(0.5 * yaw)``), and no scipy quaternion / Euler conversion.

The packages are read with ``ast`` (comments and docstrings do not count). Each allowed
exception names its file and its source text, with the reason.
"""

from __future__ import annotations

import ast

from helpers.ros_helpers import REPO

PACKAGES = ("ekf_localization", "sim_robot", "seed_experiments")
TIME_MODULE = "ekf_localization/core/units.py"
ANGLES_MODULE = "ekf_localization/core/angles.py"

# (file, source of the flagged expression) -> why it may stay
TIME_ALLOWED = {
    ("seed_experiments/experiments/seed004_kf2d.py", "np.eye(2) * 1e-9"): "P0, a variance, not a time",
}
QUATERNION_ALLOWED = {
    ("ekf_localization/control/pure_pursuit.py", "math.sin(0.5 * phi)"):
        "the chord of a circular arc, 2·r·sin(φ/2), not a quaternion",
    ("ekf_localization/models/swerve_response.py", "math.cos(0.5 * turn)"):
        "a module's wheel direction halfway through its turn, not a quaternion",
    ("ekf_localization/models/swerve_response.py", "math.sin(0.5 * turn)"):
        "a module's wheel direction halfway through its turn, not a quaternion",
}

_SECOND = 1_000_000_000
_QUATERNION_PARTS = {"x", "y", "z", "w", "qx", "qy", "qz", "qw"}


def _sources() -> dict[str, tuple[str, ast.Module]]:
    out = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            text = path.read_text()
            out[rel] = (text, ast.parse(text, rel))
    return out


SOURCES = _sources()


def _number(node: ast.AST) -> float | None:
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
        node = node.operand
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float) \
            and not isinstance(node.value, bool):
        return node.value
    return None


def _is_second(node: ast.AST) -> bool:
    """1e9, 1e-9 or 1_000_000_000 (the number of nanoseconds in a second, or its inverse)."""
    v = _number(node)
    return v is not None and (v == _SECOND or v == 1e-9)


def _time_conversions(tree: ast.Module) -> list[ast.AST]:
    hits: list[ast.AST] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult | ast.Div | ast.FloorDiv):
            if _is_second(node.left) or _is_second(node.right):
                hits.append(node)  # t * 1e-9, t / 1e9, s * 1e9, t // 1_000_000_000
            elif any(isinstance(o, ast.Attribute) and o.attr in ("sec", "nanosec")
                     for o in (node.left, node.right)):
                hits.append(node)  # stamp.sec * NS_PER_S: stamp_to_ns
        elif isinstance(node, ast.Constant) and type(node.value) is int and node.value == _SECOND:
            hits.append(node)  # PERIOD_NS = 1_000_000_000: NS_PER_S
    return hits


def _part(node: ast.AST) -> str | None:
    """'x' ... 'w' when ``node`` names a quaternion component (``w``, ``qw``, ``q.w``)."""
    name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None
    return name[-1] if name in _QUATERNION_PARTS else None


def _is_half_angle(node: ast.AST) -> bool:
    if not isinstance(node, ast.BinOp):
        return False
    if isinstance(node.op, ast.Mult):
        return _number(node.left) == 0.5 or _number(node.right) == 0.5
    return isinstance(node.op, ast.Div) and _number(node.right) == 2


def _quaternion_formulas(tree: ast.Module) -> list[ast.AST]:
    hits: list[ast.AST] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult):
            parts = {_part(node.left), _part(node.right)}
            if None not in parts and "w" in parts:
                hits.append(node)  # w * z, q.w * q.w ...
        elif isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            if name in ("sin", "cos") and node.args and _is_half_angle(node.args[0]):
                hits.append(node)  # sin(0.5 * yaw)
            elif name in ("from_quat", "as_quat", "from_euler", "as_euler"):
                hits.append(node)  # scipy's Rotation
    return hits


def _check(find, owner: str, allowed: dict[tuple[str, str], str]) -> list[str]:
    found, seen = [], set()
    for rel, (text, tree) in SOURCES.items():
        if rel == owner:
            continue
        for node in find(tree):
            segment = ast.get_source_segment(text, node) or ""
            if (rel, segment) in allowed:
                seen.add((rel, segment))
            else:
                found.append(f"{rel}:{node.lineno}: {segment}")
    stale = [f"{rel}: {segment!r} (no longer there: remove it)"
             for rel, segment in set(allowed) - seen]
    return found + stale


def test_the_owning_modules_exist_and_are_read() -> None:
    assert TIME_MODULE in SOURCES and ANGLES_MODULE in SOURCES
    assert _time_conversions(SOURCES[TIME_MODULE][1]), "the checker no longer sees NS_PER_S's literal"
    assert _quaternion_formulas(SOURCES[ANGLES_MODULE][1]), "the checker no longer sees angles' formulas"


def test_the_checkers_catch_what_they_are_for() -> None:
    time_cases = ["dt = (t - t0) * 1e-9", "x = t / 1e9", "n = int(s * 1e9)", "P = 1_000_000_000",
                  "t = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec", "x = t * -1e-9"]
    for code in time_cases:
        assert _time_conversions(ast.parse(code)), code
    for code in ["v = 1e-9", "P = np.eye(2) + 1e-9", "k = t // NS_PER_S"]:
        assert not _time_conversions(ast.parse(code)), code
    quaternion_cases = ["yaw = atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))",
                        "n = q.x * q.x + q.w * q.w", "z = math.sin(0.5 * yaw)", "c = np.cos(yaw / 2)",
                        "q = Rotation.from_euler('xyz', rpy).as_quat()"]
    for code in quaternion_cases:
        assert _quaternion_formulas(ast.parse(code)), code
    for code in ["d = x * y", "c = math.cos(yaw)", "r = 0.5 * math.sin(a)"]:
        assert not _quaternion_formulas(ast.parse(code)), code


def test_time_is_converted_only_by_core_units() -> None:
    problems = _check(_time_conversions, TIME_MODULE, TIME_ALLOWED)
    assert not problems, "convert with ekf_localization.core.units:\n" + "\n".join(problems)


def test_quaternions_are_computed_only_by_core_angles() -> None:
    problems = _check(_quaternion_formulas, ANGLES_MODULE, QUATERNION_ALLOWED)
    assert not problems, "call ekf_localization.core.angles:\n" + "\n".join(problems)
