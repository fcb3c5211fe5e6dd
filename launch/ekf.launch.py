"""ekf_node for a robot whose drivers publish the inputs; pure_pursuit_node only with path_file.

    ros2 launch ekf_localization ekf.launch.py [namespace:=r1] [frame_prefix:=r1/]
        [params_file:=<yaml>] [use_sim_time:=false]
        [odom_topic:=...] [pose_topic:=...] [imu_topic:=...] [cmd_vel_topic:=...]
        [joint_states_topic:=...] [set_pose_topic:=...]
        [path_file:=<path yaml> [pure_pursuit_params:=<yaml>]]

The remap arguments rename the topics of the shipped YAMLs (odometry/dead_wheels, camera/pose,
imu/data, cmd_vel, joint_states, set_pose) to your drivers' names. The nodes and their
parameters: ``ekf_localization.ros.launch_description.ekf_nodes`` (``ros2 launch ... --show-args``).
"""

from ekf_localization.ros.launch_actions import nodes_launch
from ekf_localization.ros.launch_description import EKF_ARGUMENTS, ekf_nodes


def generate_launch_description():
    return nodes_launch(EKF_ARGUMENTS, ekf_nodes)
