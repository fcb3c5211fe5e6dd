"""Estimation core (no ROS imports): units, angles, linear algebra, the EKF engine and its
compiled kernels, measurement records, the time-ordered :class:`Localizer` and its config.
"""
