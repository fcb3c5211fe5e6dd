"""ekf_node's own settings around the Localizer's :class:`EkfConfig`: plain, validated (no rclpy).

ekf_node's parameters are of two kinds. What the filter needs (model, noise, inputs, frames of
the estimate, lag handling) is the core's :class:`EkfConfig`. What only the node does with the
estimate (how often and where it publishes, which TF it broadcasts, the cmd_vel topic and
message type, the wheel command topic, its thread priority) is here. One schema
(:mod:`ekf_localization.ros.ekf_parameters`) parses both from the same parameter file, and
takes its defaults from these classes. The offline replay takes these settings too: it
reproduces the node's output times.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.units import seconds_to_ns


@dataclass(frozen=True)
class EkfNodeSettings:
    """ekf_node's parameters: the Localizer's ``config`` and what only the node uses."""

    config: EkfConfig = field(default_factory=EkfConfig)  # the Localizer's
    frequency: float = 30.0  # Hz, rate of odometry/filtered
    map_frame: str = "map"  # REP-105 frames, for the TF the node broadcasts
    odom_frame: str = "odom"
    publish_tf: bool = True
    publish_on_measurement: bool = False  # publish from each fused message's callback, not only the timer
    print_diagnostics: bool = True
    publish_markers: bool = False  # visualization_msgs/MarkerArray on ekf_node/markers
    publish_fusion_log: bool = True  # ekf_node/fusion_log: what was fused when (ros/fusion_log.py)
    marker_frequency: float = 5.0  # Hz
    marker_fix_count: int = 40  # recent pose fixes drawn
    thread_priority: int = 0  # SCHED_FIFO priority of ekf_node's threads; 0: the default scheduling
    stamped_cmd_vel: bool = False  # cmd_vel is TwistStamped (false: Twist)
    cmd_vel_topic: str = "cmd_vel"  # where the commands are read (a controller's own topic)
    wheel_command_topic: str = ""  # "" = no wheel-speed command input
    warnings: tuple[str, ...] = ()  # start-up warnings for the node to log

    @property
    def publish_period_ns(self) -> int:
        return seconds_to_ns(1.0 / self.frequency)


# The settings that are ekf_node parameters of the node's own (not the config, not the warnings).
NODE_SETTINGS = tuple(f.name for f in fields(EkfNodeSettings) if f.name not in ("config", "warnings"))
