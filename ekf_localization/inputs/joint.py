"""``jointN``: sensor_msgs/JointState of the dead-wheel encoders (ros2_control's
joint_state_broadcaster), fused as their speeds (core.encoder_input, seed 000 eq. 29-33)."""

from __future__ import annotations

import numpy as np

from ekf_localization.core.measurements import JointStateMeasurement
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.inputs.kind import InputKind


def read(msg) -> JointStateMeasurement:
    """Positions rad, velocities rad/s; empty arrays when absent (copies: a bag's are read-only views)."""
    return JointStateMeasurement(
        stamp_ns=stamp_to_ns(msg.header.stamp), names=tuple(str(n) for n in msg.name),
        positions=np.array(msg.position, dtype=float), velocities=np.array(msg.velocity, dtype=float),
        efforts=np.array(msg.effort, dtype=float))


KIND = InputKind("joint", "sensor_msgs/msg/JointState", read, thresholds={"_rejection_threshold": "encoders"})
