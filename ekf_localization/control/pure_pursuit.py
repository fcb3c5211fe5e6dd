"""Pure-pursuit path follower (seed 000 sec. V after Coulter 1992), ROS-free.

Each control step, given the robot's pose in the path's frame (docs/pure_pursuit.md):

1. progress: the nearest point on the path, searched forward only from the previous
   progress within ``search_window_factor · lookahead_distance`` of arc length (a path
   that comes back near itself, e.g. a repeated cycle, is never short-cut); the first call
   after a reset searches the whole first leg;
2. target (seed fig. 6): the intersection of the lookahead circle with the path that is
   furthest along it inside that window; the end of the leg once it is inside the circle;
   the nearest point if the circle meets the path nowhere. Its arc length never decreases;
3. command (body-frame twist ``vx, vy, wz``, REP-103):
   * holonomic (seed 000): three PIDs on x, y, θ in the field frame (eq. 34-37), the
     (x, y) output rotated into the body frame;
   * differential: curvature κ = 2·y/L² of the arc through the target (robot frame,
     Coulter), ω = v·κ; a heading PID turns in place when the target is more than
     ``rotate_in_place_angle`` off the nose (until within ``rotate_in_place_exit_angle``),
     and at stop points;
4. speed cap: ``max_linear_velocity``, ``v_max·d/slowdown_distance`` and ``sqrt(2·a_max·d)``
   with d the distance left on the leg (floor ``min_approach_velocity``), and a turn profile
   ``sqrt(a_max·L / (2·sin(φ/2)))`` before vertices where the path turns by φ;
5. acceleration limits over the real Δt between calls (field frame when holonomic);
6. a leg ends within ``goal_position_tolerance`` of its stop point and
   ``goal_heading_tolerance`` of the stop heading; after the last leg the follower is done
   and returns a zero twist until ``reset``.

Distances in metres, angles in radians, time in integer nanoseconds.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import NamedTuple

from ekf_localization.control.field_path import FieldPath
from ekf_localization.control.pid import PID, PIDGains
from ekf_localization.core.angles import wrap_angle
from ekf_localization.core.units import ns_to_seconds

MODES = ("holonomic", "differential")


class Command(NamedTuple):
    """Body-frame twist: forward (m/s), left (m/s), yaw rate CCW (rad/s)."""

    vx: float
    vy: float
    wz: float


ZERO = Command(0.0, 0.0, 0.0)


def circle_segment_intersections(cx: float, cy: float, r: float, x0: float, y0: float,
                                 x1: float, y1: float) -> tuple[float, ...]:
    """Parameters t in [0, 1] (sorted) where segment p0→p1 meets the circle (c, r).

    A tangent segment gives one t; a segment inside or outside the circle gives none.
    """
    dx, dy = x1 - x0, y1 - y0
    fx, fy = x0 - cx, y0 - cy
    a = dx * dx + dy * dy
    if a == 0.0:
        return ()
    b = fx * dx + fy * dy  # half of the usual b
    c = fx * fx + fy * fy - r * r
    disc = b * b - a * c
    if disc < 0.0:
        if disc < -1e-12 * a * r * r:
            return ()
        disc = 0.0  # rounding at a tangent
    if disc == 0.0:
        t = -b / a
        return (t,) if 0.0 <= t <= 1.0 else ()
    root = math.sqrt(disc)
    t1, t2 = (-b - root) / a, (-b + root) / a
    return tuple(t for t in (t1, t2) if 0.0 <= t <= 1.0)


def _require(name: str, value: float, *, positive: bool = False, allow_inf: bool = False) -> None:
    ok = not math.isnan(value) and (allow_inf or math.isfinite(value))
    ok = ok and (value > 0.0 if positive else value >= 0.0)
    if not ok:
        form = "> 0" if positive else ">= 0"
        raise ValueError(f"{name} must be a finite number {form}, got {value!r}")


@dataclass(frozen=True)
class FollowerConfig:
    """Follower parameters (SI). Defaults suit a seed-000-sized FTC robot (1.2 m/s class)."""

    mode: str = "holonomic"
    lookahead_distance: float = 0.3  # m, radius of the pursuit circle
    pid_x: PIDGains = field(default_factory=lambda: PIDGains(kp=5.0, ki=0.5, kd=0.2, integral_limit=0.1))
    pid_y: PIDGains = field(default_factory=lambda: PIDGains(kp=5.0, ki=0.5, kd=0.2, integral_limit=0.1))
    pid_yaw: PIDGains = field(default_factory=lambda: PIDGains(kp=4.0, ki=0.2, kd=0.1, integral_limit=0.2))
    max_linear_velocity: float = 1.0  # m/s
    max_angular_velocity: float = 2.0  # rad/s
    max_linear_acceleration: float = 2.0  # m/s²
    max_angular_acceleration: float = 6.0  # rad/s²
    slowdown_distance: float = 0.4  # m; 0 disables the linear ramp
    min_approach_velocity: float = 0.05  # m/s, floor of the approach speed cap
    goal_position_tolerance: float = 0.02  # m
    goal_heading_tolerance: float = 0.05  # rad
    rotate_in_place_angle: float = 1.5  # rad, differential: turn in place beyond this bearing ...
    rotate_in_place_exit_angle: float = 0.2  # rad, ... until the bearing is below this one
    search_window_factor: float = 2.0  # arc-length window = factor · lookahead_distance

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for name in ("pid_x", "pid_y", "pid_yaw"):
            if not isinstance(getattr(self, name), PIDGains):
                raise ValueError(f"{name} must be a PIDGains")
        for name in ("lookahead_distance", "max_linear_velocity", "max_angular_velocity",
                     "max_linear_acceleration", "max_angular_acceleration", "goal_position_tolerance",
                     "goal_heading_tolerance", "rotate_in_place_angle", "rotate_in_place_exit_angle"):
            _require(name, getattr(self, name), positive=True)
        for name in ("slowdown_distance", "min_approach_velocity"):
            _require(name, getattr(self, name))
        if self.search_window_factor < 1.0 or not math.isfinite(self.search_window_factor):
            raise ValueError(f"search_window_factor must be a finite number >= 1, "
                             f"got {self.search_window_factor!r}")
        if self.min_approach_velocity > self.max_linear_velocity:
            raise ValueError("min_approach_velocity must be <= max_linear_velocity")
        if self.rotate_in_place_angle > math.pi:
            raise ValueError(f"rotate_in_place_angle must be in (0, pi], got {self.rotate_in_place_angle!r}")
        if self.rotate_in_place_exit_angle > self.rotate_in_place_angle:
            raise ValueError("rotate_in_place_exit_angle must be <= rotate_in_place_angle, got "
                             f"{self.rotate_in_place_exit_angle!r} > {self.rotate_in_place_angle!r}")


def vertex_turn_speeds(path: FieldPath, config: FollowerConfig) -> tuple[float, ...]:
    """Speed allowed at each vertex for the turn the path makes within one lookahead after it.

    Turning the velocity through φ takes a speed change 2·v·sin(φ/2); pure pursuit starts
    the turn about one lookahead L before the vertex, so with acceleration a the robot
    can follow it at v = sqrt(a·L / (2·sin(φ/2))) (on an arc of radius R this is the
    centripetal limit sqrt(a·R)). Stop points and straight joints: no limit.
    """
    p, cfg = path, config
    L, a = cfg.lookahead_distance, cfg.max_linear_acceleration
    stops = set(p.stop_indices)
    n_seg = p.segment_count
    out = [math.inf] * len(p.xs)
    for k in range(1, n_seg):
        if k in stops:
            continue
        tangent_in = p.seg_tangent[k - 1]
        phi = 0.0
        j = k
        while j < n_seg and p.s[j] < p.s[k] + L:
            phi = max(phi, abs(wrap_angle(p.seg_tangent[j] - tangent_in)))
            if j + 1 in stops:
                break
            j += 1
        if phi > 1e-9:
            out[k] = math.sqrt(a * L / (2.0 * math.sin(0.5 * phi)))
    return tuple(out)


class PurePursuitFollower:
    """Follows one :class:`FieldPath`. Call :meth:`update` with the pose at increasing times."""

    def __init__(self, path: FieldPath, config: FollowerConfig | None = None) -> None:
        self.config = config or FollowerConfig()
        self.holonomic = self.config.mode == "holonomic"
        self._pid_x = PID(self.config.pid_x)
        self._pid_y = PID(self.config.pid_y)
        self._pid_yaw = PID(self.config.pid_yaw, angular=True)
        self.reset(path)

    # -- state -----------------------------------------------------------------------------
    def reset(self, path: FieldPath | None = None, keep_motion: bool = False) -> None:
        """Start over (optionally on a new path): progress 0, first leg, PIDs cleared.

        ``keep_motion``: the robot is moving (a path replaced on the fly); keep the last
        command and its time so the acceleration limits ramp from it rather than from rest.
        """
        last, last_t = (self._last, self._last_t_ns) if keep_motion else (ZERO, None)
        if path is not None:
            self.path = path
        self.leg = 0
        self.progress = 0.0  # m along the path (monotonic)
        self.target_s = 0.0  # m along the path of the target point (monotonic)
        self.target = self.path.point_at(0.0)
        self.target_heading = self.path.heading_at(0.0)
        self.cross_track_error = 0.0
        self.done = False
        self._position_reached = False
        self._turning_in_place = False
        self._last_t_ns: int | None = last_t
        self._last = last
        self._first = True
        self._vertex_speed = vertex_turn_speeds(self.path, self.config)
        self._reset_pids()

    def _turn_speed_cap(self, progress: float, stop_i: int) -> float:
        """Lowest speed over the vertices ahead, each plus what braking at a_max allows."""
        cfg = self.config
        p = self.path
        L, a = cfg.lookahead_distance, cfg.max_linear_acceleration
        horizon = progress + L + cfg.max_linear_velocity ** 2 / (2.0 * a)
        cap = math.inf
        k = max(1, bisect.bisect_right(p.s, progress - 0.5 * L))
        sv, speeds = p.s, self._vertex_speed
        while k < stop_i and sv[k] <= horizon:
            v = speeds[k]
            if v < math.inf:
                d = sv[k] - L - progress
                if d > 0.0:
                    v = math.sqrt(v * v + 2.0 * a * d)
                if v < cap:
                    cap = v
            k += 1
        return cap

    def _reset_pids(self) -> None:
        self._pid_x.reset()
        self._pid_y.reset()
        self._pid_yaw.reset()

    @property
    def leg_count(self) -> int:
        return len(self.path.stop_s)

    # -- geometry --------------------------------------------------------------------------
    def _furthest_intersection(self, x: float, y: float, r: float, s_lo: float, s_hi: float) -> float:
        """Largest arc length in [s_lo, s_hi] where the circle (x, y, r) meets the path; -1 if none."""
        p = self.path
        xs, ys, sv, dxs, dys, lens = p.xs, p.ys, p.s, p.seg_dx, p.seg_dy, p.seg_len
        best = -1.0
        i = p.segment_at(s_lo)
        n = len(lens)
        while i < n and sv[i] <= s_hi:
            for t in circle_segment_intersections(x, y, r, xs[i], ys[i], xs[i] + dxs[i], ys[i] + dys[i]):
                s = sv[i] + t * lens[i]
                if s_lo <= s <= s_hi and s > best:
                    best = s
            i += 1
        return best

    # -- control ---------------------------------------------------------------------------
    def update(self, x: float, y: float, theta: float, t_ns: int) -> Command:
        """Body-frame command for the pose (x, y, θ) measured at ``t_ns`` (int ns)."""
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):
            raise ValueError(f"pose must be finite, got ({x}, {y}, {theta})")
        if self.done:
            self._last = ZERO
            return ZERO
        cfg = self.config
        path = self.path
        dt = 0.0
        first = self._first
        self._first = False
        if self._last_t_ns is not None and t_ns > self._last_t_ns:
            dt = ns_to_seconds(t_ns - self._last_t_ns)
        if self._last_t_ns is None or t_ns > self._last_t_ns:
            self._last_t_ns = t_ns

        L = cfg.lookahead_distance
        window = cfg.search_window_factor * L
        while True:
            stop_i = path.stop_indices[self.leg]
            leg_end = path.stop_s[self.leg]
            ex, ey = path.xs[stop_i], path.ys[stop_i]

            # 1. progress: nearest point, forward only, inside the window (on the first call
            # after a reset: anywhere on the first leg, so a robot may join mid-path)
            s_hi = leg_end if first else min(leg_end, self.progress + window)
            s_near, _, _, d_near = path.nearest(x, y, self.progress, s_hi)
            if s_near > self.progress:
                self.progress = s_near
            self.cross_track_error = d_near
            d_end = math.hypot(ex - x, ey - y)

            # 6. end of leg: at the stop point and at its heading
            stop_heading = path.stop_heading(self.leg)
            if d_end <= cfg.goal_position_tolerance and leg_end - self.progress <= L:
                self._position_reached = True
            elif self.holonomic:
                self._position_reached = False  # holonomic: position and heading together
            if not (self._position_reached
                    and abs(wrap_angle(stop_heading - theta)) <= cfg.goal_heading_tolerance):
                break
            self.progress = self.target_s = leg_end
            self.leg += 1
            self._position_reached = self._turning_in_place = False
            self._reset_pids()
            if self.leg >= self.leg_count:
                self.done = True
                self._last = ZERO
                return ZERO

        # 2. target point (monotonic in arc length)
        if d_end <= L and leg_end - self.progress <= window:
            s_t = leg_end
        else:
            s_t = self._furthest_intersection(x, y, L, self.progress, min(leg_end, self.progress + window))
            if s_t < 0.0:
                s_t = s_near
        if s_t > self.target_s:
            self.target_s = s_t
        if self.target_s >= leg_end:
            self.target_s = leg_end
            self.target = (ex, ey)
            self.target_heading = stop_heading
        else:
            seg = path.segment_at(self.target_s)
            self.target = path.point_at(self.target_s, seg)
            self.target_heading = path.heading_at(self.target_s, seg)

        # 4. speed cap: approach ramp and braking to the leg end, turn profile ahead
        d_rem = max(leg_end - self.progress, d_end)
        v_cap = cfg.max_linear_velocity
        if cfg.slowdown_distance > 0.0:
            v_cap = min(v_cap, cfg.max_linear_velocity * d_rem / cfg.slowdown_distance)
        v_cap = max(min(v_cap, math.sqrt(2.0 * cfg.max_linear_acceleration * d_rem),
                        self._turn_speed_cap(self.progress, stop_i)),
                    cfg.min_approach_velocity)

        # 3. command, 5. acceleration limits
        if self.holonomic:
            # acceleration limits act on the field-frame velocity (what the path sees), then the
            # command is rotated into the body frame
            vx, vy, wz = self._limit(self._holonomic(x, y, theta, t_ns, v_cap), dt)
            c, s = math.cos(theta), math.sin(theta)
            return Command(c * vx + s * vy, -s * vx + c * vy, wz)
        return self._limit(
            self._differential(x, y, theta, t_ns, v_cap, stop_i, leg_end, ex, ey, stop_heading), dt)

    def _holonomic(self, x: float, y: float, theta: float, t_ns: int, v_cap: float) -> Command:
        """Field-frame (vx, vy, ω) from the three PIDs (eq. 34), speed-capped."""
        tx, ty = self.target
        ux = self._pid_x.update(tx, x, t_ns)
        uy = self._pid_y.update(ty, y, t_ns)
        wz = self._clamp_w(self._pid_yaw.update(self.target_heading, theta, t_ns))
        speed = math.hypot(ux, uy)
        if speed > v_cap:
            k = v_cap / speed
            ux *= k
            uy *= k
        return Command(ux, uy, wz)

    def _differential(self, x: float, y: float, theta: float, t_ns: int, v_cap: float, stop_i: int,
                      leg_end: float, ex: float, ey: float, stop_heading: float) -> Command:
        cfg = self.config
        if self._position_reached:  # turn in place to the stop heading
            return Command(0.0, 0.0, self._clamp_w(self._pid_yaw.update(stop_heading, theta, t_ns)))
        tx, ty = self.target
        if self.target_s >= leg_end:
            # goal inside the circle: aim along the extension of the last segment so the
            # arc stays gentle; once past the goal, aim at the goal itself
            seg = stop_i - 1
            length = self.path.seg_len[seg]
            ux, uy = self.path.seg_dx[seg] / length, self.path.seg_dy[seg] / length
            along = (ex - x) * ux + (ey - y) * uy
            if along > 0.0:
                ext = max(cfg.lookahead_distance - along, 0.0)
                tx, ty = ex + ux * ext, ey + uy * ext
        c, s = math.cos(theta), math.sin(theta)
        rx, ry = tx - x, ty - y
        fx, fy = c * rx + s * ry, -s * rx + c * ry  # target in the robot frame
        d2 = fx * fx + fy * fy
        if d2 == 0.0:
            return Command(0.0, 0.0, 0.0)
        bearing = math.atan2(fy, fx)
        if abs(bearing) > cfg.rotate_in_place_angle:
            self._turning_in_place = True
        elif abs(bearing) < cfg.rotate_in_place_exit_angle:
            self._turning_in_place = False
        if self._turning_in_place:
            return Command(0.0, 0.0, self._clamp_w(self._pid_yaw.update(theta + bearing, theta, t_ns)))
        kappa = 2.0 * fy / d2  # Coulter: κ = 2y/L²
        v = v_cap
        w = v * kappa
        if abs(w) > cfg.max_angular_velocity:
            v = cfg.max_angular_velocity / abs(kappa)
            w = math.copysign(cfg.max_angular_velocity, kappa)
        self._pid_yaw.update(theta, theta, t_ns)  # keep its Δt and measurement history current
        return Command(v, 0.0, w)

    def _clamp_w(self, w: float) -> float:
        wmax = self.config.max_angular_velocity
        return wmax if w > wmax else (-wmax if w < -wmax else w)

    def _limit(self, cmd: Command, dt: float) -> Command:
        """Acceleration limits against the previous command over the real Δt.

        Holonomic: on the field-frame velocity; differential: on the body-frame (v, ω), and
        when ω is held back, v is lowered as far as the deceleration limit allows so the
        robot stays on the commanded arc (κ = ω/v).
        """
        cfg = self.config
        last = self._last
        vx, vy, wz = cmd
        kappa = wz / vx if (not self.holonomic and vx > 0.0) else None
        dvx, dvy = vx - last.vx, vy - last.vy
        dv = math.hypot(dvx, dvy)
        max_dv = cfg.max_linear_acceleration * dt
        if dv > max_dv:
            k = max_dv / dv
            vx, vy = last.vx + dvx * k, last.vy + dvy * k
        dw = wz - last.wz
        max_dw = cfg.max_angular_acceleration * dt
        if abs(dw) > max_dw:
            wz = last.wz + math.copysign(max_dw, dw)
        if kappa is not None and kappa != 0.0 and abs(vx * kappa) > abs(wz):
            v_arc = abs(wz / kappa) if wz * kappa > 0.0 else 0.0
            vx = max(v_arc, last.vx - max_dv, 0.0)
        out = Command(vx, vy, wz)
        self._last = out
        return out
