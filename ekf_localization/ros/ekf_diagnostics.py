"""ekf_node's /diagnostics: a status for the filter, one for consistency, one per source
(REP-107 style key/values). The values are the Localizer's counters and those of the last
period (rates, new rejections, the period's mean NIS against its χ² band); a value not known
yet is left out, never published as "nan"."""

from __future__ import annotations

import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from ekf_localization.core.chi2_bands import mean_chi2_band
from ekf_localization.core.localizer import CONTROL_SOURCE, SET_POSE_SOURCE, WHEEL_COMMAND_SOURCE, Localizer
from ekf_localization.core.measurements import REJECT_REASONS
from ekf_localization.core.units import ns_to_seconds


class EkfDiagnostics:
    """What ekf_node publishes on /diagnostics, and what it remembers from the last period."""

    def __init__(self, localizer: Localizer, wheel_commands: bool) -> None:
        self._localizer = localizer
        self._wheel_commands = wheel_commands  # a wheel-command input is configured
        self._diag_prev: dict[str, tuple[int, int]] = {}
        self._failures_prev = (0, 0, 0)  # filter failure counters at the previous diagnostics
        self._overloaded_prev = 0  # lagged messages dropped as overloaded, at the previous diagnostics
        self._floor_reported: set[str] = set()
        self._nis_prev: dict[str, tuple[float, int]] = {}

    def _nis_values(self, source: str) -> tuple[list[tuple[str, str]], list[str]]:
        """``nis_<part>``: the mean NIS of this input's updates in the last period (first passes,
        gated ones included), ``nis_<part>_dof``, its degrees of freedom (the χ² mean), and
        ``nis_<part>_band``: the 95 % two-sided band of the mean of that many χ²(dof) values
        (core.chi2_bands); and the parts whose mean left its band."""
        out, outside = [], []
        for key, acc in self._localizer.nis.items():
            src, _, part = key.partition("/")
            if src != source:
                continue
            mean, count = _nis_period(acc, self._nis_prev.get(key))
            self._nis_prev[key] = (acc[0], acc[1])
            out.append((f"nis_{part}", "none" if mean is None else f"{mean:.3f}"))
            out.append((f"nis_{part}_dof", str(acc[2])))
            if mean is not None:
                lo, hi = mean_chi2_band(acc[2], count)
                out.append((f"nis_{part}_band", f"[{lo:.3f}, {hi:.3f}]"))
                if not lo <= mean <= hi:
                    outside.append(f"{part} {mean:.2f} [{lo:.2f}, {hi:.2f}]")
        return out, outside

    def statuses(self, name: str, steady: int, now: int | None, internal_errors: int,
                 counters: tuple[tuple[str, Any], ...]) -> list[DiagnosticStatus]:
        """The node's statuses: ``<name>: filter``, ``<name>: consistency`` and one per source.
        ``steady`` (ns) times the rates; ``now`` is the filter's clock; ``internal_errors``
        counts towards the filter's failures; ``counters`` are the node's own values."""
        loc = self._localizer
        cfg = loc.config
        timeout_ns = cfg.sensor_timeout_ns
        statuses = []
        outside: list[str] = []  # input parts whose period NIS left its band
        stale_inputs: list[str] = []
        failing_inputs: list[str] = []
        topics = {inp.name: inp.topic for inp in cfg.inputs}
        wheels = [WHEEL_COMMAND_SOURCE] if cfg.use_control and self._wheel_commands else []
        sources = list(topics) + ([CONTROL_SOURCE] if cfg.use_control else []) + wheels + [SET_POSE_SOURCE]
        for source in sources:
            st = loc.stats[source]
            prev = self._diag_prev.get(source)
            rate = 0.0
            if prev is not None and steady > prev[1]:
                rate = (st.received - prev[0]) / ns_to_seconds(steady - prev[1])
            self._diag_prev[source] = (st.received, steady)
            prev_rej = self._diag_prev.get(source + "#rejected", (0, 0))[0]
            new_rejected = st.rejected_total - prev_rej
            self._diag_prev[source + "#rejected"] = (st.rejected_total, steady)
            level, message = _input_status(st, now, timeout_ns, new_rejected, source in topics)
            if st.fault and not message.startswith("no message"):  # its handler's verdict (units guard)
                level, message = DiagnosticStatus.ERROR, st.fault
            if level == DiagnosticStatus.ERROR:
                failing_inputs.append(source)
            elif source in topics and message.startswith("no message"):
                stale_inputs.append(source)
            if st.zero_variances_floored and source not in self._floor_reported:  # warned once
                self._floor_reported.add(source)
                floor = (f"zero variance on a fused field: replaced by zero_variance_floor "
                         f"({cfg.zero_variance_floor:g}); fix the driver's covariances")
                if level == DiagnosticStatus.OK:
                    level, message = DiagnosticStatus.WARN, floor
                else:
                    message += "; " + floor
            values = [("topic", topics.get(source, source)), ("rate_hz", f"{rate:.1f}"),
                      ("received", st.received), ("applied", st.applied),
                      ("applied_as_current", st.applied_as_current), ("rejected", st.rejected_total),
                      ("zero_variances_floored", st.zero_variances_floored), ("recoveries", st.recoveries),
                      ("slips", st.slips), ("widened", st.widened)]
            values += [(f"rejected_{r}", st.rejected.get(r, 0)) for r in REJECT_REASONS]
            values.append(("last_stamp_age_s", _seconds(None if now is None or st.last_stamp_ns is None
                                                        else now - st.last_stamp_ns)))
            values.append(("last_stamp_lag_s", _seconds(st.last_stamp_lag_ns)))
            nis_values, nis_out = self._nis_values(source)
            values += nis_values
            outside += [f"{source}/{part}" for part in nis_out]
            if source == CONTROL_SOURCE and loc.command_guard is not None:
                level, message, guard_values = _guard_status(loc.command_guard, level, message)
                values += guard_values
            statuses.append(_status(f"{name}: {source}", topics.get(source, source), level, message, values))
        est = loc.committed()
        size, cap, evicted = loc.frame_cache
        failures = (loc.predict_failures, loc.nonfinite_outputs, internal_errors)
        new_failures = [a - b for a, b in zip(failures, self._failures_prev, strict=True)]
        self._failures_prev = failures
        level, message = DiagnosticStatus.OK, "tracking"
        if est is None:
            level, message = DiagnosticStatus.WARN, "waiting for the first measurement or set_pose"
        elif stale_inputs:
            level, message = DiagnosticStatus.WARN, "stale inputs: " + ", ".join(stale_inputs)
        overloaded = loc.skipped_rewinds - self._overloaded_prev  # timeline.MAX_REPLAY_ENTRIES
        self._overloaded_prev = loc.skipped_rewinds
        if overloaded:
            level, message = DiagnosticStatus.WARN, (f"overloaded: dropped {overloaded} lagged messages "
                                                     "(the CPU cannot replay their history in time)")
        if failing_inputs:
            level, message = DiagnosticStatus.ERROR, "every message rejected: " + ", ".join(failing_inputs)
        if any(new_failures):  # in the last period: clears once the filter runs cleanly again
            level, message = DiagnosticStatus.ERROR, "filter failures in the last period (see counters)"
        values = [("initialized", loc.initialized), ("filter_time_ns", loc.time_ns), ("clock_ns", now),
                  ("resets", loc.resets), ("last_reset_reason", loc.last_reset_reason),
                  ("rewinds", loc.rewinds), ("dropped_overloaded", loc.skipped_rewinds),
                  ("history_size", loc.history_size),
                  ("pose_recoveries", loc.pose_recoveries), ("last_recovery", loc.last_recovery),
                  ("predict_failures", loc.predict_failures), ("nonfinite_outputs_suppressed",
                                                               loc.nonfinite_outputs),
                  *counters]
        values += [("frame_cache_size", size), ("frame_cache_cap", cap), ("frame_cache_evictions", evicted)]
        tf = loc.transforms  # static + time-stamped links, core/frames.TransformBuffer
        values += [("tf_frames", len(tf)), ("tf_frames_cap", 2 * tf.max_frames),
                   ("tf_frames_evicted", tf.evictions)]
        if est is not None:
            for i, short in enumerate(loc.spec.state_names):
                values.append((f"std_{short}", f"{math.sqrt(max(est.covariance[i, i], 0.0)):.4g}"))
        statuses.insert(0, _status(f"{name}: filter", name, level, message, values))
        statuses.insert(1, _status(f"{name}: consistency", name,
                                   DiagnosticStatus.WARN if outside else DiagnosticStatus.OK,
                                   ("NIS outside its band: " + ", ".join(outside)) if outside
                                   else "every NIS within its band", []))
        return statuses


