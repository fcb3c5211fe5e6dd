"""What the field view shows, as plain data (no ROS): the live node and the HTML export share it.

:class:`ViewState` collects the estimate (with its 95 % ellipse, ``core/ellipse.py``), the
ground truth, the path, the camera fixes, the plots (position error, NIS per input) and the
diagnostics, and gives a JSON-able :meth:`ViewState.snapshot`. It is thread-safe: ROS
callbacks write it, the web server's thread reads it. :func:`parse_command` validates a
message from the page (a ``set_pose`` or a ``reset``) and refuses anything else.
"""

from __future__ import annotations

import contextlib
import json
import math
import threading
from bisect import bisect_left
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.ellipse import ellipse_points
from ekf_localization.core.units import NS_PER_S

MAX_COMMAND_BYTES = 1024
MAX_PLOT_RATE_HZ = 10.0  # the error plot keeps at most this many points per second
TRUTH_MATCH_NS = 60_000_000  # truth within this of an estimate's stamp gives its error
LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
CAMERA_SHOW_NS = NS_PER_S  # the camera's view is drawn while its image is this close to the estimate


class CommandError(ValueError):
    """A message from the page that is not a valid command (the reason, one line)."""


@dataclass(frozen=True)
class Command:
    action: str  # "set_pose" or "reset"
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0


def _reject_constant(name: str) -> float:
    raise CommandError(f"{name} is not a number")


def parse_command(text: str | bytes, position_limit: float) -> Command:
    """A command from the page's JSON text; raises CommandError (NaN, ∞, off-field, unknown, ...)."""
    if len(text) > MAX_COMMAND_BYTES:
        raise CommandError(f"message longer than {MAX_COMMAND_BYTES} bytes")
    try:
        msg = json.loads(text, parse_constant=_reject_constant)  # NaN / Infinity literals refused
    except CommandError:
        raise
    except (ValueError, UnicodeDecodeError) as exc:
        raise CommandError(f"not JSON ({exc})") from None
    if not isinstance(msg, dict):
        raise CommandError("not a JSON object")
    action = msg.get("type")
    if action == "reset":
        return Command("reset")
    if action != "set_pose":
        raise CommandError(f"unknown type {action!r} (set_pose or reset)")
    values = []
    for key in ("x", "y", "yaw"):
        v = msg.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise CommandError(f"set_pose: {key} must be a number, got {v!r}")
        if not math.isfinite(v):
            raise CommandError(f"set_pose: {key} must be finite")
        values.append(float(v))
    x, y, yaw = values
    if abs(x) > position_limit or abs(y) > position_limit:
        raise CommandError(f"set_pose: ({x:g}, {y:g}) is off the field (|x|, |y| <= {position_limit:g} m)")
    return Command("set_pose", x, y, wrap_angle(yaw))


def _r(v: float, digits: int = 4) -> float:
    return round(float(v), digits)


