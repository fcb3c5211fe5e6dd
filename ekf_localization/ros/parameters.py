"""The one parameter schema of the nodes and tools (no rclpy): entries, checks, errors, YAML.

A :class:`Schema` is a table of :class:`Entry` (name, type, default, unit, check, one line of
documentation). :meth:`Schema.parse` checks a flat ``{name: value}`` mapping (ROS parameter
values, dotted names as rcl flattens a YAML) and *collects* every problem; the caller adds its
own cross-parameter problems to the same list and raises one :class:`ParameterError` naming
all of them (a node exits with code 2, :mod:`ekf_localization.ros.node_runner`). The docs'
parameter tables are rendered from the schemas (:mod:`ekf_localization.tools.parameter_docs`);
:mod:`ekf_localization.ros.node_parameters` binds a schema to an rclpy node.
"""

from __future__ import annotations

import array
import math
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

# Parameters every rclpy node has; they are not part of any schema.
ROS_BUILTIN = frozenset(("use_sim_time", "start_type_description_service"))

TYPES: dict[str, str] = {  # type -> its expected form
    "float": "a float",
    "int": "an integer",
    "bool": "true or false",
    "str": "a string",
    "float_list": "a list of floats",
    "str_list": "a list of strings",
    "bool_list": "a list of booleans",
}


class Required:
    """The default of a parameter that must be given."""

    def __repr__(self) -> str:
        return "required"


REQUIRED = Required()


def is_ros_builtin(name: str) -> bool:
    return name in ROS_BUILTIN or name.startswith("qos_overrides.")


# --- problems and the one error class --------------------------------------------------------

def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 160 else text[:150] + " ... " + text[-5:]


@dataclass(frozen=True)
class Problem:
    """One bad parameter: ``name`` and what is wrong (``"expected ..., got ..."``)."""

    name: str
    text: str
    what: str = "parameter"  # or "file", "--set"

    def __str__(self) -> str:
        return f"{self.what} '{self.name}': {self.text}"


def expected(name: str, form: str, got: Any = REQUIRED, *, what: str = "parameter") -> Problem:
    """The problem "expected ``form``, got ``got``" (no "got" part when nothing was given)."""
    return Problem(name, f"expected {form}" + ("" if got is REQUIRED else f", got {_shown(got)}"), what)


class ParameterError(ValueError):
    """Bad parameters: every problem, each naming its parameter and the expected form."""

    def __init__(self, problems: Sequence[Problem] | Problem) -> None:
        self.problems = (problems,) if isinstance(problems, Problem) else tuple(problems)
        if not self.problems:
            raise ValueError("a ParameterError needs at least one problem")
        self.name = self.problems[0].name
        lines = [str(p) for p in self.problems]
        unknown = [p.name for p in self.problems if p.text.startswith(_UNKNOWN)]
        if len(lines) == 1 and not unknown:
            text = lines[0]
        else:
            head = f"{len(lines)} bad parameter{'s' if len(lines) > 1 else ''}"
            if unknown:
                head += " (unknown parameter(s) " + ", ".join(f"'{n}'" for n in unknown) + ")"
            text = head + ":\n  " + "\n  ".join(lines)
        super().__init__(text)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.problems)


def raise_problems(problems: Sequence[Problem]) -> None:
    """Raise one :class:`ParameterError` if there is any problem."""
    if problems:
        raise ParameterError(problems)


_UNKNOWN = "expected a known "


# --- checks ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Check:
    """A test on a correctly typed value and the expected form it stands for."""

    ok: Callable[[Any], bool]
    form: str


def _finite(v: float) -> bool:
    return math.isfinite(v)


def positive(form: str = "a float > 0") -> Check:
    return Check(lambda v: _finite(v) and v > 0.0, form)


def non_negative(form: str = "a float >= 0") -> Check:
    return Check(lambda v: _finite(v) and v >= 0.0, form)


def at_least(minimum: float, form: str) -> Check:
    return Check(lambda v: _finite(v) and v >= minimum, form)


# Timer rates a node can run (a period of at most 1000 s, at least 0.1 ms).
MIN_FREQUENCY_HZ = 1e-3
MAX_FREQUENCY_HZ = 1e4


def timer_rate(form: str = f"a float from {MIN_FREQUENCY_HZ:g} to {MAX_FREQUENCY_HZ:g}") -> Check:
    """A rate a node's timer can run at."""
    return Check(lambda v: MIN_FREQUENCY_HZ <= v <= MAX_FREQUENCY_HZ, form)


def finite(form: str = "a finite float") -> Check:
    return Check(_finite, form)


def choice(options: Sequence[str]) -> Check:
    return Check(lambda v: v in options, "one of " + ", ".join(repr(o) for o in options))


def non_empty(form: str = "a non-empty string") -> Check:
    return Check(lambda v: bool(str(v).strip("/ ")), form)


