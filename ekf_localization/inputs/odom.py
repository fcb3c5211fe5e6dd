"""``odomN``: nav_msgs/Odometry, pose in ``frame_id`` and twist in ``child_frame_id`` (RL's odomN)."""

from __future__ import annotations

from ekf_localization.core.measurements import OdometryMeasurement
from ekf_localization.inputs.kind import InputKind, covariance, header_of, pose6, twist6


def read(msg) -> OdometryMeasurement:
    stamp, frame = header_of(msg)
    return OdometryMeasurement(stamp_ns=stamp, frame_id=frame, child_frame_id=str(msg.child_frame_id),
                               pose=pose6(msg.pose.pose), pose_covariance=covariance(msg.pose.covariance, 6),
                               twist=twist6(msg.twist.twist),
                               twist_covariance=covariance(msg.twist.covariance, 6))


KIND = InputKind("odom", "nav_msgs/msg/Odometry", read, parts=(("pose", 0, 6), ("twist", 6, 6)),
                 thresholds={"_pose_rejection_threshold": "pose", "_twist_rejection_threshold": "twist"})
