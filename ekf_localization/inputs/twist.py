"""``twistN``: geometry_msgs/TwistWithCovarianceStamped (RL's twistN)."""

from __future__ import annotations

from ekf_localization.core.measurements import TwistMeasurement
from ekf_localization.inputs.kind import InputKind, covariance, header_of, twist6


def read(msg) -> TwistMeasurement:
    stamp, frame = header_of(msg)
    return TwistMeasurement(stamp_ns=stamp, frame_id=frame, twist=twist6(msg.twist.twist),
                            covariance=covariance(msg.twist.covariance, 6))


KIND = InputKind("twist", "geometry_msgs/msg/TwistWithCovarianceStamped", read, parts=(("twist", 6, 6),),
                 thresholds={"_rejection_threshold": "twist"})
