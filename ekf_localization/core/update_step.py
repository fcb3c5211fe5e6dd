"""One timeline entry's measurement updates applied to the EKF, and what is counted of them
(no ROS imports): each update's outcome per input (recounted when a rewind replays the entry),
the NIS of first passes, the innovations for the tools, and the command guard's evidence."""

from __future__ import annotations

import math
from collections.abc import Callable

from ekf_localization.core.command_guard import CommandGuard
from ekf_localization.core.ekf import STATUS_GATED, STATUS_OK
from ekf_localization.core.measurements import REJECT_FILTER, REJECT_GATED
from ekf_localization.core.outcomes import Innovation, NisTally, SourceStats
from ekf_localization.core.timeline import Entry, Timeline

_OUTCOME_OF_STATUS = {STATUS_OK: None, STATUS_GATED: REJECT_GATED}  # any other status: REJECT_FILTER


class UpdateStep:
    """The Timeline's ``apply`` for a message entry."""

    def __init__(self, stats: dict[str, SourceStats], nis: NisTally, guard: CommandGuard | None,
                 process_model) -> None:
        self.timeline: Timeline | None = None  # set once the timeline exists
        self._stats, self._nis, self._guard, self._model = stats, nis, guard, process_model
        self._watched: dict[str, bool] = {}  # per plan: whether the guard takes its updates as evidence
        # Called with every update's Innovation when set (tools: tuning, consistency reports).
        self.innovation_listener: Callable[[Innovation], None] | None = None

    def __call__(self, entry: Entry) -> None:
        first_pass = not entry.outcomes
        tl = self.timeline
        ekf, guard, listener = tl.ekf, self._guard, self.innovation_listener
        outcomes = []
        for plan, z, R in entry.updates:
            watched = self._watched.get(plan.nis_key)
            if watched is None:
                watched = self._watched[plan.nis_key] = guard is not None and guard.watches(plan.rows)
            prior = ekf.x.copy() if first_pass and watched else None
            result = ekf.update(plan.model, z, R, gate_sigmas=plan.gate, r_checked=plan.r_checked,
                                widen_above=plan.widen_above)
            if prior is not None:  # core.command_guard: does the drive follow the commands?
                guard.observe(entry.stamp_ns, plan.rows, prior, result.y, result.S, result.mahalanobis ** 2,
                              tl.commands.at(tl.command, entry.stamp_ns)[0], self._model, plan.model)
            if listener is not None and result.S is not None:
                listener(Innovation(entry.source, plan.name, entry.seq, entry.stamp_ns, result.y, result.S,
                                    result.accepted))
            outcomes.append(_OUTCOME_OF_STATUS.get(result.status, REJECT_FILTER))
            if first_pass and not math.isnan(result.mahalanobis):  # nan: stopped before the distance
                self._nis.add(plan.nis_key, result.mahalanobis ** 2)
            if first_pass and ekf.last_widening > 1.0:  # the residual check widened R (counted as the NIS)
                self._stats[entry.source].widened += 1
        outcomes_t = tuple(outcomes)
        if outcomes_t != entry.outcomes:  # first pass, or a re-pass after a rewind changed them
            self._stats[entry.source].recount(entry.outcomes, outcomes_t)
            entry.outcomes = outcomes_t