class ViewState:
    """The view's data, written by callbacks, read by :meth:`snapshot` (module docstring)."""

    def __init__(self, field: dict[str, Any], history_s: float = 30.0) -> None:
        self.field = field
        self.history_ns = int(history_s * NS_PER_S)
        self._lock = threading.Lock()
        self._t0: int | None = None
        self._estimate: dict[str, Any] | None = None
        self._estimate_ns = 0
        self._truth: dict[str, Any] | None = None
        self._truth_hist: deque[tuple[int, float, float]] = deque(maxlen=512)
        self._path: list[list[float]] = []
        self._target: list[float] | None = None
        self._lookahead: float | None = None
        self._fixes: dict[str, list[list[float]]] = {"accepted": [], "gated": []}
        self._camera: tuple[int, list[tuple[float, float]] | None, list[list[float]]] | None = None
        self._error: deque[tuple[float, float]] = deque()
        self._nis: dict[str, dict[str, Any]] = {}
        self._nees: deque[tuple[float, float]] = deque()  # (t, NEES of x, y against the truth)
        self._status: dict[str, Any] | None = None
        self._statuses: dict[str, dict[str, Any]] = {}
        self._last_error_ns: int | None = None
        self.counters = {"bad_messages": 0, "set_pose": 0, "reset": 0, "dropped_commands": 0}

    # -- writers (any thread) ---------------------------------------------------------------
    def _t(self, stamp_ns: int) -> float:
        if self._t0 is None:
            self._t0 = stamp_ns
        return (stamp_ns - self._t0) / NS_PER_S

    def _trim(self, series: deque, now_s: float) -> None:
        while series and series[0][0] < now_s - self.history_ns / NS_PER_S:
            series.popleft()

    def set_estimate(self, stamp_ns: int, x: float, y: float, yaw: float, cov_xy: np.ndarray) -> None:
        """The estimate and its x-y covariance (a non-finite one: no ellipse)."""
        ring = None
        cov = np.asarray(cov_xy, dtype=float)
        if np.all(np.isfinite(cov)):
            try:
                ring = [[_r(a), _r(b)] for a, b in ellipse_points((x, y), cov, segments=40)]
            except ValueError:
                ring = None
        with self._lock:
            t = self._t(stamp_ns)
            self._estimate_ns = stamp_ns
            self._estimate = {"t": _r(t, 3), "x": _r(x), "y": _r(y), "yaw": _r(yaw), "ellipse": ring}
            truth = self._truth_near(stamp_ns)
            if truth is not None and (self._last_error_ns is None or stamp_ns < self._last_error_ns
                                      or stamp_ns - self._last_error_ns >= NS_PER_S / MAX_PLOT_RATE_HZ):
                self._last_error_ns = stamp_ns
                self._error.append((_r(t, 3), _r(math.hypot(x - truth[0], y - truth[1]), 5)))
                self._trim(self._error, t)
                e = np.array([x - truth[0], y - truth[1]])
                with contextlib.suppress(np.linalg.LinAlgError):  # NEES of (x, y), χ²(2)
                    nees = float(e @ np.linalg.solve(cov, e))
                    if math.isfinite(nees):
                        self._nees.append((_r(t, 3), _r(nees, 4)))
                        self._trim(self._nees, t)

    def _truth_near(self, stamp_ns: int) -> tuple[float, float] | None:
        h = self._truth_hist
        if not h:
            return None
        stamps = [s for s, _, _ in h]
        i = bisect_left(stamps, stamp_ns)
        best = min((j for j in (i - 1, i) if 0 <= j < len(h)), key=lambda j: abs(stamps[j] - stamp_ns))
        if abs(stamps[best] - stamp_ns) > TRUTH_MATCH_NS:
            return None
        return h[best][1], h[best][2]

    def set_truth(self, stamp_ns: int, x: float, y: float, yaw: float) -> None:
        with self._lock:
            t = self._t(stamp_ns)
            if self._truth_hist and stamp_ns < self._truth_hist[-1][0]:
                self._truth_hist.clear()  # time went back (a restart): old truth matches nothing
            self._truth_hist.append((stamp_ns, x, y))
            self._truth = {"t": _r(t, 3), "x": _r(x), "y": _r(y), "yaw": _r(yaw)}

    def set_path(self, points: list[tuple[float, float]]) -> None:
        with self._lock:
            self._path = [[_r(a), _r(b)] for a, b in points]

    def set_target(self, point: tuple[float, float] | None) -> None:
        with self._lock:
            self._target = None if point is None else [_r(point[0]), _r(point[1])]

    def set_lookahead(self, radius: float | None) -> None:
        """The follower's lookahead circle (drawn around the estimate)."""
        with self._lock:
            self._lookahead = None if radius is None else _r(radius)

    def set_fixes(self, accepted: list[tuple[float, float]], gated: list[tuple[float, float]]) -> None:
        with self._lock:
            self._fixes = {"accepted": [[_r(a), _r(b)] for a, b in accepted],
                           "gated": [[_r(a), _r(b)] for a, b in gated]}

    def set_camera(self, stamp_ns: int, fov_base: list[tuple[float, float]] | None,
                   seen: list[tuple[float, float]]) -> None:
        """tag_localizer's newest image: its field of view on the floor in base_link (drawn from
        the estimate) and the map positions of the layout tags it saw."""
        with self._lock:
            self._camera = (stamp_ns, fov_base, [[_r(a), _r(b)] for a, b in seen])

    def _camera_view(self) -> dict[str, Any] | None:
        """The field of view in the map (from the estimate) and the tags seen, while the image is
        within CAMERA_SHOW_NS of the estimate's stamp (a stopped camera leaves nothing drawn)."""
        if self._camera is None or self._estimate is None:
            return None
        stamp_ns, fov, seen = self._camera
        if abs(stamp_ns - self._estimate_ns) > CAMERA_SHOW_NS:
            return None
        e = self._estimate
        c, s = math.cos(e["yaw"]), math.sin(e["yaw"])
        ring = None if fov is None else [[_r(e["x"] + c * bx - s * by), _r(e["y"] + s * bx + c * by)]
                                         for bx, by in fov]
        return {"fov": ring, "seen": list(seen)}

    def set_status(self, name: str, level: int, message: str, values: dict[str, str],
                   stamp_ns: int | None = None, filter_status: bool = False,
                   source: str | None = None) -> None:
        """One diagnostic status; ``filter_status``: the one shown as the view's status;
        ``source``: an ekf_node input, whose ``nis_<part>`` values extend its NIS plots."""
        with self._lock:
            entry = {"name": name, "level": LEVELS.get(level, str(level)), "message": message}
            self._statuses[name] = entry
            if filter_status:
                self._status = entry
            if source is None or stamp_ns is None:
                return
            t = self._t(stamp_ns)
            for key, value in values.items():
                if not key.startswith("nis_") or key.endswith(("_dof", "_band")) or value in ("", "none"):
                    continue
                try:
                    nis = float(value)
                except ValueError:
                    continue
                if not math.isfinite(nis):
                    continue
                series = self._nis.setdefault(f"{source}/{key[4:]}", {"dof": None, "points": deque()})
                with contextlib.suppress(ValueError):
                    series["dof"] = int(values.get(key + "_dof", ""))
                with contextlib.suppress(ValueError):  # "[lo, hi]": the 95 % band of that mean
                    series["band"] = [float(v) for v in values.get(key + "_band", "").strip("[]").split(",")]
                series["points"].append((_r(t, 3), _r(nis, 4)))
                self._trim(series["points"], t)

    # -- reader -----------------------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        """A JSON-able copy of everything the page draws."""
        with self._lock:
            return {
                "type": "state",
                "estimate": self._estimate, "truth": self._truth, "path": list(self._path),
                "target": self._target, "lookahead": self._lookahead,
                "fixes": {k: list(v) for k, v in self._fixes.items()},
                "camera": self._camera_view(),
                "error": [list(p) for p in self._error],
                "nis": {k: {"dof": v["dof"], "band": v.get("band"), "points": [list(p) for p in v["points"]]}
                        for k, v in self._nis.items()},
                "nees": [list(p) for p in self._nees],
                "status": self._status, "statuses": sorted(self._statuses.values(), key=lambda s: s["name"]),
                "counters": dict(self.counters),
            }
