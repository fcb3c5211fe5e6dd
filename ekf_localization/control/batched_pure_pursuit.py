"""Pure pursuit for N robots on one path at once, numpy over the trial axis (holonomic mode).

The algorithm is :class:`~ekf_localization.control.pure_pursuit.PurePursuitFollower`'s
(the reference; docs/pure_pursuit.md), step for step: progress by the forward-only nearest
point, the furthest lookahead intersection as the target, the approach / braking / turn
speed caps, the three PIDs of seed 000 eq. 34-37, the acceleration limits and the leg ends.
Every comparison and every floating-point expression is evaluated in the reference's order,
so the commands are the same to the last bit (``test/test_batched_pure_pursuit.py``); the
loops over path segments (nearest point, lookahead intersection) are the reference's loops,
compiled, once per trial. Python's max/min become np.maximum/np.minimum (the same value for
finite inputs).

All trials share one clock (``update(x, y, theta, t_ns)`` with one ``t_ns``), as in a
Monte-Carlo loop. A trial that is done returns a zero twist and keeps its state, like the
reference. Differential mode stays with the per-trial follower.
"""

from __future__ import annotations

import math

import numpy as np

from ekf_localization.control.field_path import FieldPath
from ekf_localization.control.pid import PIDGains
from ekf_localization.control.pure_pursuit import FollowerConfig, vertex_turn_speeds
from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.kernels import njit, source_stamp, wrap
from ekf_localization.core.units import NS_PER_S


def _hypot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """math.hypot element by element: np.hypot (libm) differs from it in the last bit for
    about 0.3% of inputs, and bit-equal commands keep the experiments' numbers unchanged."""
    return np.fromiter(map(math.hypot, a.tolist(), b.tolist()), float, len(a))


def _clamp(v: np.ndarray, lo: np.ndarray | float, hi: np.ndarray | float) -> np.ndarray:
    return np.minimum(np.maximum(v, lo), hi)


@njit(cache=True)
def _first_segment(vs: np.ndarray, s: float, n_segments: int) -> int:  # pragma: no cover - compiled
    """FieldPath.segment_at."""
    i = np.searchsorted(vs, s, side="right") - 1
    return min(max(i, 0), n_segments - 1)


@njit(cache=True)
def _nearest_points(x, y, s_min, s_max, vs, ss, sx, sy, dx, dy, seg_len, s_out, d_out):  # pragma: no cover
    """FieldPath.nearest per trial, its loop and arithmetic, into s_out and d_out (compiled)."""
    n = seg_len.shape[0]
    for b in range(x.shape[0]):
        best = -1
        best_d2 = math.inf
        best_t = 0.0
        i = _first_segment(vs, s_min[b], n)
        while i < n and ss[i] <= s_max[b]:
            L = seg_len[i]
            t_lo = max(0.0, (s_min[b] - ss[i]) / L)
            t_hi = min(1.0, (s_max[b] - ss[i]) / L)
            t = ((x[b] - sx[i]) * dx[i] + (y[b] - sy[i]) * dy[i]) / (L * L)
            t = min(max(t, t_lo), t_hi)
            px = sx[i] + t * dx[i]
            py = sy[i] + t * dy[i]
            d2 = (px - x[b]) * (px - x[b]) + (py - y[b]) * (py - y[b])
            if best < 0 or d2 < best_d2:  # the first strict minimum
                best, best_d2, best_t = i, d2, t
            i += 1
        s_out[b] = ss[best] + best_t * seg_len[best]
        d_out[b] = math.sqrt(best_d2)


@njit(cache=True)
def _furthest_intersections(x, y, r, s_lo, s_hi, vs, ss, sx, sy, ca, cdx, cdy, seg_len,
                            out):  # pragma: no cover - compiled
    """The reference's circle test per trial over its segments (see _furthest_intersection)."""
    n = seg_len.shape[0]
    for b in range(x.shape[0]):
        best = -1.0
        i = _first_segment(vs, s_lo[b], n)
        while i < n and ss[i] <= s_hi[b]:
            a = ca[i]
            fx = sx[i] - x[b]
            fy = sy[i] - y[b]
            hb = fx * cdx[i] + fy * cdy[i]  # half of the usual b
            c = fx * fx + fy * fy - r * r
            disc = hb * hb - a * c
            if disc >= -1e-12 * a * r * r and a != 0.0:
                root = math.sqrt(max(disc, 0.0))  # a tangent: one root, twice
                for t in ((-hb - root) / a, (-hb + root) / a):
                    s = ss[i] + t * seg_len[i]
                    if t >= 0.0 and t <= 1.0 and s >= s_lo[b] and s <= s_hi[b] and s > best:
                        best = s
            i += 1
        out[b] = best


