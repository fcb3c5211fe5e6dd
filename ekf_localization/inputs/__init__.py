"""The input kinds ekf_node fuses, one module each (``kind.py`` says what a kind is).

A new kind is a module defining ``KIND`` and one line below; ekf_node, bag_replay, the
parameter schema and the Localizer take it from here.
"""

from ekf_localization.inputs import imu, joint, landmark, odom, pose, tag_corners, twist
from ekf_localization.inputs.kind import InputKind

KINDS: dict[str, InputKind] = {kind.name: kind for kind in (
    odom.KIND,
    pose.KIND,
    twist.KIND,
    imu.KIND,
    joint.KIND,
    landmark.KIND,
    tag_corners.KIND,
)}
