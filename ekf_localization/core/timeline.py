"""The filter's committed state and the entries applied to it, in stamp order (no ROS).

Each entry (a message's updates, or a command) keeps the state it was applied to. An entry
stamped before the newest one is put in its place: the filter goes back to the state before the
first newer entry, applies it, and applies the newer entries again. The result equals
processing everything in stamp order. Entries older than ``history_length`` before the newest
are forgotten; one older than the oldest kept state is refused (``older_than_history``).
Without smoothing (``history_ns`` None) a lagged entry is applied to the current state, as
robot_localization does.

The steps of :meth:`Timeline.insert`:

1. Start the filter at the first entry's stamp (it may move back by up to history_length for
   a lagged entry that follows).
2. An entry at or after the newest: predict to its stamp, apply it (a widening entry adds its
   variances to P first), append it. A command (with
   smoothing, once the history has an entry) is deferred instead: it waits in ``deferred`` until
   a measurement at or after its stamp arrives (or it falls history_length behind the newest
   command), and the estimates between entries predict through it. A command is an input to the
   process model, not a measurement: applied at once it would move the committed state ahead of
   measurements that have not arrived yet, and each of them would then come in lagged and rewind
   the commands (on a starved CPU, with the sensors' queues behind and cmd_vel fresh, about 100
   entries per message). The order in which entries are applied, and so the result, is the same.
3. A lagged entry: find the first newer entry, restore the state before it, apply the lagged
   entry, then every newer one again; one that would replay more than MAX_REPLAY_ENTRIES is
   dropped as overloaded (work skipped, never a backlog).
4. Forget the entries older than history_length.
"""

from __future__ import annotations

import math
from bisect import bisect_right, insort
from collections.abc import Callable
from dataclasses import dataclass
from operator import attrgetter
from typing import NamedTuple

import numpy as np

from ekf_localization.core.command_model import Command, CommandModel
from ekf_localization.core.ekf import ExtendedKalmanFilter
from ekf_localization.core.measurements import REJECT_OVERLOADED, REJECT_TOO_OLD

_ENTRY_KEY = attrgetter("stamp_ns", "seq")  # the history's order (bisected on)
# A lagged entry that would replay more entries than this is dropped: under overload (a starved
# CPU, a backlog of lagged camera poses), replaying the whole history at each message makes the
# filter fall further behind, and fusing the entry into the current state instead would put an
# old pose at the robot's present place. In normal running a camera pose 50-80 ms late replays
# ~15 entries (odometry and IMU at 100 Hz, cmd_vel at 50 Hz), one 150 ms late behind 200 Hz
# odometry ~55, ~170 with 1 kHz odometry; 256 entries cost a few ms of replay at most.
MAX_REPLAY_ENTRIES = 256


class Snapshot(NamedTuple):
    t_ns: int
    x: np.ndarray
    P: np.ndarray
    command: Command | None  # the command in effect


@dataclass(eq=False)
class Entry:
    """One timeline entry: a message's updates or a command, and the state it was applied to."""

    stamp_ns: int
    source: str
    updates: tuple = ()  # (plan, z, R) of a message, applied by the Timeline's ``apply``
    command: np.ndarray | None = None  # a command entry when set: the model input
    drive: bool = True  # a drive command (latency, coasting); False: a process input
    widen: np.ndarray | None = None  # (n,) variances added to P's diagonal at the stamp (a slip)
    outcomes: tuple[str | None, ...] = ()  # per update: None (applied) or a reason
    seq: int = 0
    prior: Snapshot | None = None


