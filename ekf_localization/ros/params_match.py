"""Which sections of a ROS parameter file apply to a node, the way rcl matches them.

rcl reads a params file's top-level keys as node names, a key without a leading ``/`` as if it
had one (``ekf_node:`` is ``/ekf_node``, which a node in namespace ``/r1`` does not match), and
two wildcards: ``*`` for one namespace token or the node name, ``/**`` for any number of tokens
(none included). So ``/**/ekf_node:`` applies to ``ekf_node`` in any namespace, ``/**:`` to every
node. (Checked against rclpy 7.1: a file with ``ekf_node``, ``/**/ekf_node``, ``/*/ekf_node``,
``/**`` and ``/r1/ekf_node`` sections gives ``/ekf_node`` the 1st, 2nd and 4th and ``/r1/ekf_node``
all but the 1st.)

:func:`unmatched_params_files` lets a node say at start that a ``--params-file`` it was given
has no section for it (its parameters are then silently the defaults). No rclpy here.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import yaml

from ekf_localization.ros.parameters import read_parameter_yaml


def _key_pattern(key: str) -> re.Pattern[str]:
    tokens = (key if key.startswith("/") else "/" + key).split("/")[1:]
    parts = []
    for token in tokens:
        if token == "**":
            parts.append("(?:/[^/]+)*")
        elif token == "*":
            parts.append("/[^/]+")
        else:
            parts.append("/" + re.escape(token))
    return re.compile("".join(parts))


_VALUED = ("-r", "--remap", "-p", "--param", "--params-file")


def ros_args_options(args: Sequence[str]) -> Iterator[tuple[str, str | None]]:
    """(flag, value) of each option inside ``--ros-args ... [--]`` sections of ``args`` that takes
    a value (remaps, parameters, parameter files); value is None when the arguments end first."""
    in_ros_args = False
    i = 0
    while i < len(args):
        a = args[i]
        if a == "--ros-args":
            in_ros_args = True
        elif a == "--":
            in_ros_args = False
        elif in_ros_args and a in _VALUED:
            value = args[i + 1] if i + 1 < len(args) else None
            yield a, value
            i += 1
        i += 1


def section_applies(key: str, node_fqn: str) -> bool:
    """Whether the params-file section ``key`` applies to the node ``node_fqn`` (``/ns/name``)."""
    return _key_pattern(str(key)).fullmatch(node_fqn) is not None


def node_fqn(default_name: str, args: Sequence[str], default_namespace: str = "/") -> str:
    """The fully qualified name a node created as ``default_name`` gets from the ``--ros-args``
    remaps ``-r [node:]__node:=NAME`` and ``-r [node:]__ns:=NS`` in ``args`` (rcl's rules, global
    or addressed to this node)."""
    name, namespace = default_name, default_namespace
    for flag, value in ros_args_options(args):
        if flag in ("-r", "--remap") and value is not None:
            lhs, sep, rhs = value.partition(":=")
            target, _, what = lhs.rpartition(":")
            if sep and target in ("", default_name):
                if what == "__node":
                    name = rhs
                elif what == "__ns":
                    namespace = rhs
    return "/" + namespace.strip("/") + "/" + name if namespace.strip("/") else "/" + name


def params_files(args: Sequence[str]) -> list[str]:
    """The ``--params-file`` paths in the ``--ros-args`` of ``args``, in order."""
    return [value for flag, value in ros_args_options(args)
            if flag == "--params-file" and value is not None]


def unmatched_params_files(fqn: str, args: Sequence[str]) -> list[str]:
    """One message per ``--params-file`` in ``args`` none of whose sections applies to node ``fqn``
    (a file rcl cannot read is left to rcl's own error)."""
    messages = []
    for path in params_files(args):
        try:
            doc = read_parameter_yaml(path)
        except (OSError, yaml.YAMLError):
            continue
        if not isinstance(doc, Mapping) or any(section_applies(str(k), fqn) for k in doc):
            continue
        keys = ", ".join(f"'{k}'" for k in doc) or "none"
        name = fqn.rsplit("/", 1)[-1]
        messages.append(
            f"parameter file '{path}' has no section for this node ({fqn}; the file's sections: {keys}), "
            f"so none of its parameters apply and the node runs on its defaults: key the section "
            f"'/**/{name}:' (any namespace) or '{fqn}:'")
    return messages


def section_for(doc: Mapping, node_fqn_or_name: str) -> Mapping:
    """The ``ros__parameters`` of the first section of a parsed params file that applies to the node
    (``ekf_node`` is taken as ``/ekf_node``); KeyError when none does."""
    fqn = node_fqn_or_name if node_fqn_or_name.startswith("/") else "/" + node_fqn_or_name
    for key, body in doc.items():
        if section_applies(str(key), fqn):
            return body["ros__parameters"]
    raise KeyError(f"no section of the parameter file applies to {fqn} (sections: {list(doc)})")


def params_file_section(path: str | Path, node_fqn_or_name: str) -> Mapping:
    """:func:`section_for` of the params file at ``path``."""
    return section_for(read_parameter_yaml(path), node_fqn_or_name)
