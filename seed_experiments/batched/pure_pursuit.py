"""Pure pursuit for N robots on one path at once (holonomic mode), vectorised over the trials.

The algorithm is :class:`~ekf_localization.control.pure_pursuit.PurePursuitFollower`'s (the
reference; docs/pure_pursuit.md), step for step, with numpy arrays over the trials in place of
its scalars: 1. progress by the forward-only nearest point, 6. the leg ends, 2. the furthest
lookahead intersection as the target, 4. the approach / braking / turn speed caps, 3. the three
PIDs of seed 000 eq. 34-37, 5. the acceleration limits. The geometric searches evaluate every
segment (or vertex) for every trial and mask the ones outside the search window instead of
looping over the window. ``test/test_batched_pure_pursuit.py`` compares the commands and the
state with N reference followers to a floating-point tolerance.

All trials share one clock (``update(x, y, theta, t_ns)`` with one ``t_ns``), as in a
Monte-Carlo loop. A trial that is done returns a zero twist and keeps its state, like the
reference. Differential mode stays with the per-trial follower.
"""

from __future__ import annotations

import numpy as np

from ekf_localization.control.field_path import FieldPath
from ekf_localization.control.pure_pursuit import FollowerConfig, vertex_turn_speeds
from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.units import NS_PER_S, ns_to_seconds

_YAW = 2  # column of the yaw PID in the (N, 3) PID arrays (x, y, yaw)


