"""The ROS 2 nodes: thin adapters from messages and parameters to the core.
"""
