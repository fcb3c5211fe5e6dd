"""Which command drives the process model when, and the prediction across command changes.

A command (cmd_vel, a wheel command) acts from ``control_latency`` after its stamp: until then
the command before it still drives. It acts for ``control_timeout``; then the model coasts to
rest (a zero command). A process input read from a message (e.g. an IMU's forward
acceleration, seed 001 eq. 2) acts from its stamp, with no latency and no coasting. Before any
command the model holds its velocity (U = None). No ROS imports.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ekf_localization.core.command_guard import CommandGuard
from ekf_localization.core.config import EkfConfig
from ekf_localization.core.ekf import ExtendedKalmanFilter
from ekf_localization.core.measurements import REJECT_IMPLAUSIBLE, REJECT_LIMITS, REJECT_NONFINITE
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.tilt import TiltSample, horizontal_projection

_CONTROL_FIELDS = np.arange(6, dtype=np.intp)  # the command twist, fields vx .. vyaw
MAX_PREDICTION_STEPS = 1000  # per prediction: 10 s at 10 ms steps; a longer gap (a day) in longer steps
MAX_PENDING_COMMANDS = 16  # links of a chain: a burst of commands costs O(1) each, never O(burst)


class Command(NamedTuple):
    """A command and the one it replaces: ``previous`` (itself a chain while commands arrive
    faster than the latency) acts until stamp + latency."""

    stamp_ns: int
    u: np.ndarray
    previous: Command | None
    drive: bool = True  # a cmd_vel command (latency, coasting); False: a process input


class CommandModel:
    """The command in effect at any time, and predictions split where it changes."""

    def __init__(self, latency_ns: int, timeout_ns: int, max_step_ns: int, coast: np.ndarray | None) -> None:
        self.latency_ns = latency_ns
        self.timeout_ns = timeout_ns
        self.max_step_ns = max(1, max_step_ns)
        self.coast = coast  # the model input of a drive at rest (None: the model takes no command)
        self.guard: CommandGuard | None = None  # drops drive commands it does not trust

    def _start(self, command: Command) -> int:
        return command.stamp_ns + (self.latency_ns if command.drive else 0)

    def then(self, current: Command | None, stamp_ns: int, u: np.ndarray, drive: bool) -> Command:
        """The chain after a new command stamped ``stamp_ns``: a drive command keeps the ones
        that still act before its latency has passed. A link that would never act (stamped at or
        after the new one: a burst) is dropped, and of a chain longer than MAX_PENDING_COMMANDS
        the oldest pending links (each acting for less than latency / MAX_PENDING_COMMANDS on
        average) go, the one acting now kept: the chain, and the cost of a command, stay bounded."""
        if not drive:
            return Command(stamp_ns, u, None, drive=False)
        links = []  # newest first
        link = self.acting_from(current, stamp_ns)
        while link is not None:
            if link.stamp_ns < stamp_ns or not link.drive:
                links.append(link)
            link = link.previous
        if len(links) >= MAX_PENDING_COMMANDS:  # keep the newest ones and the one acting now
            links = links[:MAX_PENDING_COMMANDS - 2] + links[-1:]
        chain = None
        for link in reversed(links):
            chain = link._replace(previous=chain)
        return Command(stamp_ns, u, chain)

    def acting_from(self, command: Command | None, t_ns: int) -> Command | None:
        """The chain as far as it can act at or after ``t_ns`` (older links dropped)."""
        if command is None:
            return None
        if t_ns >= self._start(command):
            return command._replace(previous=None)
        return command._replace(previous=self.acting_from(command.previous, t_ns))

    def at(self, command: Command | None, t_ns: int) -> tuple[np.ndarray | None, float]:
        """The model input in effect at ``t_ns`` and the time it next changes."""
        if command is None:
            return None, math.inf
        start = self._start(command)
        if t_ns < start:  # its predecessors until then
            u, change = self.at(command.previous, t_ns)
            return u, min(change, start)
        expiry = start + self.timeout_ns
        if t_ns < expiry:
            return command.u, expiry
        return (self.coast if command.drive else None), math.inf

    def propagate(self, ekf: ExtendedKalmanFilter, t_ns: int, to_ns: int,
                  command: Command | None) -> tuple[int, bool]:
        """Predict ``ekf`` from ``t_ns`` to ``to_ns`` in steps of at most max_prediction_step (at most
        MAX_PREDICTION_STEPS of them: a longer gap takes longer steps), split where the command
        changes. Returns (the new time, every step finite)."""
        step = self.max_step_ns
        if to_ns - t_ns > MAX_PREDICTION_STEPS * step:
            step = -(-(to_ns - t_ns) // MAX_PREDICTION_STEPS)
        ok = True
        while t_ns < to_ns:
            u, change = self.at(command, t_ns)
            if self.guard is not None and u is not None:
                u, change = self.guard.screen(u, change, t_ns, ekf)
            end = int(min(to_ns, t_ns + step, change))
            ok &= ekf.predict(end - t_ns, u)
            t_ns = end
        return t_ns, ok


class CommandInput:
    """Drive commands: cmd_vel's twist or wheel speeds turned into one (seed 000 eq. 23-24),
    checked, as the model's input; the :class:`CommandModel` that says which acts when, and its
    guard (core.command_guard), which drops commands the drive does not follow and widens P
    while it does (``CommandGuard.screen``: the one place a command changes P)."""

    def __init__(self, config: EkfConfig, spec: MotionModelSpec, state_fields: tuple[int, ...]) -> None:
        self._from_twist = spec.control_from_twist if config.use_control else None
        limits = np.asarray(config.control_velocity_limits, dtype=float).tolist()
        # per twist field: the larger |value| refused as beyond the limits, and as implausible
        self._limits = [lim if lim > 0.0 else math.inf for lim in limits]
        self._bounds = np.asarray(config.plausible_bounds, dtype=float)[_CONTROL_FIELDS + 6].tolist()
        self._twist_from_wheels = None
        if config.wheel_radius > 0.0 and spec.twist_from_wheels is not None:
            wheels, self._twist_from_wheels = spec.twist_from_wheels(config)
            # array index of each of the model's wheels in the message
            self._wheel_index = np.array([config.wheel_order.index(w) for w in wheels], dtype=np.intp)
        latency = config.control_latency_ns if config.use_control else 0
        coast = spec.control_from_twist(np.zeros(6)) if spec.takes_control else None  # at rest
        self.model = CommandModel(latency, config.control_timeout_ns, config.max_prediction_step_ns, coast)
        self.model.guard = self.guard = CommandGuard.of(config, state_fields, self.used)

    def acting_stamp(self, stamp_ns: int, now_ns: int | None) -> int:
        """The stamp a drive command takes on the timeline: its own, so that it acts at stamp +
        ``control_latency``; or, received after that time (a late publisher: the drive got it late
        as well, and a drive acts on a command when it gets it), ``now_ns`` - latency, so that it
        acts from its receipt. Either way the drive never acts on a command before it exists."""
        latency = self.model.latency_ns
        if now_ns is None or stamp_ns + latency >= now_ns:
            return stamp_ns
        return now_ns - latency

    @property
    def used(self) -> bool:
        """Whether commands drive the model (``use_control`` and a model that takes them)."""
        return self._from_twist is not None

    def twist_of_wheels(self, speeds) -> np.ndarray | None:
        """The body twist [vx vy vz wx wy wz] of wheel speeds in ``wheel_order`` (None: not one per wheel)."""
        w = np.asarray(speeds, dtype=float).ravel()
        if self._twist_from_wheels is None or w.shape != (len(self._wheel_index),):
            return None
        v = self._twist_from_wheels @ w[self._wheel_index]
        return np.array([v[0], v[1], 0.0, 0.0, 0.0, v[2]]) if np.all(np.isfinite(w)) else np.full(6, np.nan)

    def model_input(self, twist: np.ndarray, tilt: TiltSample | None = None) -> tuple[np.ndarray, str | None]:
        """(the model's input u, or the reason the command is refused: non-finite, beyond
        ``control_velocity_limits``, beyond the plausible bounds). With the ramp's ``tilt``, the
        body velocity along the surface becomes the horizontal one."""
        u = self._from_twist(twist)
        if not all(map(math.isfinite, u.tolist())):
            return u, REJECT_NONFINITE
        values = np.asarray(twist, dtype=float).tolist()  # (six values: Python's loops)
        if any(abs(v) > lim for v, lim in zip(values, self._limits, strict=True)):
            return u, REJECT_LIMITS
        implausible = any(abs(v) > b for v, b in zip(values, self._bounds, strict=True))
        reason = REJECT_IMPLAUSIBLE if implausible else None
        if reason is None and tilt is not None:
            u = horizontal_projection(tilt.roll, tilt.pitch) @ u
        return u, reason
