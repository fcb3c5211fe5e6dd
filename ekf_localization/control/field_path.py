"""Field paths: a polyline of waypoints with optional headings and stop points.

A path is what the pure-pursuit follower drives along: straight segments between waypoints
(metres, in ``frame_id``, REP-103/105). Curves are written as ``ellipse_arc`` elements in
the YAML and expanded into short segments when the file is loaded. A closed path returns to
its first waypoint; ``cycles: N`` repeats a closed loop N times (unrolled into one polyline,
so the distance along the path keeps increasing through the cycles).

Heading along the path (what a holonomic robot's θ controller aims at): each segment starts
at the heading of its first waypoint and ends at the heading of its second, interpolated
linearly in arc length the short way round; a waypoint without an explicit heading stands
for "the direction of this segment" (tangent). So an all-tangent path faces the direction of
travel and turns at the corners, and explicit headings blend smoothly in between.

Stop points are waypoints the robot must reach (within the goal tolerances) before going on:
every waypoint marked ``stop: true`` and always the last one. The stretch of path between
two stop points is a leg.

YAML format (see ``docs/pure_pursuit.md``)::

    name: my_path
    frame_id: map          # optional, default map
    closed: false          # optional
    cycles: 1              # optional, only with closed: true
    waypoints:
      - [0.0, 0.0]                         # x, y (m)
      - [1.0, 0.0, 1.5708]                 # x, y, heading (rad)
      - {x: 1.0, y: 1.0, heading_deg: 90, stop: true}
      - {ellipse_arc: {center: [1.5, 1.0], radii: [0.5, 0.3], start_deg: 180, end_deg: 0,
                       rotation_deg: 0, points: 16}}
"""

from __future__ import annotations

import bisect
import math
import os
import pathlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import yaml

from ekf_localization.core.angles import wrap_angle

PACKAGE = "ekf_localization"
MIN_SEGMENT_LENGTH = 1e-6  # m; shorter segments are rejected (or merged by from_poses)
PRESETS = ("seed000_test_path", "ftc_cycle")


class PathError(ValueError):
    """A path description is malformed; the message names the offending entry."""


@dataclass(frozen=True)
class Waypoint:
    """A path vertex: position (m), optional heading (rad, CCW from +x), stop flag."""

    x: float
    y: float
    heading: float | None = None
    stop: bool = False