class _PathArrays:
    """A :class:`FieldPath`'s geometry as numpy arrays (vertices, segments, legs)."""

    def __init__(self, path: FieldPath, config: FollowerConfig) -> None:
        self.vx = np.array(path.xs)  # vertices
        self.vy = np.array(path.ys)
        self.vs = np.array(path.s)  # arc length at each vertex
        self.sx = self.vx[:-1]  # segment starts
        self.sy = self.vy[:-1]
        self.ss = self.vs[:-1]
        self.dx = np.array(path.seg_dx)
        self.dy = np.array(path.seg_dy)
        self.seg_len = np.array(path.seg_len)
        self.h0 = np.array(path.seg_heading_start)
        self.h1 = np.array(path.seg_heading_end)
        self.stop_i = np.array(path.stop_indices)
        self.stop_s = np.array(path.stop_s)
        self.stop_heading = np.array([path.stop_heading(k) for k in range(len(path.stop_s))])
        self.vertex_speed = np.array(vertex_turn_speeds(path, config))
        self.length = path.length
        self.n_seg = len(self.seg_len)

    def segment_at(self, s: np.ndarray) -> np.ndarray:
        """FieldPath.segment_at per trial: the segment holding arc length s (a vertex: the outgoing)."""
        return np.clip(np.searchsorted(self.vs, s, side="right") - 1, 0, self.n_seg - 1)

    def in_window(self, s_lo: np.ndarray, s_hi: np.ndarray) -> np.ndarray:
        """(n, segments) mask of the segments the reference visits for [s_lo, s_hi]: from the one
        holding s_lo while the segment starts at or before s_hi."""
        j = np.arange(self.n_seg)
        return (j >= self.segment_at(s_lo)[:, None]) & (self.ss <= s_hi[:, None])

    def nearest(self, x: np.ndarray, y: np.ndarray, s_min: np.ndarray,
                s_max: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """FieldPath.nearest per trial: (arc length, distance) of the nearest point in [s_min, s_max]."""
        s_min = np.clip(s_min, 0.0, self.length)
        s_max = np.clip(np.maximum(s_max, s_min), None, self.length)
        L = self.seg_len
        t_lo = np.maximum(0.0, (s_min[:, None] - self.ss) / L)
        t_hi = np.minimum(1.0, (s_max[:, None] - self.ss) / L)
        t = ((x[:, None] - self.sx) * self.dx + (y[:, None] - self.sy) * self.dy) / (L * L)  # projection
        t = np.where(t < t_lo, t_lo, np.where(t > t_hi, t_hi, t))
        d2 = (self.sx + t * self.dx - x[:, None]) ** 2 + (self.sy + t * self.dy - y[:, None]) ** 2
        d2 = np.where(self.in_window(s_min, s_max), d2, np.inf)
        best = np.argmin(d2, axis=1)  # the first minimum, as the reference's strict '<'
        rows = np.arange(len(x))
        return self.ss[best] + t[rows, best] * L[best], np.sqrt(d2[rows, best])

    def furthest_intersection(self, x: np.ndarray, y: np.ndarray, r: float, s_lo: np.ndarray,
                              s_hi: np.ndarray) -> np.ndarray:
        """Largest arc length in [s_lo, s_hi] where the circle (x, y, r) meets the path, -1 where it
        does not: pure_pursuit.circle_segment_intersections on every segment of the window."""
        a = self.dx * self.dx + self.dy * self.dy  # > 0: FieldPath refuses zero-length segments
        fx = self.sx - x[:, None]
        fy = self.sy - y[:, None]
        hb = fx * self.dx + fy * self.dy  # half of the usual b
        c = fx * fx + fy * fy - r * r
        disc = hb * hb - a * c
        meets = (disc >= -1e-12 * a * r * r) & self.in_window(s_lo, s_hi)  # within rounding of a tangent
        root = np.sqrt(np.maximum(disc, 0.0))
        best = np.full(len(x), -1.0)
        for t in ((-hb - root) / a, (-hb + root) / a):
            s = self.ss + t * self.seg_len
            ok = meets & (t >= 0.0) & (t <= 1.0) & (s >= s_lo[:, None]) & (s <= s_hi[:, None])
            best = np.maximum(best, np.where(ok, s, -1.0).max(axis=1))
        return best

    def turn_speed_cap(self, progress: np.ndarray, stop_i: np.ndarray, L: float, a: float,
                       brake: float) -> np.ndarray:
        """PurePursuitFollower._turn_speed_cap per trial: the lowest vertex speed ahead up to the
        braking horizon (``brake`` = v_max² / 2a), each plus what braking at ``a`` allows."""
        horizon = progress + L + brake
        k0 = np.maximum(1, np.searchsorted(self.vs, progress - 0.5 * L, side="right"))
        k = np.arange(len(self.vs))
        ahead = ((k >= k0[:, None]) & (k < stop_i[:, None]) & (self.vs <= horizon[:, None])
                 & np.isfinite(self.vertex_speed))
        v = self.vertex_speed
        d = self.vs - L - progress[:, None]  # distance left to brake before the turn starts
        with np.errstate(invalid="ignore"):  # inf - inf where a vertex has no limit (masked)
            v_brake = np.where(d > 0.0, np.sqrt(v * v + 2.0 * a * np.maximum(d, 0.0)), v)
        return np.where(ahead, v_brake, np.inf).min(axis=1)


class BatchedPurePursuit:
    """N holonomic pure-pursuit followers on one :class:`FieldPath`."""

    def __init__(self, path: FieldPath, config: FollowerConfig | None = None, n: int = 1) -> None:
        self.config = config or FollowerConfig()
        if self.config.mode != "holonomic":
            raise ValueError("BatchedPurePursuit follows in holonomic mode only; use one "
                             "PurePursuitFollower per trial for differential mode")
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        self.n = n
        self.path = path
        self._p = _PathArrays(path, self.config)
        cfg = self.config
        gains = (cfg.pid_x, cfg.pid_y, cfg.pid_yaw)
        self._kp, self._ki, self._kd, self._integral_limit, self._output_limit = (
            np.array([getattr(g, a) for g in gains])
            for a in ("kp", "ki", "kd", "integral_limit", "output_limit"))
        self.reset()

    # -- state -----------------------------------------------------------------------------
    def reset(self) -> None:
        """Start every trial over: progress 0, first leg, PIDs cleared, at rest."""
        n = self.n
        self.leg = np.zeros(n, dtype=np.int64)
        self.progress = np.zeros(n)  # m along the path (monotonic)
        self.target_s = np.zeros(n)
        self.target = np.tile(self.path.point_at(0.0), (n, 1))
        self.target_heading = np.full(n, self.path.heading_at(0.0))
        self.cross_track_error = np.zeros(n)
        self.done = np.zeros(n, dtype=bool)
        self._position_reached = np.zeros(n, dtype=bool)
        self._last_t_ns = np.zeros(n, dtype=np.int64)
        self._has_last_t = np.zeros(n, dtype=bool)
        self._last = np.zeros((n, 3))  # field-frame (vx, vy, wz) of the last command
        self._first = np.ones(n, dtype=bool)
        # the three PIDs (x, y, yaw) per trial: reset and updated together, so they share a clock
        self._integral = np.zeros((n, 3))
        self._last_error = np.zeros((n, 3))
        self._pid_last_measurement = np.zeros((n, 3))
        self._pid_last_t_ns = np.zeros(n, dtype=np.int64)
        self._pid_has_last = np.zeros(n, dtype=bool)

    def _reset_pids(self, trials: np.ndarray) -> None:
        self._integral[trials] = 0.0
        self._last_error[trials] = 0.0
        self._pid_has_last[trials] = False

    @property
    def leg_count(self) -> int:
        return len(self._p.stop_s)

    # -- control ---------------------------------------------------------------------------
    def update(self, x: np.ndarray, y: np.ndarray, theta: np.ndarray, t_ns: int) -> np.ndarray:
        """(N, 3) body-frame commands (vx, vy, wz) for the poses (N,) measured at ``t_ns``."""
        x, y, theta = (np.asarray(v, dtype=float) for v in (x, y, theta))
        if x.shape != (self.n,) or y.shape != (self.n,) or theta.shape != (self.n,):
            raise ValueError(f"x, y, theta must have shape ({self.n},)")
        bad = np.flatnonzero(~(np.isfinite(x) & np.isfinite(y) & np.isfinite(theta)))
        if len(bad):
            i = int(bad[0])
            raise ValueError(f"pose must be finite, got ({x[i]}, {y[i]}, {theta[i]}) in trial {i}")
        t_ns = int(t_ns)
        out = np.zeros((self.n, 3))
        self._last[self.done] = 0.0
        run = np.flatnonzero(~self.done)
        if len(run) == 0:
            return out
        # the follower's clock (the acceleration limits' Δt)
        has, last_t = self._has_last_t[run], self._last_t_ns[run]
        dt = np.where(has & (t_ns > last_t), ns_to_seconds(t_ns - last_t), 0.0)
        self._last_t_ns[run] = np.where(~has | (t_ns > last_t), t_ns, last_t)
        self._has_last_t[run] = True
        first = self._first[run]
        self._first[run] = False

        leg_state = self._progress_and_leg_ends(run, x[run], y[run], theta[run], first)
        going = ~self.done[run]
        run, dt = run[going], dt[going]
        if len(run) == 0:
            return out
        stop_i, leg_end, s_near, d_end, stop_heading = (v[going] for v in leg_state)
        xr, yr, thr = x[run], y[run], theta[run]
        tx, ty, th = self._target(run, xr, yr, stop_i, leg_end, s_near, d_end, stop_heading)
        v_cap = self._speed_cap(self.progress[run], stop_i, leg_end, d_end)

        # 3. command: three PIDs in the field frame (eq. 34), speed-capped
        u = self._pids(run, np.column_stack([tx, ty, th]), np.column_stack([xr, yr, thr]), t_ns)
        w_max = self.config.max_angular_velocity
        u[:, 2] = np.clip(u[:, 2], -w_max, w_max)
        speed = np.hypot(u[:, 0], u[:, 1])
        fast = speed > v_cap
        u[fast, :2] *= (v_cap[fast] / speed[fast])[:, None]
        u = self._limit(run, u, dt)
        # the field-frame (x, y) velocity rotated into the body frame
        c, s = np.cos(thr), np.sin(thr)
        out[run, 0] = c * u[:, 0] + s * u[:, 1]
        out[run, 1] = -s * u[:, 0] + c * u[:, 1]
        out[run, 2] = u[:, 2]
        return out

    def _progress_and_leg_ends(self, run: np.ndarray, x: np.ndarray, y: np.ndarray, theta: np.ndarray,
                               first: np.ndarray) -> tuple[np.ndarray, ...]:
        """Steps 1 and 6 for the trials ``run``: progress by the nearest point, then, while a trial
        is at its leg's stop point and heading (holonomic: both together), the next leg. Returns,
        per trial of ``run``, the leg's stop vertex and arc length, the nearest point's arc length,
        the distance to the stop point and the stop heading, all of the leg the trial stays on."""
        cfg, p = self.config, self._p
        L = cfg.lookahead_distance
        window = cfg.search_window_factor * L
        m = len(run)
        stop_i = np.zeros(m, dtype=np.int64)
        leg_end, s_near, d_end, stop_heading = (np.zeros(m) for _ in range(4))
        pending = np.arange(m)  # positions in ``run`` still in the loop
        while len(pending):
            b = run[pending]
            leg = self.leg[b]
            si, le = p.stop_i[leg], p.stop_s[leg]
            s_hi = np.where(first[pending], le, np.minimum(le, self.progress[b] + window))
            sn, dn = p.nearest(x[pending], y[pending], self.progress[b], s_hi)
            prog = np.maximum(self.progress[b], sn)
            self.progress[b] = prog
            self.cross_track_error[b] = dn
            de = np.hypot(p.vx[si] - x[pending], p.vy[si] - y[pending])
            sh = p.stop_heading[leg]
            at = (de <= cfg.goal_position_tolerance) & (le - prog <= L)
            self._position_reached[b] = at
            stop_i[pending], leg_end[pending], s_near[pending], d_end[pending], stop_heading[pending] = (
                si, le, sn, de, sh)
            ends = at & (np.abs(wrap_angles(sh - theta[pending])) <= cfg.goal_heading_tolerance)
            e = b[ends]
            self.progress[e] = self.target_s[e] = le[ends]
            self.leg[e] += 1
            self._position_reached[e] = False
            self._reset_pids(e)
            finished = e[self.leg[e] >= self.leg_count]
            self.done[finished] = True
            self._last[finished] = 0.0
            pending = pending[ends & (self.leg[b] < self.leg_count)]
        return stop_i, leg_end, s_near, d_end, stop_heading

    def _target(self, run: np.ndarray, x: np.ndarray, y: np.ndarray, stop_i: np.ndarray,
                leg_end: np.ndarray, s_near: np.ndarray, d_end: np.ndarray,
                stop_heading: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Step 2: the target point (monotonic in arc length) and its heading; (x, y, heading)."""
        cfg, p = self.config, self._p
        L = cfg.lookahead_distance
        window = cfg.search_window_factor * L
        prog = self.progress[run]
        hit = p.furthest_intersection(x, y, L, prog, np.minimum(leg_end, prog + window))
        s_t = np.where(hit < 0.0, s_near, hit)  # the circle misses the path: the nearest point
        s_t = np.where((d_end <= L) & (leg_end - prog <= window), leg_end, s_t)  # leg end in the circle
        ts = np.maximum(self.target_s[run], s_t)
        end = ts >= leg_end
        ts = np.minimum(ts, leg_end)
        self.target_s[run] = ts
        seg = p.segment_at(ts)  # FieldPath.point_at and heading_at on that segment
        f = (np.clip(ts, 0.0, p.length) - p.vs[seg]) / p.seg_len[seg]
        h0 = p.h0[seg]
        heading = wrap_angles(h0 + np.clip(f, 0.0, 1.0) * wrap_angles(p.h1[seg] - h0))
        tx = np.where(end, p.vx[stop_i], p.sx[seg] + f * p.dx[seg])
        ty = np.where(end, p.vy[stop_i], p.sy[seg] + f * p.dy[seg])
        th = np.where(end, stop_heading, heading)
        self.target[run, 0] = tx
        self.target[run, 1] = ty
        self.target_heading[run] = th
        return tx, ty, th

    def _speed_cap(self, progress: np.ndarray, stop_i: np.ndarray, leg_end: np.ndarray,
                   d_end: np.ndarray) -> np.ndarray:
        """Step 4: the approach ramp and braking to the leg end, the turn profile ahead."""
        cfg = self.config
        v_max, a = cfg.max_linear_velocity, cfg.max_linear_acceleration
        d_rem = np.maximum(leg_end - progress, d_end)
        v_cap = np.full(len(progress), v_max)
        if cfg.slowdown_distance > 0.0:
            v_cap = np.minimum(v_cap, v_max * d_rem / cfg.slowdown_distance)
        turn = self._p.turn_speed_cap(progress, stop_i, cfg.lookahead_distance, a, v_max ** 2 / (2.0 * a))
        return np.maximum(np.minimum(np.minimum(v_cap, np.sqrt(2.0 * a * d_rem)), turn),
                          cfg.min_approach_velocity)

    def _pids(self, run: np.ndarray, setpoint: np.ndarray, measurement: np.ndarray, t_ns: int) -> np.ndarray:
        """PID.update (eq. 34-37) of the x, y and yaw PIDs of the trials ``run``: (n, 3) actions."""
        error = setpoint - measurement  # eq. 35
        error[:, _YAW] = wrap_angles(error[:, _YAW])
        has, last_t = self._pid_has_last[run], self._pid_last_t_ns[run]
        step = has & (t_ns > last_t)  # Δt > 0: the I and D terms
        moved = ~has | (t_ns > last_t)
        dt = np.where(step, (t_ns - last_t) / NS_PER_S, 1.0)[:, None]  # 1.0: unused (no step)
        integral = np.clip(self._integral[run] + error * dt, -self._integral_limit,
                           self._integral_limit)  # eq. 36 with Δt, clamped (anti-windup)
        integral = np.where(step[:, None], integral, self._integral[run])
        delta = measurement - self._pid_last_measurement[run]
        delta[:, _YAW] = wrap_angles(delta[:, _YAW])
        derivative = np.where(step[:, None], -delta / dt, 0.0)  # eq. 37 on the measurement
        self._integral[run] = integral
        last_measurement = self._pid_last_measurement[run]
        self._pid_last_measurement[run] = np.where(moved[:, None], measurement, last_measurement)
        self._pid_last_t_ns[run] = np.where(moved, t_ns, last_t)
        self._pid_has_last[run] = True
        self._last_error[run] = error
        u = self._kp * error + self._ki * integral + self._kd * derivative  # eq. 34
        return np.clip(u, -self._output_limit, self._output_limit)

    def _limit(self, run: np.ndarray, u: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """Step 5: acceleration limits on the field-frame velocity against the last command."""
        cfg = self.config
        last = self._last[run]
        dv = u[:, :2] - last[:, :2]
        dv_norm = np.hypot(dv[:, 0], dv[:, 1])
        max_dv = cfg.max_linear_acceleration * dt
        over = dv_norm > max_dv
        u[over, :2] = last[over, :2] + dv[over] * (max_dv[over] / dv_norm[over])[:, None]
        dw = u[:, 2] - last[:, 2]
        max_dw = cfg.max_angular_acceleration * dt
        u[:, 2] = np.where(np.abs(dw) > max_dw, last[:, 2] + np.copysign(max_dw, dw), u[:, 2])
        self._last[run] = u
        return u