def _nis_period(acc: list, prev: tuple[float, int] | None) -> tuple[float | None, int]:
    """(mean NIS, count) of the updates since ``prev`` (sum, count) from an accumulator [sum, count, dof]."""
    s0, n0 = prev if prev is not None and prev[1] <= acc[1] else (0.0, 0)  # a reset cleared acc
    n = acc[1] - n0
    return ((acc[0] - s0) / n if n > 0 else None), n


def _guard_status(guard, level: bytes, message: str) -> tuple[bytes, str, list]:
    """cmd_vel's level and message with core.command_guard's verdict, and its values."""
    total, dof, bound = guard.statistic
    values = [("followed", guard.followed), ("guard_nis_sum", f"{total:.3f}"), ("guard_dof", dof),
              ("guard_bound", f"{bound:.3f}"), ("guard_trips", guard.trips),
              ("guard_recoveries", guard.recoveries)]
    if not guard.followed:
        level, message = DiagnosticStatus.WARN, f"cmd_vel: not followed (window NIS {total:.1f} vs chi2 " \
            f"bound {bound:.1f}, {dof} dof): commands dropped"
    return level, message, values


def _seconds(ns: int | None) -> str:
    """A duration for a diagnostic value: seconds with 3 decimals, "never" before the first message."""
    return "never" if ns is None else f"{ns_to_seconds(ns):.3f}"


