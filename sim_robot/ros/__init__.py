"""sim_node and its parameters and message builders: the rclpy adapter around the world.
"""
