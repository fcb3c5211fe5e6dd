"""Path following (no ROS imports): PID, field paths and the pure-pursuit follower.
"""
