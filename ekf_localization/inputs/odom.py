"""``odomN``: nav_msgs/Odometry, pose in ``frame_id`` and twist in ``child_frame_id`` (RL's odomN)."""

from __future__ import annotations

from ekf_localization.core.measurements import OdometryMeasurement
from ekf_localization.inputs.kind import InputKind, covariance, header_of, pose6, twist6
from ekf_localization.inputs.parts import (
    COMMON,
    POSE_FRAME,
    POSE_USE_CHILD_FRAME,
    TILT_COMPENSATION,
    TWIST_COVARIANCE,
    PartsSettings,
    configure_parts,
    parts_handler,
)

PARTS = (("pose", 0, 6), ("twist", 6, 6))


def read(msg) -> OdometryMeasurement:
    stamp, frame = header_of(msg)
    return OdometryMeasurement(stamp_ns=stamp, frame_id=frame, child_frame_id=str(msg.child_frame_id),
                               pose=pose6(msg.pose.pose), pose_covariance=covariance(msg.pose.covariance, 6),
                               twist=twist6(msg.twist.twist),
                               twist_covariance=covariance(msg.twist.covariance, 6))


def configure(values, name, spec, report) -> PartsSettings:
    return configure_parts(values, name, spec, report, "odom", PARTS)


KIND = InputKind("odom", "nav_msgs/msg/Odometry", read, configure, parts_handler, parts=PARTS,
                 thresholds={"_pose_rejection_threshold": "pose", "_twist_rejection_threshold": "twist"},
                 common=COMMON,
                 parameters=(TILT_COMPENSATION, TWIST_COVARIANCE, POSE_FRAME, POSE_USE_CHILD_FRAME))