def floats(length: int | None, form: str, *, non_negative_values: bool = False,
           multiple_of: int = 1) -> Check:
    """A list of finite floats: exactly ``length`` long (or any multiple of ``multiple_of``)."""

    def ok(v: list[float]) -> bool:
        size = len(v) == length if length is not None else len(v) % multiple_of == 0
        return size and all(math.isfinite(x) and (x >= 0.0 or not non_negative_values) for x in v)

    return Check(ok, form)


# --- entries and schemas ---------------------------------------------------------------------

@dataclass(frozen=True)
class Entry:
    """One parameter: name, type, default, unit, check, one line of documentation.

    ``default_doc`` replaces the default in the docs when it is derived from other parameters
    (``default`` is then None). ``check`` (on a value of the right type) defines the expected
    form in error messages; without one, the type's.
    """

    name: str
    type: str
    default: Any
    unit: str
    doc: str
    check: Check | None = None
    default_doc: str | None = None

    def __post_init__(self) -> None:
        if self.type not in TYPES:
            raise ValueError(f"{self.name}: unknown parameter type {self.type!r}")

    @property
    def form(self) -> str:
        """The expected form, with the unit: "a float > 0 (Hz)"."""
        base = self.check.form if self.check else TYPES[self.type]
        return base + (f" ({self.unit})" if self.unit and self.unit not in base else "")


@dataclass(frozen=True)
class Parsed:
    """What :meth:`Schema.parse` found: typed ``values`` (defaults for missing or bad entries,
    ``REQUIRED`` for a missing required one), the ``problems``, ``warnings`` (deprecated names)
    and ``others``, the names the schema does not know (for the caller to judge)."""

    values: dict[str, Any]
    problems: list[Problem]
    warnings: list[str]
    others: dict[str, Any]
    given: frozenset[str] = frozenset()


@dataclass(frozen=True)
class Schema(Mapping[str, Entry]):
    """The parameters of one node (a mapping name -> :class:`Entry`).

    ``renamed`` maps a deprecated name to its new one: the old name keeps working with a
    warning. ``ints_as_floats`` accepts an integer where a float is expected (the EKF, as
    robot_localization's YAMLs often write ``frequency: 30``); the other nodes require a
    decimal point, as rclpy does for a declared double.
    """

    node: str
    doc: str  # where the parameters are documented, for messages
    entries: tuple[Entry, ...]
    renamed: Mapping[str, str] = field(default_factory=dict)
    ints_as_floats: bool = False

    def __post_init__(self) -> None:
        names = [e.name for e in self.entries]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.node}: duplicate parameter names")

    def __getitem__(self, name: str) -> Entry:
        for e in self.entries:
            if e.name == name:
                return e
        raise KeyError(name)

    def __iter__(self) -> Iterator[str]:
        return (e.name for e in self.entries)

    def __len__(self) -> int:
        return len(self.entries)

    def defaults(self) -> dict[str, Any]:
        return {e.name: e.default for e in self.entries
                if e.default is not None and e.default is not REQUIRED}

    def unknown(self, name: str, value: Any) -> Problem:
        return expected(name, f"a known {self.node} parameter (see {self.doc})", value)

    def parse(self, values: Mapping[str, Any], prefix: str = "") -> Parsed:
        """Type-check and check every entry (``prefix`` + name in ``values``)."""
        values = dict(values)
        warnings: list[str] = []
        problems: list[Problem] = []
        for old, new in self.renamed.items():
            if prefix + old not in values:
                continue
            old_value = values.pop(prefix + old)
            if prefix + new in values and values[prefix + new] != old_value:
                problems.append(expected(prefix + old, f"only one of '{prefix + old}' (deprecated) and "
                                         f"'{prefix + new}', or the same value for both", old_value))
                continue
            values[prefix + new] = old_value
            warnings.append(f"parameter '{prefix + old}' is deprecated: use '{prefix + new}' (same "
                            f"meaning; see {self.doc})")
        out: dict[str, Any] = {}
        given = set()
        for e in self.entries:
            key = prefix + e.name
            if key not in values or values[key] is None:  # None: an empty list from rcl
                out[e.name] = e.default
                continue
            given.add(e.name)
            value, problem = self._value(e, key, values[key])
            if problem is not None:
                problems.append(problem)
                out[e.name] = e.default
            else:
                out[e.name] = value
        known = {prefix + e.name for e in self.entries}
        others = {k: v for k, v in values.items() if k not in known and k.startswith(prefix)}
        return Parsed(out, problems, warnings, others, frozenset(given))

    def unknown_problems(self, others: Mapping[str, Any]) -> list[Problem]:
        """One problem per name that is neither in the schema nor a ROS parameter."""
        return [self.unknown(k, v) for k, v in sorted(others.items()) if not is_ros_builtin(k)]

    def _value(self, e: Entry, key: str, v: Any) -> tuple[Any, Problem | None]:
        typed = _typed(e.type, v, self.ints_as_floats)
        if typed is None:
            form = e.form
            kind = TYPES[e.type]
            text = form if kind in form else f"{form} ({kind})"
            if e.type in ("float", "float_list") and _typed(e.type, v, True) is not None:
                example = float(v) if e.type == "float" else [float(x) for x in v][:3]
                text += f", written with a decimal point (e.g. {example!r})"
            return None, expected(key, text, v)
        if e.type == "float" and math.isnan(typed):
            return None, expected(key, e.form, v)
        if e.check is not None and not e.check.ok(typed):
            return None, expected(key, e.form, v)
        return typed, None


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_float(v: Any, ints: bool) -> bool:
    return isinstance(v, (float, np.floating)) or (ints and _is_int(v))


