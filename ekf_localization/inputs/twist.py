"""``twistN``: geometry_msgs/TwistWithCovarianceStamped (RL's twistN)."""

from __future__ import annotations

from ekf_localization.core.measurements import TwistMeasurement
from ekf_localization.inputs.kind import InputKind, covariance, header_of, twist6
from ekf_localization.inputs.parts import (
    COMMON,
    TILT_COMPENSATION,
    TWIST_COVARIANCE,
    PartsSettings,
    configure_parts,
    parts_handler,
)

PARTS = (("twist", 6, 6),)


def read(msg) -> TwistMeasurement:
    stamp, frame = header_of(msg)
    return TwistMeasurement(stamp_ns=stamp, frame_id=frame, twist=twist6(msg.twist.twist),
                            covariance=covariance(msg.twist.covariance, 6))


def configure(values, name, spec, report) -> PartsSettings:
    return configure_parts(values, name, spec, report, "twist", PARTS, poses=False)


KIND = InputKind("twist", "geometry_msgs/msg/TwistWithCovarianceStamped", read, configure, parts_handler,
                 parts=PARTS, thresholds={"_rejection_threshold": "twist"}, common=COMMON,
                 parameters=(TILT_COMPENSATION, TWIST_COVARIANCE))
