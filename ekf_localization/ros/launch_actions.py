"""The launch files' actions: :mod:`ekf_localization.ros.launch_description`'s node specs as
``launch_ros`` Nodes. Imported only by ``launch/*.launch.py`` (``launch`` comes with ROS 2)."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription, OpaqueFunction
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.logging import get_logger
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from ekf_localization.ros.launch_description import PACKAGE, NodeSpec, defaults, legacy_forward
from launch import LaunchDescription


def _declare(arguments: Mapping[str, tuple[str, str]], share: str) -> list[DeclareLaunchArgument]:
    values = defaults(arguments, share)
    return [DeclareLaunchArgument(name, default_value=values[name], description=text)
            for name, (_, text) in arguments.items()]


def _node(spec: NodeSpec) -> Node:
    return Node(package=PACKAGE, executable=spec.executable, name=spec.name,
                namespace=spec.namespace or None,  # None: keep a namespace pushed by an including file
                output="screen", parameters=[*spec.param_files, spec.overrides],
                remappings=list(spec.remaps))


def nodes_launch(arguments: Mapping[str, tuple[str, str]],
                 make_specs: Callable[..., list[NodeSpec]]) -> LaunchDescription:
    """``arguments`` declared, then the nodes ``make_specs(share, **their values)`` gives."""
    share = get_package_share_directory(PACKAGE)

    def nodes(context) -> list[Node]:
        values = {name: LaunchConfiguration(name).perform(context) for name in arguments}
        return [_node(spec) for spec in make_specs(share, **values)]

    return LaunchDescription([*_declare(arguments, share), OpaqueFunction(function=nodes)])


def legacy_launch(arguments: Mapping[str, tuple[str, str]]) -> LaunchDescription:
    """The deprecated launch file: a warning, then sim.launch.py or ekf.launch.py."""
    share = get_package_share_directory(PACKAGE)

    def forward(context) -> list[IncludeLaunchDescription]:
        values = {name: LaunchConfiguration(name).perform(context) for name in arguments}
        target, forwarded, message = legacy_forward(**values)
        get_logger("ekf_localization.launch").warning(message)
        return [IncludeLaunchDescription(PythonLaunchDescriptionSource(os.path.join(share, "launch", target)),
                                         launch_arguments=forwarded.items())]

    return LaunchDescription([*_declare(arguments, share), OpaqueFunction(function=forward)])
