"""The Localizer's configuration: plain, validated dataclasses and their defaults (no ROS).

The defaults written here are the only ones: the parameter schema
(:mod:`ekf_localization.ros.ekf_parameters`, which parses and validates ekf_node's
parameters into an :class:`EkfConfig`) and docs/ekf_node.md take them from these classes.
What only the node uses (output rate, TF, markers, topics, scheduling) is not here but in
:mod:`ekf_localization.ros.ekf_node_settings`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ekf_localization.core.measurements import N_FIELDS
from ekf_localization.core.recovery import RecoveryConfig
from ekf_localization.core.units import METRES_PER_INCH, seconds_to_ns

MECANUM_WHEELS = ("rear_left", "rear_right", "front_left", "front_right")  # eq. 24's m1..m4
# Seed 000 (eq. 26) in SI: 0.002 in²/s = 1.2903e-6 m²/s, 0.45 (in/s)² = 2.9032e-4 (m/s)².
_IN2 = METRES_PER_INCH ** 2


def _diag15(values: dict[int, float], rest: float) -> np.ndarray:
    d = np.full(N_FIELDS, rest)
    for i, v in values.items():
        d[i] = v
    return np.diag(d)


DEFAULT_PROCESS_NOISE = np.diag([0.05, 0.05, 0.06, 0.03, 0.03, 0.06, 0.025, 0.025, 0.04,
                                 0.01, 0.01, 0.02, 0.01, 0.01, 0.015])  # RL's default
DEFAULT_INITIAL_COVARIANCE = _diag15({0: 1.0, 1: 1.0, 5: 1.0, 6: 1.0, 7: 1.0, 11: 1.0}, 1e-9)
DEFAULT_CONTROL_VELOCITY_VARIANCE = (0.45 * _IN2, 0.45 * _IN2, 0.0, 0.0, 0.0, 0.45)


# Plausibility limits: above any FTC/FRC drive (about 5 m/s, 15 rad/s) with margin.
DEFAULT_MAX_PLAUSIBLE_SPEED = 10.0
DEFAULT_MAX_PLAUSIBLE_ANGULAR_SPEED = 35.0
DEFAULT_MAX_PLAUSIBLE_ACCELERATION = 100.0
DEFAULT_MAX_PLAUSIBLE_POSITION = 1000.0

@dataclass(frozen=True)
class InputConfig:
    """One sensor input (odom0, imu0, joint0, ...): what every kind has. Its kind's own settings
    are ``settings`` (ekf_localization.inputs: e.g. parts.PartsSettings, an EncoderInputConfig)
    and ``handler`` builds what fuses its messages (core.fusion_context.Handler)."""

    name: str  # "odom0"
    kind: str  # its kind in ekf_localization.inputs.KINDS
    topic: str
    settings: Any
    handler: Callable[..., Any]  # (InputConfig, FusionContext) -> Handler
    queue_size: int = 10
    rejection_thresholds: tuple[tuple[str, float], ...] = ()  # (part name, Mahalanobis sigmas)
    variance_scale: float = 1.0  # every message covariance is multiplied by this (ekf_tune fits it)

    def threshold(self, part: str) -> float:
        return dict(self.rejection_thresholds).get(part, math.inf)


@dataclass(frozen=True)
class EkfConfig:
    """Everything the Localizer needs, validated. Times in seconds and ns."""

    model: str = "mecanum"
    sensor_timeout: float = 1.0 / 30.0  # the schema's default: 1 / frequency (ekf_node's output rate)
    base_link_frame: str = "base_link"
    world_frame: str = "odom"  # the schema's default: odom_frame (ekf_node's map_frame or odom_frame)
    predict_to_current_time: bool = True
    smooth_lagged_data: bool = True
    history_length: float = 1.0
    max_measurement_age: float = 2.0  # the schema's default: max(2.0, history_length)
    future_stamp_tolerance: float = 0.1  # s: clock skew between machines, not a stamp 200 ms ahead
    max_prediction_step: float = 0.01
    use_control: bool = False
    control_timeout: float = 0.2
    control_velocity_variance: tuple[float, ...] = DEFAULT_CONTROL_VELOCITY_VARIANCE
    control_tilt_compensation: bool = False
    control_time_constant: tuple[float, ...] = (0.0,) * 6
    acceleration_limits: tuple[float, ...] = (0.0,) * 6  # 0 = no limit
    deceleration_limits: tuple[float, ...] = (0.0,) * 6
    control_latency: float = 0.0
    control_velocity_limits: tuple[float, ...] = (0.0,) * 6  # 0 = no check
    control_guard: bool = True  # core.command_guard: drop commands the drive does not follow
    control_guard_window: float = 0.25  # s
    control_guard_false_alarm: float = 1.0e-3  # the χ² test's size per window
    control_guard_confirm: float = 0.03  # s without a velocity measurement: unconfirmed
    wheel_radius: float = 0.0  # 0 = no wheel geometry
    half_wheelbase: float = 0.0
    half_track: float = 0.0
    wheel_acceleration_limit: float = 0.0  # 0 = per-axis limits
    wheel_speed_limit: float = 0.0  # 0 = none
    control_steer_rate_limit: float = 0.0  # rad/s; > 0: the swerve response (0 = per-axis)
    control_module_positions: tuple[float, ...] = ()  # [x0, y0, x1, y1, ...] m, for the swerve response
    wheel_order: tuple[str, ...] = MECANUM_WHEELS  # the wheel of each array entry
    process_noise_covariance: np.ndarray = field(default_factory=DEFAULT_PROCESS_NOISE.copy)  # (15, 15)
    initial_estimate_covariance: np.ndarray = field(
        default_factory=DEFAULT_INITIAL_COVARIANCE.copy)  # (15, 15)
    initial_state: np.ndarray = field(default_factory=lambda: np.zeros(N_FIELDS))
    inputs: tuple[InputConfig, ...] = ()
    # (parent, child, (x, y, z, yaw, pitch, roll)): static_transform_publisher's meaning
    static_transforms: tuple[tuple[str, str, tuple[float, ...]], ...] = ()
    zero_variance_floor: float = 1e-9  # a zero variance on a fused field is replaced by this
    max_plausible_speed: float = DEFAULT_MAX_PLAUSIBLE_SPEED
    max_plausible_angular_speed: float = DEFAULT_MAX_PLAUSIBLE_ANGULAR_SPEED
    max_plausible_acceleration: float = DEFAULT_MAX_PLAUSIBLE_ACCELERATION
    max_plausible_position: float = DEFAULT_MAX_PLAUSIBLE_POSITION
    pose_recovery: bool = True
    pose_recovery_min_fixes: int = 10
    pose_recovery_min_duration: float = 1.0
    pose_recovery_agreement: float = 0.2
    pose_recovery_angle_agreement: float = 0.3

    @property
    def recovery(self) -> RecoveryConfig:
        return RecoveryConfig(self.pose_recovery, self.pose_recovery_min_fixes,
                              seconds_to_ns(self.pose_recovery_min_duration), self.pose_recovery_agreement,
                              self.pose_recovery_angle_agreement)

    @property
    def plausible_bounds(self) -> np.ndarray:
        """(15,) largest plausible |value| per RL field (angles: unbounded, they are wrapped)."""
        p, v, w, a = (self.max_plausible_position, self.max_plausible_speed, self.max_plausible_angular_speed,
                      self.max_plausible_acceleration)
        return np.array([p, p, p, math.inf, math.inf, math.inf, v, v, v, w, w, w, a, a, a])

    @property
    def history_length_ns(self) -> int:
        return seconds_to_ns(self.history_length)

    @property
    def max_measurement_age_ns(self) -> int:
        return seconds_to_ns(self.max_measurement_age)

    @property
    def future_stamp_tolerance_ns(self) -> int:
        return seconds_to_ns(self.future_stamp_tolerance)

    @property
    def max_prediction_step_ns(self) -> int:
        return seconds_to_ns(self.max_prediction_step)

    @property
    def control_timeout_ns(self) -> int:
        return seconds_to_ns(self.control_timeout)

    @property
    def control_guard_confirm_ns(self) -> int:
        return seconds_to_ns(self.control_guard_confirm)

    @property
    def control_guard_window_ns(self) -> int:
        return seconds_to_ns(self.control_guard_window)

    @property
    def control_latency_ns(self) -> int:
        return seconds_to_ns(self.control_latency)

    @property
    def sensor_timeout_ns(self) -> int:
        return seconds_to_ns(self.sensor_timeout)
