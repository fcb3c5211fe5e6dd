"""A :class:`~ekf_localization.ros.parameters.Schema` bound to an rclpy node.

A node, right after ``Node.__init__``:

1. :func:`given_values` declares every parameter it was started with (a typo too, so the
   schema reports it) and returns their values; the node parses them with its schema (a bad
   file raises :class:`~ekf_localization.ros.parameters.ParameterError`, exit code 2);
2. :func:`declare_unset` declares the rest with the values in effect, so ``ros2 param get``
   shows what the node runs with;
3. :func:`refuse_changes`: the nodes read their parameters only at start-up, so a later
   ``ros2 param set`` is refused with that reason instead of being accepted and ignored.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from ekf_localization.ros.parameters import Schema, is_ros_builtin

_EMPTY_LIST_TYPES = {"float_list": Parameter.Type.DOUBLE_ARRAY, "str_list": Parameter.Type.STRING_ARRAY,
                     "bool_list": Parameter.Type.BOOL_ARRAY}


def given_values(node: Node) -> dict[str, Any]:
    """Declare every parameter the node was started with and return their values (ROS's own,
    ``use_sim_time``, ..., left out).

    Declared with dynamic typing: rcl passes an empty list (``[]`` in a YAML) as "not set",
    which ``automatically_declare_parameters_from_overrides`` cannot declare. rclpy keeps the
    overrides of undeclared parameters only in ``Node._parameter_overrides``.
    """
    values = {}
    for name, p in node._parameter_overrides.items():
        if is_ros_builtin(name):
            continue
        if not node.has_parameter(name):
            node.declare_parameter(name, p.value, ParameterDescriptor(dynamic_typing=True))
        values[name] = p.value
    return values


def given_qos_overrides(node: Node) -> dict[str, Any]:
    """The ``qos_overrides.*`` the node was started with (rclpy declares them with the endpoints)."""
    return {name: p.value for name, p in node._parameter_overrides.items()
            if name.startswith("qos_overrides.")}


def declare_unset(node: Node, schema: Schema, values: Mapping[str, Any]) -> None:
    """Declare each schema parameter the node was not given, with its value in ``values``."""
    for name, value in values.items():
        if node.has_parameter(name) or value is None:
            continue
        entry = schema[name]
        descriptor = ParameterDescriptor(description=entry.doc, additional_constraints=entry.form)
        if isinstance(value, (list, tuple)) and not value:  # [] has no type of its own
            node.declare_parameter(name, _EMPTY_LIST_TYPES[entry.type], descriptor)
        else:
            node.declare_parameter(name, list(value) if isinstance(value, tuple) else value, descriptor)


def refuse_changes(node: Node, schema: Schema) -> None:
    """Refuse every later change of the node's parameters (ROS's own excepted), with the reason."""
    name_of_node = schema.node

    def on_set(parameters: list[Parameter]) -> SetParametersResult:
        fixed = [p.name for p in parameters if not is_ros_builtin(p.name)]
        if not fixed:
            return SetParametersResult(successful=True)
        names = ", ".join(f"'{n}'" for n in fixed)
        return SetParametersResult(successful=False, reason=(
            f"{name_of_node} reads {names} only at start-up: restart it with the new value in its "
            f"parameter file (see {schema.doc})"))

    node.add_on_set_parameters_callback(on_set)