class FieldPath:
    """An immutable polyline with cumulative arc length, headings and stop points.

    Geometry is held in tuples of Python floats: the follower calls into it a few times per
    control step, and for 2-D geometry on a handful of segments that is faster than numpy.
    """

    def __init__(self, waypoints: Sequence[Waypoint], *, closed: bool = False, cycles: int = 1,
                 frame_id: str = "map", name: str = "") -> None:
        if not isinstance(frame_id, str) or not frame_id:
            raise PathError("frame_id: expected a non-empty string")
        if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 1:
            raise PathError(f"cycles: expected an integer >= 1, got {cycles!r}")
        if cycles != 1 and not closed:
            raise PathError("cycles: only allowed on a closed path (closed: true)")
        base = list(waypoints)
        if len(base) < 2:
            raise PathError(f"waypoints: need at least 2, got {len(base)}")
        for i, w in enumerate(base):
            if not (math.isfinite(w.x) and math.isfinite(w.y)):
                raise PathError(f"waypoints[{i}]: x and y must be finite, got ({w.x}, {w.y})")
            if w.heading is not None and not math.isfinite(w.heading):
                raise PathError(f"waypoints[{i}]: heading must be finite, got {w.heading}")
        n_base = len(base)
        if closed:
            if math.hypot(base[-1].x - base[0].x, base[-1].y - base[0].y) < MIN_SEGMENT_LENGTH:
                raise PathError("closed: the last waypoint repeats the first; a closed path "
                                "returns to its start by itself, drop the repeated waypoint")
            verts = base * cycles + [base[0]]
        else:
            verts = base
        for i in range(len(verts) - 1):
            if math.hypot(verts[i + 1].x - verts[i].x, verts[i + 1].y - verts[i].y) < MIN_SEGMENT_LENGTH:
                j = (i + 1) % n_base
                raise PathError(f"waypoints[{i % n_base}] and waypoints[{j}] coincide "
                                "(zero-length segment)")
        self.name = name
        self.frame_id = frame_id
        self.closed = bool(closed)
        self.cycles = cycles
        self.base_waypoints: tuple[Waypoint, ...] = tuple(base)
        self.waypoints: tuple[Waypoint, ...] = tuple(verts)
        self.xs: tuple[float, ...] = tuple(float(w.x) for w in verts)
        self.ys: tuple[float, ...] = tuple(float(w.y) for w in verts)
        n_seg = len(verts) - 1
        dx = [self.xs[i + 1] - self.xs[i] for i in range(n_seg)]
        dy = [self.ys[i + 1] - self.ys[i] for i in range(n_seg)]
        seg_len = [math.hypot(a, b) for a, b in zip(dx, dy, strict=True)]
        s = [0.0]
        for length in seg_len:
            s.append(s[-1] + length)
        self.seg_dx: tuple[float, ...] = tuple(dx)
        self.seg_dy: tuple[float, ...] = tuple(dy)
        self.seg_len: tuple[float, ...] = tuple(seg_len)
        self.s: tuple[float, ...] = tuple(s)  # arc length at each vertex
        self.length: float = s[-1]
        tangent = [math.atan2(b, a) for a, b in zip(dx, dy, strict=True)]
        self.seg_tangent: tuple[float, ...] = tuple(tangent)  # direction of travel (rad)
        self.seg_heading_start: tuple[float, ...] = tuple(
            verts[i].heading if verts[i].heading is not None else tangent[i] for i in range(n_seg))
        self.seg_heading_end: tuple[float, ...] = tuple(
            verts[i + 1].heading if verts[i + 1].heading is not None else tangent[i] for i in range(n_seg))
        stop_idx = [i for i in range(1, len(verts) - 1) if verts[i].stop] + [len(verts) - 1]
        self.stop_indices: tuple[int, ...] = tuple(stop_idx)
        self.stop_s: tuple[float, ...] = tuple(s[i] for i in stop_idx)

    # -- queries -------------------------------------------------------------------------
    @property
    def segment_count(self) -> int:
        return len(self.seg_len)

    @property
    def start(self) -> tuple[float, float, float]:
        """Start pose (x, y, heading) of the path."""
        return self.xs[0], self.ys[0], self.seg_heading_start[0]

    def points(self) -> np.ndarray:
        """(K, 2) array of the (unrolled) vertices."""
        return np.column_stack([self.xs, self.ys])

    def segment_at(self, s: float) -> int:
        """Index of the segment holding arc length ``s`` (at a vertex: the outgoing one)."""
        i = bisect.bisect_right(self.s, s) - 1
        return 0 if i < 0 else (self.segment_count - 1 if i >= self.segment_count else i)

    def point_at(self, s: float, seg: int | None = None) -> tuple[float, float]:
        """(x, y) at arc length ``s`` (clamped to [0, length])."""
        s = min(max(s, 0.0), self.length)
        i = self.segment_at(s) if seg is None else seg
        f = (s - self.s[i]) / self.seg_len[i]
        return self.xs[i] + f * self.seg_dx[i], self.ys[i] + f * self.seg_dy[i]

    def heading_at(self, s: float, seg: int | None = None) -> float:
        """Heading target (rad, wrapped) at arc length ``s``; ``seg`` picks the segment at a vertex."""
        s = min(max(s, 0.0), self.length)
        i = self.segment_at(s) if seg is None else seg
        f = min(max((s - self.s[i]) / self.seg_len[i], 0.0), 1.0)
        h0 = self.seg_heading_start[i]
        return wrap_angle(h0 + f * wrap_angle(self.seg_heading_end[i] - h0))

    def stop_heading(self, leg: int) -> float:
        """Heading to hold at the end of leg ``leg`` (the end heading of its last segment)."""
        return wrap_angle(self.seg_heading_end[self.stop_indices[leg] - 1])

    def nearest(self, x: float, y: float, s_min: float = 0.0,
                s_max: float = math.inf) -> tuple[float, float, float, float]:
        """Nearest point to (x, y) with arc length in [s_min, s_max]: (s, px, py, distance)."""
        s_min = min(max(s_min, 0.0), self.length)
        s_max = min(max(s_max, s_min), self.length)
        best = (math.inf, s_min, 0.0, 0.0)
        xs, ys, sv, dxs, dys, lens = self.xs, self.ys, self.s, self.seg_dx, self.seg_dy, self.seg_len
        i = self.segment_at(s_min)
        n = len(lens)
        while i < n and sv[i] <= s_max:
            length = lens[i]
            t_lo = max(0.0, (s_min - sv[i]) / length)
            t_hi = min(1.0, (s_max - sv[i]) / length)
            dx, dy = dxs[i], dys[i]
            t = ((x - xs[i]) * dx + (y - ys[i]) * dy) / (length * length)
            t = t_lo if t < t_lo else (t_hi if t > t_hi else t)
            px, py = xs[i] + t * dx, ys[i] + t * dy
            d2 = (px - x) ** 2 + (py - y) ** 2
            if d2 < best[0]:
                best = (d2, sv[i] + t * length, px, py)
            i += 1
        return best[1], best[2], best[3], math.sqrt(best[0])

    def with_cycles(self, cycles: int) -> FieldPath:
        """The same closed loop repeated ``cycles`` times."""
        return FieldPath(self.base_waypoints, closed=self.closed, cycles=cycles, frame_id=self.frame_id,
                    name=self.name)

    @classmethod
    def from_poses(cls, xs: Sequence[float], ys: Sequence[float],
                   headings: Sequence[float] | None = None, *, frame_id: str = "map",
                   name: str = "") -> FieldPath:
        """A path from a pose list (e.g. nav_msgs/Path); consecutive duplicates are merged."""
        if len(xs) != len(ys) or (headings is not None and len(headings) != len(xs)):
            raise PathError("poses: xs, ys and headings must have the same length")
        wps: list[Waypoint] = []
        for i in range(len(xs)):
            w = Waypoint(float(xs[i]), float(ys[i]), None if headings is None else float(headings[i]))
            if wps and math.hypot(w.x - wps[-1].x, w.y - wps[-1].y) < MIN_SEGMENT_LENGTH:
                wps[-1] = w  # keep the later heading
                continue
            wps.append(w)
        return cls(wps, frame_id=frame_id, name=name)

    def __repr__(self) -> str:
        return (f"FieldPath(name={self.name!r}, frame_id={self.frame_id!r}, vertices={len(self.xs)}, "
                f"length={self.length:.3f} m, stops={len(self.stop_s)})")


