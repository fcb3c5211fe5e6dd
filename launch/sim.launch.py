"""The simulator, the EKF and the pure-pursuit follower (seed 000's robot and test path).

    ros2 launch ekf_localization sim.launch.py [namespace:=r1] [frame_prefix:=r1/]
        [use_sim_time:=true] [sim_params:=<yaml>] [ekf_params:=<yaml>]
        [pure_pursuit_params:=<yaml>] [path_file:=<path yaml>]

With use_sim_time (default) sim_node publishes /clock: two simulators on one domain need
use_sim_time:=false. With camera:=images and tag_localizer's single_tag corners, ekf_node gets
a tag_cornersN per tag and camera (sim_robot/ros/sim_corner_inputs.py). The nodes and their parameters:
``ekf_localization.ros.launch_description.sim_nodes``.
"""

from functools import partial

from ekf_localization.ros.launch_actions import nodes_launch
from ekf_localization.ros.launch_description import SIM_ARGUMENTS, sim_nodes
from sim_robot.ros.sim_corner_inputs import corner_inputs


def generate_launch_description():
    # camera:=images with single_tag corners: ekf_node's tag_cornersN from the simulated cameras
    return nodes_launch(SIM_ARGUMENTS, partial(sim_nodes, corner_inputs=corner_inputs))
