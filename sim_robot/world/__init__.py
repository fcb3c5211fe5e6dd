"""The ROS-free simulated world: truth at 1 kHz, drives, field, sensors (batched over trials).
"""