@njit(cache=True)
def _turn_speed_caps(progress, stop_i, horizon, k0, L, a, vs, vertex_speed, out):  # pragma: no cover
    """Per trial, the lowest of the vertices [k0, stop_i) up to the horizon, each plus braking
    (see BatchedPurePursuit._turn_speed_cap; compiled)."""
    for b in range(progress.shape[0]):
        best = math.inf
        k = k0[b]
        while k < stop_i[b] and vs[k] <= horizon[b]:
            v = vertex_speed[k]
            if v < math.inf:
                d = vs[k] - L - progress[b]
                vd = math.sqrt(v * v + 2.0 * a * d) if d > 0.0 else v
                best = min(best, vd)
            k += 1
        out[b] = best


def _make_pid_steps(stamp: str):
    """The three PIDs' step per trial (wraps with core.kernels' wrap: keyed by ``stamp``)."""

    @njit(cache=True)
    def pid_steps(setpoint, measurement, t_ns, idx, kp, ki, kd, i_lim, u_lim, integral, last_error,
                  last_measurement, last_t_ns, has_last, out):  # pragma: no cover - compiled
        """PID.update (eq. 34-37) of axes x, y, yaw (angular) for the trials idx, in its order."""
        if len(stamp) < 0:  # never true: references the stamp so that it keys the cache
            return
        for r in range(idx.shape[0]):
            b = idx[r]
            step = has_last[b] and t_ns > last_t_ns[b]
            moved = not has_last[b] or t_ns > last_t_ns[b]
            dt = (t_ns - last_t_ns[b]) / NS_PER_S if step else 0.0
            for c in range(3):
                error = setpoint[r, c] - measurement[r, c]  # eq. 35
                if c == 2:
                    error = wrap(error)
                derivative = 0.0
                if step:
                    new = integral[b, c] + error * dt  # eq. 36 with Δt, clamped (anti-windup)
                    integral[b, c] = min(max(new, -i_lim[c]), i_lim[c])
                    delta = measurement[r, c] - last_measurement[b, c]
                    if c == 2:
                        delta = wrap(delta)
                    derivative = -(delta / dt)  # eq. 37 on the measurement
                if moved:
                    last_measurement[b, c] = measurement[r, c]
                last_error[b, c] = error
                u = kp[c] * error + ki[c] * integral[b, c] + kd[c] * derivative  # eq. 34
                out[r, c] = min(max(u, -u_lim[c]), u_lim[c])
            if moved:
                last_t_ns[b] = t_ns
            has_last[b] = True

    return pid_steps


_pid_steps = _make_pid_steps(source_stamp(__file__))