# -- YAML ----------------------------------------------------------------------------------
def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise PathError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _heading(entry: Mapping[str, Any], where: str) -> float | None:
    if "heading" in entry and "heading_deg" in entry:
        raise PathError(f"{where}: give heading (rad) or heading_deg, not both")
    if "heading" in entry:
        return _number(entry["heading"], f"{where}.heading")
    if "heading_deg" in entry:
        return math.radians(_number(entry["heading_deg"], f"{where}.heading_deg"))
    return None


def _ellipse_arc(spec: Any, where: str) -> list[Waypoint]:
    """Points of an ellipse arc, start and end angle included (parametric angle, degrees)."""
    if not isinstance(spec, Mapping):
        raise PathError(f"{where}: expected a mapping with center, radii, start_deg, end_deg")
    allowed = {"center", "radii", "start_deg", "end_deg", "rotation_deg", "points"}
    unknown = set(spec) - allowed
    if unknown:
        raise PathError(f"{where}: unknown keys {sorted(unknown)}; allowed {sorted(allowed)}")
    for key in ("center", "radii", "start_deg", "end_deg"):
        if key not in spec:
            raise PathError(f"{where}.{key}: missing")
    pair = {}
    for key in ("center", "radii"):
        v = spec[key]
        if not isinstance(v, Sequence) or isinstance(v, str) or len(v) != 2:
            raise PathError(f"{where}.{key}: expected [a, b], got {v!r}")
        pair[key] = (_number(v[0], f"{where}.{key}[0]"), _number(v[1], f"{where}.{key}[1]"))
    a, b = pair["radii"]
    if a <= 0.0 or b <= 0.0:
        raise PathError(f"{where}.radii: expected two positive numbers (m), got {list(pair['radii'])}")
    t0 = math.radians(_number(spec["start_deg"], f"{where}.start_deg"))
    t1 = math.radians(_number(spec["end_deg"], f"{where}.end_deg"))
    rot = math.radians(_number(spec.get("rotation_deg", 0.0), f"{where}.rotation_deg"))
    n = spec.get("points", 16)
    if isinstance(n, bool) or not isinstance(n, int) or n < 2:
        raise PathError(f"{where}.points: expected an integer >= 2, got {n!r}")
    cx, cy = pair["center"]
    cr, sr = math.cos(rot), math.sin(rot)
    out = []
    for k in range(n):
        t = t0 + (t1 - t0) * k / (n - 1)
        ex, ey = a * math.cos(t), b * math.sin(t)
        out.append(Waypoint(cx + cr * ex - sr * ey, cy + sr * ex + cr * ey))
    return out


