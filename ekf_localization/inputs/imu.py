"""``imuN``: sensor_msgs/Imu, orientation as roll, pitch, yaw (RL's imuN; REP-145: a covariance
whose first entry is -1 means the message has no such data)."""

from __future__ import annotations

import numpy as np

from ekf_localization.core.angles import quaternion_to_rpy
from ekf_localization.core.measurements import ImuMeasurement
from ekf_localization.inputs.kind import InputKind, covariance, header_of


def read(msg) -> ImuMeasurement:
    stamp, frame = header_of(msg)
    q, a, acc = msg.orientation, msg.angular_velocity, msg.linear_acceleration
    return ImuMeasurement(
        stamp_ns=stamp, frame_id=frame, orientation=np.array(quaternion_to_rpy(q.x, q.y, q.z, q.w)),
        orientation_covariance=covariance(msg.orientation_covariance, 3),
        angular_velocity=np.array([a.x, a.y, a.z], dtype=float),
        angular_velocity_covariance=covariance(msg.angular_velocity_covariance, 3),
        linear_acceleration=np.array([acc.x, acc.y, acc.z], dtype=float),
        linear_acceleration_covariance=covariance(msg.linear_acceleration_covariance, 3))


KIND = InputKind("imu", "sensor_msgs/msg/Imu", read,
                 parts=(("orientation", 3, 3), ("angular_velocity", 9, 3), ("linear_acceleration", 12, 3)),
                 thresholds={"_pose_rejection_threshold": "orientation",
                             "_twist_rejection_threshold": "angular_velocity",
                             "_angular_velocity_rejection_threshold": "angular_velocity",
                             "_linear_acceleration_rejection_threshold": "linear_acceleration"})