class Timeline:
    """The committed filter and its history. ``apply(entry)`` fuses a message entry's updates
    into ``ekf`` (the caller's: it counts outcomes and NIS); commands are applied here."""

    def __init__(self, ekf: ExtendedKalmanFilter, commands: CommandModel, history_ns: int | None,
                 apply: Callable[[Entry], None]) -> None:
        self.ekf = ekf
        self._x0, self._P0 = ekf.x.copy(), ekf.P.copy()  # the initial state, at the first entry
        self._scratch = ExtendedKalmanFilter(ekf.model, ekf.x, ekf.P)  # estimates between entries
        self.commands = commands
        self._history_ns = history_ns
        self._apply = apply
        self.rewinds = 0
        self.skipped_rewinds = 0  # lagged entries beyond MAX_REPLAY_ENTRIES, dropped
        self.clear()

    def clear(self) -> None:
        """Forget the state and the history (the next entry starts the filter again)."""
        self.initialized = False
        self.t_ns = 0  # time of the committed state
        self.command: Command | None = None
        self.pending: Command | None = None  # a command that came before the filter started
        self.history: list[Entry] = []  # in _ENTRY_KEY order
        self.deferred: list[Entry] = []  # commands at or after t_ns, not yet applied (step 2)
        self.newest_measurement_ns: int | None = None
        self.diverged = False  # a committed prediction was not finite
        self._seq = 0
        self._start_entry: Entry | None = None  # the first entry while in the history ...
        self._start_floor_ns: int | None = None  # ... and how far back the initial state may move
        self._version = 0  # changes with the committed state (keys the cache)
        self._cache: tuple[int, Snapshot] | None = None
        if self.commands.guard is not None:  # core.command_guard starts again with the filter
            self.commands.guard.reset()

    def start(self, t_ns: int, x: np.ndarray | None = None, P: np.ndarray | None = None,
              command: Command | None = None) -> None:
        """Put the committed state (the initial state by default) at ``t_ns``; the history is
        cleared. The command in effect: ``command``, else one that came before the start."""
        pending, deferred = self.pending, self.deferred
        self.clear()
        self.ekf.set_state(self._x0 if x is None else x, self._P0 if P is None else P)
        self.t_ns = int(t_ns)
        self.command = command if command is not None else pending
        self.deferred = [e for e in deferred if e.stamp_ns >= self.t_ns]  # still to act
        self.initialized = True

    def put_pose(self, stamp: int, rows: list[int], values: np.ndarray, C: np.ndarray) -> None:
        """Restart at ``stamp`` with state ``rows`` = ``values`` (covariance ``C``, no correlation
        with the rest); the other components are kept. The history is cleared."""
        if self.initialized:
            x, P = self.estimate_at(max(stamp, self.earliest_insertable_ns or stamp))
        else:
            x, P = self._x0.copy(), self._P0.copy()
        command = self.command if self.initialized else self.pending
        for e in self.deferred:  # the waiting commands before the new start act in it; start()
            if e.stamp_ns < stamp:   # keeps those at or after it waiting, so each acts once
                command = self.commands.then(command, e.stamp_ns, e.command, e.drive)
        x[rows] = values
        P[rows, :] = 0.0
        P[:, rows] = 0.0
        P[np.ix_(rows, rows)] = C
        self.start(stamp, x, P, command)
        self.newest_measurement_ns = stamp

    @property
    def earliest_insertable_ns(self) -> int | None:
        """Oldest stamp an entry may have and still be applied at its own time."""
        if not self.initialized:
            return None
        if not self.history:
            return self.t_ns
        first = self.history[0]
        return self._start_floor_ns if first is self._start_entry else first.prior.t_ns

    def insert(self, entry: Entry) -> str | None:
        """Apply ``entry`` at its stamp (see the module docstring). Returns a reason it was refused."""
        s = entry.stamp_ns
        if not self.initialized:  # 1. the initial state at the first stamp, or up to history_length before
            self.start(s)
            if self._history_ns is not None:
                self._start_floor_ns = max(0, s - self._history_ns)
        self._seq += 1
        entry.seq = self._seq
        if entry.command is not None and self._history_ns is not None and self.history and s >= self.t_ns:
            insort(self.deferred, entry, key=_ENTRY_KEY)  # 2. a command: deferred
            self._version += 1
            while self.deferred[0].stamp_ns < self.deferred[-1].stamp_ns - self._history_ns:
                self._append(self.deferred.pop(0))
            self._forget()
            return None
        while self.deferred and entry.command is None and self.deferred[0].stamp_ns <= s:
            self._append(self.deferred.pop(0))  # the commands that act before this measurement
        if self._history_ns is None:
            if s < self.t_ns:  # lagged: fused into the current state, as robot_localization does
                entry.stamp_ns = self.t_ns
            self._process(entry)
        elif self.history and s < self.history[-1].stamp_ns:  # 3. lagged: rewind and replay
            first = self.history[0]
            before_start = s < first.prior.t_ns
            if before_start and (first is not self._start_entry or s < self._start_floor_ns):
                return REJECT_TOO_OLD
            i = bisect_right(self.history, (s, entry.seq), key=_ENTRY_KEY)
            if len(self.history) - i > MAX_REPLAY_ENTRIES:  # beyond the replay bound: skipped
                self.skipped_rewinds += 1
                return REJECT_OVERLOADED
            if before_start:
                first.prior = first.prior._replace(t_ns=s)  # the initial state, now at s
                self._start_entry = entry
            self._restore(self.history[i].prior)
            replay = self.history[i:]
            self.history.insert(i, entry)
            for e in (entry, *replay):
                self._process(e)
            self.rewinds += 1
        else:  # 2. in order
            if s < self.t_ns:
                return REJECT_TOO_OLD
            self._append(entry)
        if entry.command is None and (self.newest_measurement_ns is None or s > self.newest_measurement_ns):
            self.newest_measurement_ns = s
        self._forget()
        return None

    def _append(self, entry: Entry) -> None:
        """Apply an entry at or after the newest and append it to the history."""
        self.history.append(entry)
        self._process(entry)
        if entry.seq == 1 and self._start_floor_ns is not None:
            self._start_entry = entry

    def _forget(self) -> None:
        """4. Forget the entries older than history_length before the newest."""
        history = self.history
        if self._history_ns is not None and history:
            cutoff = history[-1].stamp_ns - self._history_ns
            k, n = 0, len(history)  # a scan from the oldest: an entry retires a few (cheaper than bisect)
            while k < n and history[k].stamp_ns < cutoff:
                k += 1
            if k:
                del history[:k]

    def _restore(self, snap: Snapshot) -> None:
        self.ekf.restore(snap.x, snap.P)
        self.t_ns = snap.t_ns
        self.command = snap.command

    def _process(self, entry: Entry) -> None:
        """Predict the committed state to the entry's stamp and apply the entry."""
        if self._history_ns is not None:  # the state a rewind restores
            entry.prior = Snapshot(self.t_ns, self.ekf.x.copy(), self.ekf.P.copy(), self.command)
        self.t_ns, ok = self.commands.propagate(self.ekf, self.t_ns, entry.stamp_ns, self.command)
        self.diverged |= not ok
        self._version += 1
        if entry.command is not None:
            self.command = self.commands.then(self.command, entry.stamp_ns, entry.command, entry.drive)
        else:
            if entry.widen is not None:  # more uncertain from here on (e.g. the wheels slipped)
                P = self.ekf.P.copy()
                P[np.diag_indices_from(P)] += entry.widen
                self.ekf.restore(self.ekf.x, P)
            self._apply(entry)

    def estimate_at(self, t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(x, P) at ``t_ns`` without changing the filter: predicted from the committed state, or
        from the history for an earlier time (None if older than it). x is nan where a step of
        the prediction was not finite."""
        if not self.initialized:
            return None
        if t_ns == self.t_ns:
            return self.ekf.x.copy(), self.ekf.P.copy()
        deferred: list[Entry] = []  # the commands to predict through
        if t_ns > self.t_ns:
            base = Snapshot(self.t_ns, self.ekf.x, self.ekf.P, self.command)
            deferred = self.deferred
            if self._cache is not None and self._cache[0] == self._version and self._cache[1].t_ns <= t_ns:
                base = self._cache[1]  # publishing at a steady rate: go on from the last estimate
                deferred = deferred[bisect_right(deferred, (base.t_ns, math.inf), key=_ENTRY_KEY):]
        else:
            earliest = self.earliest_insertable_ns
            if t_ns < earliest:
                return None
            k = bisect_right(self.history, (t_ns, math.inf), key=_ENTRY_KEY)
            base = self.history[k].prior  # of the first entry after t
        sc = self._scratch
        sc.x[:] = base.x
        sc.P[:] = base.P
        t, command, ok = base.t_ns, base.command, True
        for e in deferred:
            if e.stamp_ns > t_ns:
                break
            t, step_ok = self.commands.propagate(sc, t, e.stamp_ns, command)
            ok &= step_ok
            command = self.commands.then(command, e.stamp_ns, e.command, e.drive)
        t, step_ok = self.commands.propagate(sc, t, t_ns, command)
        ok &= step_ok
        x, P = sc.x.copy(), sc.P.copy()
        if not ok:
            x[:] = math.nan
        elif t_ns >= self.t_ns:
            self._cache = (self._version, Snapshot(t, x.copy(), P.copy(), command))
        return x, P