def _waypoints(raw: Any) -> list[Waypoint]:
    if not isinstance(raw, Sequence) or isinstance(raw, str):
        raise PathError("waypoints: expected a list")
    out: list[Waypoint] = []
    for i, entry in enumerate(raw):
        where = f"waypoints[{i}]"
        if isinstance(entry, Mapping) and "ellipse_arc" in entry:
            if len(entry) != 1:
                raise PathError(f"{where}: an ellipse_arc entry takes no other keys")
            arc = _ellipse_arc(entry["ellipse_arc"], f"{where}.ellipse_arc")
            if out and math.hypot(arc[0].x - out[-1].x, arc[0].y - out[-1].y) < 1e-6:
                arc = arc[1:]  # the arc starts where the previous waypoint is
            out.extend(arc)
        elif isinstance(entry, Mapping):
            unknown = set(entry) - {"x", "y", "heading", "heading_deg", "stop"}
            if unknown:
                raise PathError(f"{where}: unknown keys {sorted(unknown)}; "
                                "allowed x, y, heading, heading_deg, stop")
            if "x" not in entry or "y" not in entry:
                raise PathError(f"{where}: expected a mapping with x and y (m)")
            stop = entry.get("stop", False)
            if not isinstance(stop, bool):
                raise PathError(f"{where}.stop: expected true or false, got {stop!r}")
            out.append(Waypoint(_number(entry["x"], f"{where}.x"), _number(entry["y"], f"{where}.y"),
                                _heading(entry, where), stop))
        elif isinstance(entry, Sequence) and not isinstance(entry, str) and len(entry) in (2, 3):
            vals = [_number(v, f"{where}[{k}]") for k, v in enumerate(entry)]
            out.append(Waypoint(vals[0], vals[1], vals[2] if len(vals) == 3 else None))
        else:
            raise PathError(f"{where}: expected [x, y], [x, y, heading_rad], a mapping "
                            f"{{x, y, heading|heading_deg, stop}} or {{ellipse_arc: ...}}, got {entry!r}")
    return out


