"""Deprecated: use sim.launch.py (the simulator) or ekf.launch.py (a robot).

    ros2 launch ekf_localization ekf_localization.launch.py [use_sim:=true] [use_sim_time:=<use_sim>]
        [path_file:=<yaml>] [ekf_params:=<yaml>] [sim_params:=<yaml>] [pure_pursuit_params:=<yaml>]

Logs a deprecation warning naming the replacement, then starts it: ``use_sim:=true`` ->
sim.launch.py, ``use_sim:=false`` -> ekf.launch.py, which starts pure_pursuit_node only when
path_file is given (this file used to drive a real robot along seed 000's test path).
"""

from ekf_localization.ros.launch_actions import legacy_launch
from ekf_localization.ros.launch_description import LEGACY_ARGUMENTS


def generate_launch_description():
    return legacy_launch(LEGACY_ARGUMENTS)
