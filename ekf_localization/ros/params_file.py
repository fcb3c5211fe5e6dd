"""Check a node's ``--ros-args`` the way rcl will read them, before ``rclpy.init`` does.

rcl rejects a parameter file it cannot parse (a YAML syntax error, a missing file, a list
mixing types such as ``[1.0, 2]`` or ``[true, 1]``) inside ``rclpy.init``, with a C-level
message and a Python traceback. :func:`ros_args_problem` finds those problems first and
says, in one line, which file and parameter and what form rcl expects.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from ekf_localization.ros.parameters import parse_parameter_value, read_parameter_yaml
from ekf_localization.ros.params_match import ros_args_options

_LIST_FORM = ("a list whose elements are all of one type: all true/false, all integers, "
              "all floats written with a decimal point (1.0, not 1), or all strings")


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, Mapping):
        return "mapping"
    if isinstance(value, list):
        return "list"
    return "null" if value is None else type(value).__name__


def _a(kind: str) -> str:
    return ("an " if kind[0] in "aeiou" else "a ") + kind


def value_problem(name: str, value: Any, empty_lists: bool = False) -> str | None:
    """Why rcl cannot read ``value`` for parameter ``name`` (one line), or None.

    rcl reads ``[]`` and a missing value as "not set", which a node declaring its parameters
    from the file cannot declare: an error unless ``empty_lists`` (the node declares them itself).
    """
    if value is None and not empty_lists:
        return f"parameter '{name}': expected a value, got nothing (write '{name}: <value>')"
    if not isinstance(value, list):
        return None
    if not value and not empty_lists:
        return (f"parameter '{name}': expected a non-empty list (rcl reads [] as 'not set'); "
                "leave the parameter out to get its default")
    kinds = [_kind(v) for v in value]
    nested = [i for i, k in enumerate(kinds) if k in ("list", "mapping", "null")]
    if nested:
        i = nested[0]
        return f"parameter '{name}': expected {_LIST_FORM}; element {i} is {_a(kinds[i])} ({value[i]!r})"
    if len(set(kinds)) > 1:
        first = kinds[0]
        i = next(i for i, k in enumerate(kinds) if k != first)
        return (f"parameter '{name}': expected {_LIST_FORM}; element {i} is {_a(kinds[i])} "
                f"({value[i]!r}) among {first}s")
    return None


def _walk(body: Mapping[str, Any], empty_lists: bool, prefix: str = "") -> str | None:
    for key, value in body.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            problem = _walk(value, empty_lists, name + ".")
        else:
            problem = value_problem(name, value, empty_lists)
        if problem:
            return problem
    return None


def params_file_problem(path: str | Path, empty_lists: bool = False) -> str | None:
    """Why rcl cannot load the parameter file ``path`` (one line naming it), or None."""
    try:
        doc = read_parameter_yaml(path)
    except OSError as exc:
        return f"parameter file '{path}': expected a readable YAML file ({exc.strerror or exc})"
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        at = f" at line {where.line + 1}, column {where.column + 1}" if where is not None else ""
        what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        return f"parameter file '{path}': expected valid YAML; syntax error{at}: {what}"
    if not isinstance(doc, Mapping):
        return (f"parameter file '{path}': expected a mapping of node names to "
                f"{{ros__parameters: {{...}}}}, got {_a(_kind(doc))}")
    for node, body in doc.items():
        params = body.get("ros__parameters") if isinstance(body, Mapping) else None
        if not isinstance(params, Mapping):
            return (f"parameter file '{path}': expected '{node}' to hold 'ros__parameters:' "
                    "with a mapping of parameters")
        problem = _walk(params, empty_lists)
        if problem:
            return f"parameter file '{path}': {problem}"
    return None


def ros_args_problem(args: Sequence[str], empty_lists: bool = False) -> str | None:
    """The first ``--params-file`` or ``-p name:=value`` in ``--ros-args`` rcl (or a node declaring
    its parameters from them, unless ``empty_lists``) would refuse, or None."""
    for flag, value in ros_args_options(args):
        if flag == "--params-file":
            if value is None:
                return "--params-file: expected a file name after it"
            problem = params_file_problem(value, empty_lists)
            if problem:
                return problem
        elif flag in ("-p", "--param"):
            if value is None or ":=" not in value:
                return f"{flag}: expected NAME:=VALUE after it"
            name, _, text = value.partition(":=")
            try:
                parsed = parse_parameter_value(text)
            except yaml.YAMLError:
                parsed = text  # rcl reads it as a string
            problem = value_problem(name, parsed, empty_lists) if text else None
            if problem:
                return problem
    return None
