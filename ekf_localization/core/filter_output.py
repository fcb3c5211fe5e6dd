"""The read side of the Localizer: the estimate to publish and what it reports (no ROS imports).

:class:`FilterOutput` is the base of :class:`ekf_localization.core.localizer.Localizer`, which
fills in the timeline, the clock, the tilt and the counters it reads.

* The output is a prediction of a *copy* of the committed state to the requested time
  (:meth:`FilterOutput.estimate_at`, :meth:`FilterOutput.advance_to`): publishing never moves
  the filter. With ``predict_to_current_time`` false it is stamped at the newest measurement
  (robot_localization's default) until ``sensor_timeout`` passes without one.
"""

from __future__ import annotations

from collections.abc import Callable

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.input_frames import InputFrames
from ekf_localization.core.outcomes import Estimate, Innovation, NisTally
from ekf_localization.core.receive_clock import ReceiveClock
from ekf_localization.core.tilt import TiltSample
from ekf_localization.core.tilt_input import TiltInput
from ekf_localization.core.timeline import Entry, Timeline
from ekf_localization.core.update_step import UpdateStep


class FilterOutput:
    """The estimates and the state of the filter, read without changing it."""

    config: EkfConfig
    state_fields: tuple[int, ...]
    nonfinite_outputs: int
    _timeline: Timeline
    _clock: ReceiveClock
    _tilt: TiltInput
    _frames: InputFrames
    _nis: NisTally
    _step: UpdateStep
    _last_output_ns: int | None

    def _observe_clock(self, now_ns: int | None) -> int | None:
        """Take the receiver's clock (the Localizer's: a clock going back resets the filter)."""
        raise NotImplementedError

    @property
    def innovation_listener(self) -> Callable[[Innovation], None] | None:
        """Called with every update's Innovation when set (tools: tuning, consistency reports)."""
        return self._step.innovation_listener

    @innovation_listener.setter
    def innovation_listener(self, listener: Callable[[Innovation], None] | None) -> None:
        self._step.innovation_listener = listener

    @property
    def nis(self) -> dict[str, list[float]]:
        """"source/part" -> [sum of NIS, count, dimension] over every first-pass update (a copy)."""
        return self._nis.totals()

    @property
    def initialized(self) -> bool:
        return self._timeline.initialized

    @property
    def time_ns(self) -> int | None:
        """Stamp of the committed state (None before the first measurement)."""
        return self._timeline.t_ns if self._timeline.initialized else None

    @property
    def clock_ns(self) -> int | None:
        return self._clock.now_ns

    @property
    def frame_cache(self) -> tuple[int, int, int]:
        """(entries, cap, evictions) of the per-frame bookkeeping (core.input_frames)."""
        return self._frames.frame_cache

    @property
    def history(self) -> list[Entry]:
        """The timeline's entries, oldest first: those applied, then the commands still deferred."""
        return [*self._timeline.history, *self._timeline.deferred]

    @property
    def history_size(self) -> int:
        return len(self._timeline.history)

    rewinds = property(lambda self: self._timeline.rewinds)
    skipped_rewinds = property(lambda self: self._timeline.skipped_rewinds)  # over timeline's replay bound
    earliest_insertable_ns = property(lambda self: self._timeline.earliest_insertable_ns,
                                      doc="Oldest stamp a measurement may have and still act at its time.")
    newest_measurement_ns = property(lambda self: self._timeline.newest_measurement_ns)

    def committed(self) -> Estimate | None:
        """The committed state itself (not predicted)."""
        tl = self._timeline
        if not tl.initialized:
            return None
        return Estimate(tl.t_ns, tl.ekf.x.copy(), tl.ekf.P.copy(), self.state_fields)

    def tilt_at(self, stamp_ns: int) -> TiltSample | None:
        """The IMU's roll/pitch in effect at ``stamp_ns`` (None without a tilt sample)."""
        return self._tilt.at(stamp_ns)

    def estimate_at(self, t_ns: int) -> Estimate | None:
        """The estimate at ``t_ns`` without changing the filter: predicted forward from the
        committed state (commands included), or from the history for an earlier time (None
        if older than it, or before the start)."""
        xP = self._timeline.estimate_at(int(t_ns))
        return None if xP is None else Estimate(int(t_ns), xP[0], xP[1], self.state_fields)

    def advance_to(self, now_ns: int) -> Estimate | None:
        """The estimate to publish at clock time ``now_ns``, or None (not started, or nothing new).

        Stamped at ``now_ns`` when ``predict_to_current_time``; otherwise at the newest
        measurement, or at ``now_ns`` once ``sensor_timeout`` has passed without one. Output
        stamps strictly increase (a lagged measurement does not republish an old stamp).
        """
        self._observe_clock(now_ns)
        tl = self._timeline
        if not tl.initialized:
            return None
        now_ns = int(now_ns)
        newest = tl.newest_measurement_ns
        if self.config.predict_to_current_time or newest is None \
                or now_ns - newest >= self.config.sensor_timeout_ns:
            t = max(now_ns, tl.t_ns)
        else:
            t = max(newest, tl.t_ns)
        if self._last_output_ns is not None and t <= self._last_output_ns:
            return None
        est = self.estimate_at(t)
        if est is None:
            return None
        if not est.is_finite():
            self.nonfinite_outputs += 1
            return None
        self._last_output_ns = t
        extra = self._tilt.attitude(t)
        if extra:  # z (dead-reckoned on the ramp) and the IMU's roll and pitch
            est = Estimate(est.stamp_ns, est.state, est.covariance, est.state_fields, extra)
        return est
