"""A PID controller on one scalar (seed 000, eq. 34-37) with the practical fixes it needs.

The seed's form sums raw errors and differences them per update. Here the terms are
normalised by the real time step Δt (integer nanoseconds in, seconds inside), so the gains
do not change when the control rate does:

    u = kp·e + ki·∫e dt − kd·d(measurement)/dt

* derivative on measurement, not on error: a jump of the setpoint (a new target point,
  a new leg) gives no derivative kick;
* the integral is clamped to ±``integral_limit`` (anti-windup);
* the output is clamped to ±``output_limit``;
* angular controllers wrap the error and the measurement difference to (−π, π].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.units import ns_to_seconds


@dataclass(frozen=True)
class PIDGains:
    """Gains (SI, per second) and limits of one PID; all must be finite and >= 0."""

    kp: float
    ki: float = 0.0
    kd: float = 0.0
    integral_limit: float = math.inf  # bound on ∫e dt (error unit · s)
    output_limit: float = math.inf  # bound on |u|

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        for name in ("integral_limit", "output_limit"):
            value = getattr(self, name)
            if math.isnan(value) or value <= 0.0:
                raise ValueError(f"{name} must be > 0 (inf allowed), got {value!r}")


class PID:
    """One PID loop. ``update(setpoint, measurement, t_ns)`` returns the control action."""

    __slots__ = ("gains", "angular", "integral", "_last_measurement", "_last_t_ns", "last_error")

    def __init__(self, gains: PIDGains, angular: bool = False) -> None:
        self.gains = gains
        self.angular = angular
        self.reset()

    def reset(self) -> None:
        """Forget the integral and the previous measurement (next update is P + I only)."""
        self.integral = 0.0
        self.last_error = 0.0
        self._last_measurement: float | None = None
        self._last_t_ns: int | None = None

    def update(self, setpoint: float, measurement: float, t_ns: int) -> float:
        """Control action at time ``t_ns`` (int ns). Δt <= 0 skips the I and D terms."""
        g = self.gains
        error = setpoint - measurement  # eq. 35
        if self.angular:
            error = wrap_angle(error)
        derivative = 0.0
        last_t = self._last_t_ns
        if last_t is not None and t_ns > last_t:
            dt = ns_to_seconds(t_ns - last_t)
            # eq. 36 with Δt, clamped (anti-windup)
            integral = self.integral + error * dt
            lim = g.integral_limit
            self.integral = lim if integral > lim else (-lim if integral < -lim else integral)
            delta = measurement - self._last_measurement
            if self.angular:
                delta = wrap_angle(delta)
            derivative = -delta / dt  # eq. 37 on the measurement, divided by the real Δt
        if last_t is None or t_ns > last_t:
            self._last_measurement = measurement
            self._last_t_ns = t_ns
        self.last_error = error
        u = g.kp * error + g.ki * self.integral + g.kd * derivative  # eq. 34
        lim = g.output_limit
        return lim if u > lim else (-lim if u < -lim else u)