class _BatchedPIDs:
    """The follower's three :class:`~ekf_localization.control.pid.PID` loops (x, y, yaw) for
    N trials, as (N, 3) arrays; they are reset together, so they share one clock per trial."""

    def __init__(self, gains: tuple[PIDGains, PIDGains, PIDGains], n: int) -> None:
        self.kp, self.ki, self.kd, self.i_lim, self.u_lim = (
            np.array([getattr(g, a) for g in gains])
            for a in ("kp", "ki", "kd", "integral_limit", "output_limit"))
        self.integral = np.zeros((n, 3))
        self.last_error = np.zeros((n, 3))
        self._last_measurement = np.zeros((n, 3))
        self._last_t_ns = np.zeros(n, dtype=np.int64)
        self._has_last = np.zeros(n, dtype=bool)

    def reset(self, idx: np.ndarray | slice) -> None:
        self.integral[idx] = 0.0
        self.last_error[idx] = 0.0
        self._has_last[idx] = False

    def update(self, setpoint: np.ndarray, measurement: np.ndarray, t_ns: int, idx: np.ndarray) -> np.ndarray:
        """(len(idx), 3) actions of the trials ``idx``; columns x, y, yaw (the angular one)."""
        out = np.empty((len(idx), 3))
        sp, meas = (np.ascontiguousarray(v, dtype=float) for v in (setpoint, measurement))
        _pid_steps(sp, meas, int(t_ns), np.ascontiguousarray(idx, dtype=np.int64), self.kp, self.ki, self.kd,
                   self.i_lim, self.u_lim, self.integral, self.last_error, self._last_measurement,
                   self._last_t_ns, self._has_last, out)
        return out


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
        p = path
        self._vx = np.array(p.xs)  # vertices
        self._vy = np.array(p.ys)
        self._vs = np.array(p.s)
        self._sx = self._vx[:-1]  # segment starts
        self._sy = self._vy[:-1]
        self._ss = self._vs[:-1]
        self._dx = np.array(p.seg_dx)
        self._dy = np.array(p.seg_dy)
        self._len = np.array(p.seg_len)
        # the reference's circle test takes the segment end as start + delta, then subtracts
        self._cdx = (self._sx + self._dx) - self._sx
        self._cdy = (self._sy + self._dy) - self._sy
        self._ca = self._cdx * self._cdx + self._cdy * self._cdy
        self._h0 = np.array(p.seg_heading_start)
        self._h1 = np.array(p.seg_heading_end)
        self._stop_i = np.array(p.stop_indices)
        self._stop_s = np.array(p.stop_s)
        self._stop_heading = np.array([p.stop_heading(k) for k in range(len(p.stop_s))])
        self._vertex_speed = np.array(vertex_turn_speeds(p, self.config))
        self._every = np.arange(n)
        cfg = self.config
        self._pids = _BatchedPIDs((cfg.pid_x, cfg.pid_y, cfg.pid_yaw), n)
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
        self._pids.reset(slice(None))

    @property
    def leg_count(self) -> int:
        return len(self._stop_s)

    # -- geometry (FieldPath's, over trials × segments) --------------------------------------
    def _segment_at(self, s: np.ndarray) -> np.ndarray:
        i = np.searchsorted(self._vs, s, side="right") - 1
        return np.minimum(np.maximum(i, 0), len(self._len) - 1)

    def _nearest(self, x: np.ndarray, y: np.ndarray, s_min: np.ndarray,
                 s_max: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """FieldPath.nearest: (arc length, distance) of the nearest point in [s_min, s_max]."""
        length = self.path.length
        s_min = np.minimum(np.maximum(s_min, 0.0), length)
        s_max = np.minimum(np.maximum(s_max, s_min), length)
        s_out, d_out = np.empty(len(x)), np.empty(len(x))
        _nearest_points(np.ascontiguousarray(x), np.ascontiguousarray(y), s_min, s_max, self._vs, self._ss,
                        self._sx, self._sy, self._dx, self._dy, self._len, s_out, d_out)
        return s_out, d_out

    def _furthest_intersection(self, x: np.ndarray, y: np.ndarray, r: float, s_lo: np.ndarray,
                               s_hi: np.ndarray) -> np.ndarray:
        """Largest arc length in [s_lo, s_hi] where the circle (x, y, r) meets the path; -1 if none.
        The segment end is taken as start + delta, then the start subtracted (as the reference)."""
        out = np.empty(len(x))
        lo, hi = (np.ascontiguousarray(v, dtype=float) for v in (s_lo, s_hi))
        _furthest_intersections(np.ascontiguousarray(x), np.ascontiguousarray(y), float(r), lo, hi, self._vs,
                                self._ss, self._sx, self._sy, self._ca, self._cdx, self._cdy, self._len, out)
        return out

    def _turn_speed_cap(self, progress: np.ndarray, stop_i: np.ndarray) -> np.ndarray:
        """Lowest speed over the vertices ahead, each plus what braking at a_max allows."""
        cfg = self.config
        L, a = cfg.lookahead_distance, cfg.max_linear_acceleration
        horizon = progress + L + cfg.max_linear_velocity ** 2 / (2.0 * a)
        k0 = np.maximum(1, np.searchsorted(self._vs, progress - 0.5 * L, side="right"))
        out = np.empty(len(progress))
        _turn_speed_caps(np.ascontiguousarray(progress), np.ascontiguousarray(stop_i, dtype=np.int64),
                         horizon, k0, float(L), float(a), self._vs, self._vertex_speed, out)
        return out

    # -- control ---------------------------------------------------------------------------
    def update(self, x: np.ndarray, y: np.ndarray, theta: np.ndarray, t_ns: int) -> np.ndarray:
        """(N, 3) body-frame commands (vx, vy, wz) for the poses (N,) measured at ``t_ns``."""
        x, y, theta = (np.asarray(v, dtype=float) for v in (x, y, theta))
        if x.shape != (self.n,) or y.shape != (self.n,) or theta.shape != (self.n,):
            raise ValueError(f"x, y, theta must have shape ({self.n},)")
        with np.errstate(over="ignore", invalid="ignore"):
            summed_finite = np.isfinite(x + y + theta).all()  # one test for the common case
        if not summed_finite:
            bad = np.flatnonzero(~(np.isfinite(x) & np.isfinite(y) & np.isfinite(theta)))
            if len(bad):
                i = int(bad[0])
                raise ValueError(f"pose must be finite, got ({x[i]}, {y[i]}, {theta[i]}) in trial {i}")
        out = np.zeros((self.n, 3))
        if self.done.any():
            self._last[self.done] = 0.0
            idx = np.flatnonzero(~self.done)
        else:
            idx = self._every
        if len(idx) == 0:
            return out
        cfg = self.config
        first = self._first[idx]
        self._first[idx] = False
        has, last_t = self._has_last_t[idx], self._last_t_ns[idx]
        later = has & (t_ns > last_t)
        dt = np.where(later, (t_ns - last_t) * 1e-9, 0.0)
        self._last_t_ns[idx] = np.where(~has | (t_ns > last_t), t_ns, last_t)
        self._has_last_t[idx] = True

        L = cfg.lookahead_distance
        window = cfg.search_window_factor * L
        m = len(idx)
        stop_i = np.zeros(m, dtype=np.int64)
        leg_end, ex, ey, d_end, s_near, stop_heading = np.zeros((6, m))
        looping = np.arange(m)  # positions in idx still in the leg loop
        while len(looping):
            j = idx[looping]
            leg = self.leg[j]
            si, le = self._stop_i[leg], self._stop_s[leg]
            xj, yj, tj = x[j], y[j], theta[j]
            # 1. progress: nearest point, forward only, inside the window
            prog = self.progress[j]
            s_hi = np.where(first[looping], le, np.minimum(le, prog + window))
            sn, dn = self._nearest(xj, yj, prog, s_hi)
            prog = np.maximum(prog, sn)
            self.progress[j] = prog
            self.cross_track_error[j] = dn
            de = _hypot(self._vx[si] - xj, self._vy[si] - yj)
            sh = self._stop_heading[leg]
            # 6. end of leg (holonomic: position and heading together)
            reached = (de <= cfg.goal_position_tolerance) & (le - prog <= L)
            self._position_reached[j] = reached
            advance = reached & (np.abs(wrap_angles(sh - tj)) <= cfg.goal_heading_tolerance)
            if not advance.any():  # the common case: every trial stays on its leg
                stop_i[looping], leg_end[looping], d_end[looping] = si, le, de
                ex[looping], ey[looping] = self._vx[si], self._vy[si]
                s_near[looping], stop_heading[looping] = sn, sh
                break
            stay = looping[~advance]
            k = ~advance
            stop_i[stay], leg_end[stay], d_end[stay] = si[k], le[k], de[k]
            ex[stay], ey[stay] = self._vx[si[k]], self._vy[si[k]]
            s_near[stay], stop_heading[stay] = sn[k], sh[k]
            ja = j[advance]
            self.progress[ja] = le[advance]
            self.target_s[ja] = le[advance]
            self.leg[ja] += 1
            self._position_reached[ja] = False
            self._pids.reset(ja)
            finished = ja[self.leg[ja] >= self.leg_count]
            self.done[finished] = True
            self._last[finished] = 0.0
            looping = looping[advance][self.leg[ja] < self.leg_count]

        live = ~self.done[idx]
        if not live.all():
            idx, first, dt = idx[live], first[live], dt[live]
            stop_i, leg_end, ex, ey = stop_i[live], leg_end[live], ex[live], ey[live]
            d_end, s_near, stop_heading = d_end[live], s_near[live], stop_heading[live]
            if len(idx) == 0:
                return out
        xi, yi, ti = x[idx], y[idx], theta[idx]
        prog = self.progress[idx]

        # 2. target point (monotonic in arc length)
        at_end = (d_end <= L) & (leg_end - prog <= window)
        s_t = leg_end.copy()
        seek = ~at_end
        if seek.any():
            hit = self._furthest_intersection(xi[seek], yi[seek], L, prog[seek],
                                              np.minimum(leg_end[seek], prog[seek] + window))
            s_t[seek] = np.where(hit < 0.0, s_near[seek], hit)
        ts = self.target_s[idx]
        ts = np.maximum(ts, s_t)
        end = ts >= leg_end
        ts = np.minimum(ts, leg_end)
        self.target_s[idx] = ts
        seg = self._segment_at(ts)
        s_c = _clamp(ts, 0.0, self.path.length)
        f = (s_c - self._vs[seg]) / self._len[seg]
        tx = np.where(end, ex, self._vx[seg] + f * self._dx[seg])
        ty = np.where(end, ey, self._vy[seg] + f * self._dy[seg])
        fh = _clamp(f, 0.0, 1.0)
        h0 = self._h0[seg]
        th = np.where(end, stop_heading, wrap_angles(h0 + fh * wrap_angles(self._h1[seg] - h0)))
        self.target[idx, 0], self.target[idx, 1], self.target_heading[idx] = tx, ty, th

        # 4. speed cap: approach ramp and braking to the leg end, turn profile ahead
        d_rem = np.maximum(leg_end - prog, d_end)
        v_cap = np.full(len(idx), cfg.max_linear_velocity)
        if cfg.slowdown_distance > 0.0:
            v_cap = np.minimum(v_cap, cfg.max_linear_velocity * d_rem / cfg.slowdown_distance)
        cap = np.minimum(np.minimum(v_cap, np.sqrt(2.0 * cfg.max_linear_acceleration * d_rem)),
                   self._turn_speed_cap(prog, stop_i))
        v_cap = np.maximum(cap, cfg.min_approach_velocity)

        # 3. command: three PIDs in the field frame (eq. 34), speed-capped
        u = self._pids.update(np.column_stack([tx, ty, th]), np.column_stack([xi, yi, ti]), t_ns, idx)
        ux, uy, wz = u[:, 0], u[:, 1], u[:, 2]
        wmax = cfg.max_angular_velocity
        wz = _clamp(wz, -wmax, wmax)
        speed = _hypot(ux, uy)
        over = speed > v_cap
        with np.errstate(divide="ignore", invalid="ignore"):  # speed 0 is never over the cap
            k = np.where(over, v_cap / speed, 1.0)
        ux, uy = ux * k, uy * k

        # 5. acceleration limits on the field-frame velocity
        last = self._last[idx]
        dvx, dvy = ux - last[:, 0], uy - last[:, 1]
        dv = _hypot(dvx, dvy)
        max_dv = cfg.max_linear_acceleration * dt
        lim = dv > max_dv
        k = np.where(lim, max_dv / np.where(lim, dv, 1.0), 1.0)
        ux = np.where(lim, last[:, 0] + dvx * k, ux)
        uy = np.where(lim, last[:, 1] + dvy * k, uy)
        dw = wz - last[:, 2]
        max_dw = cfg.max_angular_acceleration * dt
        wz = np.where(np.abs(dw) > max_dw, last[:, 2] + np.copysign(max_dw, dw), wz)
        self._last[idx, 0], self._last[idx, 1], self._last[idx, 2] = ux, uy, wz
        c, s = np.cos(ti), np.sin(ti)
        out[idx, 0] = c * ux + s * uy
        out[idx, 1] = -s * ux + c * uy
        out[idx, 2] = wz
        return out
