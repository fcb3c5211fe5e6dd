"""Bring up the simulator, the EKF and the pure-pursuit follower with the package's YAMLs.

    ros2 launch ekf_localization ekf_localization.launch.py [use_sim:=true] [use_sim_time:=true]
        [path_file:=<yaml>] [ekf_params:=<yaml>] [sim_params:=<yaml>] [pure_pursuit_params:=<yaml>]

On a real robot pass ``use_sim:=false``: the robot's drivers then provide
``odometry/dead_wheels``, ``camera/pose`` and ``imu/data`` and consume ``cmd_vel``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "ekf_localization"


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory(PACKAGE)
    config = os.path.join(share, "config")
    args = [
        DeclareLaunchArgument("use_sim", default_value="true",
                              description="start sim_node (false on a real robot)"),
        DeclareLaunchArgument("use_sim_time", default_value="true",
                              description="run on /clock published by sim_node"),
        DeclareLaunchArgument("sim_params", default_value=os.path.join(config, "sim.yaml")),
        DeclareLaunchArgument("ekf_params", default_value=os.path.join(config, "ekf.yaml")),
        DeclareLaunchArgument("pure_pursuit_params",
                              default_value=os.path.join(config, "pure_pursuit.yaml")),
        DeclareLaunchArgument("path_file",
                              default_value=os.path.join(config, "paths", "seed000_test_path.yaml")),
    ]
    use_sim_time = {"use_sim_time": LaunchConfiguration("use_sim_time")}
    nodes = [
        Node(package=PACKAGE, executable="sim_node", name="sim_node", output="screen",
             parameters=[LaunchConfiguration("sim_params")],  # the clock's source runs on wall time
             condition=IfCondition(LaunchConfiguration("use_sim"))),
        Node(package=PACKAGE, executable="ekf_node", name="ekf_node", output="screen",
             parameters=[LaunchConfiguration("ekf_params"), use_sim_time]),
        Node(package=PACKAGE, executable="pure_pursuit_node", name="pure_pursuit_node", output="screen",
             parameters=[LaunchConfiguration("pure_pursuit_params"), use_sim_time,
                         {"path_file": LaunchConfiguration("path_file")}]),
    ]
    return LaunchDescription(args + nodes)