def _input_status(st, now: int | None, timeout_ns: int, new_rejected: int,
                  is_input: bool) -> tuple[bytes, str]:
    """Level and message of one source: ERROR when every message for longer than sensor_timeout
    was rejected (naming the reasons and the stamps' lag), WARN when silent that long or when
    some were rejected in the last period."""
    if now is not None and is_input:
        unapplied = st.unapplied_for_ns(now)
        if st.last_received_clock_ns is None:
            return DiagnosticStatus.WARN, "no message yet"
        silent = now - st.last_received_clock_ns
        if silent > timeout_ns:
            return DiagnosticStatus.WARN, f"no message for {ns_to_seconds(silent):.2f} s (sensor_timeout)"
        if unapplied is not None and unapplied > timeout_ns and new_rejected > 0:
            reasons = ", ".join(f"{r} {n}" for r, n in st.rejected.most_common(3) if n > 0)
            lag = ns_to_seconds(st.last_stamp_lag_ns)
            where = f"lag the clock by {lag:.3f} s" if lag >= 0 else f"lead the clock by {-lag:.3f} s"
            return (DiagnosticStatus.ERROR, f"every message rejected for {ns_to_seconds(unapplied):.2f} s "
                                            f"({reasons}): its stamps {where}")
    if new_rejected > 0:
        return DiagnosticStatus.WARN, f"{new_rejected} rejected in the last period"
    return DiagnosticStatus.OK, "ok"


def _status(name: str, hardware_id: str, level: bytes, message: str, values: list) -> DiagnosticStatus:
    st = DiagnosticStatus()
    st.level = level
    st.name = name
    st.hardware_id = hardware_id
    st.message = message
    st.values = [KeyValue(key=k, value=str(v)) for k, v in values if _known(v)]
    return st


def _known(value: Any) -> bool:
    """False for a value not known yet: a non-finite number, or its text ("nan", "inf"). Such a
    key is left out of /diagnostics rather than published as "nan"."""
    if isinstance(value, bool | int):
        return True
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):  # text such as "never" or a frame name
        return True