def path_from_dict(data: Any, cycles: int | None = None) -> FieldPath:
    """Build a path from a parsed YAML document; ``cycles`` overrides the file's value."""
    if not isinstance(data, Mapping):
        raise PathError("path file: expected a mapping with a waypoints list")
    allowed = {"name", "frame_id", "closed", "cycles", "waypoints", "description"}
    unknown = set(data) - allowed
    if unknown:
        raise PathError(f"path file: unknown keys {sorted(unknown)}; allowed {sorted(allowed)}")
    if "waypoints" not in data:
        raise PathError("waypoints: missing")
    closed = data.get("closed", False)
    if not isinstance(closed, bool):
        raise PathError(f"closed: expected true or false, got {closed!r}")
    n_cycles = data.get("cycles", 1) if cycles is None else cycles
    name = data.get("name", "")
    if not isinstance(name, str):
        raise PathError(f"name: expected a string, got {name!r}")
    return FieldPath(_waypoints(data["waypoints"]), closed=closed, cycles=n_cycles,
                frame_id=data.get("frame_id", "map"), name=name)


def load_path(file: str | os.PathLike[str], cycles: int | None = None) -> FieldPath:
    """Load and validate a path YAML; errors name the file and the entry."""
    p = pathlib.Path(file)
    try:
        with open(p) as fh:
            data = yaml.safe_load(fh)
    except OSError as exc:
        raise PathError(f"{p}: cannot read ({exc.strerror})") from exc
    except yaml.YAMLError as exc:
        raise PathError(f"{p}: not valid YAML ({exc})") from exc
    try:
        path = path_from_dict(data, cycles)
    except PathError as exc:
        raise PathError(f"{p}: {exc}") from exc
    if not path.name:
        path.name = p.stem
    return path


# -- files -----------------------------------------------------------------------------
def _package_roots() -> list[pathlib.Path]:
    """The package's share directory (when installed), then the source tree."""
    roots = []
    try:
        from ament_index_python.packages import get_package_share_directory
        roots.append(pathlib.Path(get_package_share_directory(PACKAGE)))
    except (ImportError, LookupError, OSError):  # no ament index (AMENT_PREFIX_PATH unset), or
        pass                                       # the package is not installed there
    roots.append(pathlib.Path(__file__).resolve().parents[2])  # source / editable install
    return roots


def _search_roots() -> list[pathlib.Path]:
    return [pathlib.Path.cwd(), *_package_roots()]


def config_dir() -> pathlib.Path:
    """The package's config/ directory (share directory when installed, else the source tree)."""
    for root in _package_roots():
        if (root / "config").is_dir():
            return root / "config"
    raise FileNotFoundError("cannot find the package's config directory")


def resolve_config_file(name: str | os.PathLike[str]) -> pathlib.Path:
    """An existing file: absolute, else relative to the cwd, the package share dir, the source tree."""
    p = pathlib.Path(name).expanduser()
    if p.is_absolute():
        if p.is_file():
            return p
        raise FileNotFoundError(f"{p} does not exist")
    tried: list[str] = []
    for root in _search_roots():
        candidate = root / p
        if candidate.is_file():
            return candidate
        if str(candidate) not in tried:
            tried.append(str(candidate))
    raise FileNotFoundError(f"{p} not found; looked in: {', '.join(tried)}")


def preset_file(name: str) -> pathlib.Path:
    """The YAML of a preset path (``seed000_test_path`` or ``ftc_cycle``)."""
    if name not in PRESETS:
        raise PathError(f"unknown preset {name!r}; presets are {', '.join(PRESETS)}")
    return resolve_config_file(pathlib.Path("config") / "paths" / f"{name}.yaml")


def load_preset(name: str, cycles: int | None = None) -> FieldPath:
    """Load a preset path by name."""
    return load_path(preset_file(name), cycles)
