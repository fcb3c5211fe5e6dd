"""Simulated FTC/FRC robot: a ROS-free world (truth at 1 kHz, sensors) and its ROS node.

``sim_robot.world`` is the entry point for code that runs without ROS (Monte-Carlo
experiments, closed-loop tests); ``sim_robot.ros.sim_node`` is the thin rclpy adapter.
"""
