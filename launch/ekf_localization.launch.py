"""Bring up the simulator, the EKF and the pure-pursuit follower with the package's YAMLs.

    ros2 launch ekf_localization ekf_localization.launch.py [use_sim:=true] [use_sim_time:=<use_sim>]
        [path_file:=<yaml>] [ekf_params:=<yaml>] [sim_params:=<yaml>] [pure_pursuit_params:=<yaml>]

The nodes and their parameters come from ``ekf_localization.ros.launch_description`` (the
launch test starts exactly those). On a real robot pass ``use_sim:=false``: the robot's
drivers then provide ``odometry/dead_wheels``, ``camera/pose`` and ``imu/data`` and consume
``cmd_vel``; ``use_sim_time`` follows ``use_sim`` unless given.
"""

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from ekf_localization.ros.launch_description import ARGUMENTS, PACKAGE, default_arguments, node_specs
from launch import LaunchDescription


def _nodes(context, share: str):
    values = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    return [Node(package=PACKAGE, executable=spec.executable, name=spec.name, output="screen",
                 parameters=[*spec.param_files, spec.overrides])
            for spec in node_specs(share, **values)]


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory(PACKAGE)
    defaults = default_arguments(share)
    args = [DeclareLaunchArgument(name, default_value=defaults[name], description=text)
            for name, text in ARGUMENTS.items()]
    return LaunchDescription(args + [OpaqueFunction(function=_nodes, args=[share])])
