"""``poseN``: geometry_msgs/PoseWithCovarianceStamped (RL's poseN; a camera's field pose)."""

from __future__ import annotations

from ekf_localization.core.measurements import PoseMeasurement
from ekf_localization.inputs.kind import InputKind, covariance, header_of, pose6


def read(msg) -> PoseMeasurement:
    stamp, frame = header_of(msg)
    return PoseMeasurement(stamp_ns=stamp, frame_id=frame, pose=pose6(msg.pose.pose),
                           covariance=covariance(msg.pose.covariance, 6))


KIND = InputKind("pose", "geometry_msgs/msg/PoseWithCovarianceStamped", read, parts=(("pose", 0, 6),),
                 thresholds={"_rejection_threshold": "pose"})
