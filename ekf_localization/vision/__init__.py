"""Camera geometry and AprilTags: the tag layout, the pinhole camera, the detector interface.

ROS-free (numpy only, OpenCV where a detector needs it); sits above ``models`` and below
``inputs`` in the package's layers.
"""
