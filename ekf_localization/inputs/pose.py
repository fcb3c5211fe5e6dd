"""``poseN``: geometry_msgs/PoseWithCovarianceStamped (RL's poseN; a camera's field pose)."""

from __future__ import annotations

from ekf_localization.core.measurements import PoseMeasurement
from ekf_localization.inputs.kind import InputKind, covariance, header_of, pose6
from ekf_localization.inputs.parts import COMMON, POSE_FRAME, PartsSettings, configure_parts, parts_handler

PARTS = (("pose", 0, 6),)


def read(msg) -> PoseMeasurement:
    stamp, frame = header_of(msg)
    return PoseMeasurement(stamp_ns=stamp, frame_id=frame, pose=pose6(msg.pose.pose),
                           covariance=covariance(msg.pose.covariance, 6))


def configure(values, name, spec, report) -> PartsSettings:
    return configure_parts(values, name, spec, report, "pose", PARTS)


KIND = InputKind("pose", "geometry_msgs/msg/PoseWithCovarianceStamped", read, configure, parts_handler,
                 parts=PARTS, thresholds={"_rejection_threshold": "pose"}, common=COMMON,
                 parameters=(POSE_FRAME,), absolute_pose=True)