def _as_list(v: Any) -> list | None:
    if isinstance(v, (str, bytes, Mapping)):
        return None
    if isinstance(v, (list, tuple, array.array, np.ndarray)):
        return list(v)
    return None


def _typed(type_name: str, v: Any, ints_as_floats: bool) -> Any:
    """``v`` as ``type_name``, or None if it has another type."""
    if type_name == "float":
        return float(v) if _is_float(v, ints_as_floats) else None
    if type_name == "int":
        return int(v) if _is_int(v) else None
    if type_name == "bool":
        return bool(v) if isinstance(v, (bool, np.bool_)) else None
    if type_name == "str":
        return v if isinstance(v, str) else None
    items = _as_list(v)
    if items is None:
        return None
    if type_name == "float_list":
        return [float(x) for x in items] if all(_is_float(x, ints_as_floats) for x in items) else None
    if type_name == "str_list":
        return items if all(isinstance(x, str) for x in items) else None
    if type_name == "bool_list":
        return [bool(x) for x in items] if all(isinstance(x, (bool, np.bool_)) for x in items) else None
    raise AssertionError(type_name)


# --- YAML parameter files, read as rcl reads them ---------------------------------------------

def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


class _RclLikeLoader(yaml.SafeLoader):
    """SafeLoader that, like rcl's parser, reads ``1e-9`` as a float (YAML 1.1 needs ``1.0e-9``)."""


_RclLikeLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                  |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                  |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                  |[-+]?\.(?:inf|Inf|INF)
                  |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))


# launch_ros writes a launch file's list parameters as tuples, which PyYAML tags !!python/tuple
# (launch_ros/actions/node.py dumps its evaluated parameters); rcl reads them as arrays, and so do we
_RclLikeLoader.add_constructor("tag:yaml.org,2002:python/tuple",
                               lambda loader, node: loader.construct_sequence(node))


def parse_parameter_value(text: str) -> Any:
    """One parameter value written as YAML, read the way rcl reads a params file."""
    return yaml.load(text, Loader=_RclLikeLoader)  # a SafeLoader subclass


def read_parameter_yaml(yaml_path: str | Path) -> Any:
    """The YAML document of a ROS params file, scalars typed as rcl types them.

    Raises OSError (unreadable) or yaml.YAMLError (syntax).
    """
    return yaml.load(Path(yaml_path).read_text(), Loader=_RclLikeLoader)  # a SafeLoader subclass


def names_node(key: str, name: str) -> bool:
    """Whether the params-file section ``key`` is node ``name``'s own: ``name``, ``/name`` or
    ``/<any namespace>/name`` (the global ``/**`` applies too, but names no node)."""
    return key in (name, "/" + name) or key.endswith("/" + name)


def parameters_from_yaml(yaml_path: str | Path, node_name: str = "ekf_node") -> dict[str, Any]:
    """The flat parameter dict a ROS params file gives node ``node_name`` (``/**`` wildcard too)."""
    path = Path(yaml_path)
    try:
        doc = read_parameter_yaml(path)
    except (OSError, yaml.YAMLError) as exc:
        raise ParameterError(expected(str(path), "a readable YAML parameter file", str(exc),
                                      what="file")) from None
    if not isinstance(doc, Mapping):
        raise ParameterError(expected(str(path), "a YAML mapping of node names to ros__parameters",
                                      type(doc).__name__, what="file"))
    name = node_name.strip("/").split("/")[-1]
    values: dict[str, Any] = {}
    matched = False
    for key, body in doc.items():
        k = str(key)
        if k == "/**" or names_node(k, name):
            if not isinstance(body, Mapping) or not isinstance(body.get("ros__parameters"), Mapping):
                raise ParameterError(expected(f"{k}.ros__parameters", "a mapping of parameters", body))
            values.update(_flatten(body["ros__parameters"]))
            matched = True
    if not matched:
        raise ParameterError(expected(str(path), f"a section for node '{name}' or '/**'",
                                      sorted(map(str, doc)), what="file"))
    return values
