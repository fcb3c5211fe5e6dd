"""Pure pursuit for N robots on one path at once (holonomic mode), one compiled call per update.

The algorithm is :class:`~ekf_localization.control.pure_pursuit.PurePursuitFollower`'s
(the reference; docs/pure_pursuit.md), step for step: progress by the forward-only nearest
point, the furthest lookahead intersection as the target, the approach / braking / turn
speed caps, the three PIDs of seed 000 eq. 34-37, the acceleration limits and the leg ends.
The kernel runs the reference's scalar code per trial, every comparison and floating-point
expression in its order, with CPython's ``math.hypot`` (``core/hypot.py``: libm's differs
in the last bit), so the commands are the same to the last bit
(``test/test_batched_pure_pursuit.py``). Python's max/min become numba's (the same value
for finite inputs).

All trials share one clock (``update(x, y, theta, t_ns)`` with one ``t_ns``), as in a
Monte-Carlo loop. A trial that is done returns a zero twist and keeps its state, like the
reference. Differential mode stays with the per-trial follower.
"""

from __future__ import annotations

import math

import numpy as np

from ekf_localization.control.field_path import FieldPath
from ekf_localization.control.pure_pursuit import FollowerConfig, vertex_turn_speeds
from ekf_localization.core.kernels import compiled_entry, njit, py_hypot, source_stamp, wrap
from ekf_localization.core.units import NS_PER_S


@njit(cache=True, inline="always")
def _segment_at(vs: np.ndarray, s: float, n_segments: int) -> int:  # pragma: no cover - compiled
    """FieldPath.segment_at."""
    i = np.searchsorted(vs, s, side="right") - 1
    return min(max(i, 0), n_segments - 1)


@njit(cache=True, inline="always")
def _nearest_point(x, y, s_min, s_max, vs, ss, sx, sy, dx, dy, seg_len):  # pragma: no cover - compiled
    """FieldPath.nearest: (arc length, distance) of the nearest point in [s_min, s_max], its
    loop and arithmetic (s_min, s_max already clamped to the path)."""
    n = seg_len.shape[0]
    best = -1
    best_d2 = math.inf
    best_t = 0.0
    i = _segment_at(vs, s_min, n)
    while i < n and ss[i] <= s_max:
        L = seg_len[i]
        t_lo = max(0.0, (s_min - ss[i]) / L)
        t_hi = min(1.0, (s_max - ss[i]) / L)
        t = ((x - sx[i]) * dx[i] + (y - sy[i]) * dy[i]) / (L * L)
        t = min(max(t, t_lo), t_hi)
        px = sx[i] + t * dx[i]
        py = sy[i] + t * dy[i]
        d2 = (px - x) * (px - x) + (py - y) * (py - y)
        if best < 0 or d2 < best_d2:  # the first strict minimum
            best, best_d2, best_t = i, d2, t
        i += 1
    return ss[best] + best_t * seg_len[best], math.sqrt(best_d2)


@njit(cache=True, inline="always")
def _furthest_intersection(x, y, r, s_lo, s_hi, vs, ss, sx, sy, ca, cdx, cdy,
                           seg_len):  # pragma: no cover - compiled
    """Largest arc length in [s_lo, s_hi] where the circle (x, y, r) meets the path, -1 if
    none: the reference's circle test, with the segment end taken as start + delta and the
    start then subtracted (ca, cdx, cdy)."""
    n = seg_len.shape[0]
    best = -1.0
    i = _segment_at(vs, s_lo, n)
    while i < n and ss[i] <= s_hi:
        a = ca[i]
        fx = sx[i] - x
        fy = sy[i] - y
        hb = fx * cdx[i] + fy * cdy[i]  # half of the usual b
        c = fx * fx + fy * fy - r * r
        disc = hb * hb - a * c
        if disc >= -1e-12 * a * r * r and a != 0.0:
            root = math.sqrt(max(disc, 0.0))  # a tangent: one root, twice
            for t in ((-hb - root) / a, (-hb + root) / a):
                s = ss[i] + t * seg_len[i]
                if t >= 0.0 and t <= 1.0 and s >= s_lo and s <= s_hi and s > best:
                    best = s
        i += 1
    return best


@njit(cache=True, inline="always")
def _turn_speed_cap(progress, stop_i, L, a, brake, vs, vertex_speed):  # pragma: no cover - compiled
    """Lowest speed over the vertices ahead up to the braking horizon, each plus what braking
    at ``a`` allows (``brake`` = v_max² / 2a, computed in Python as the reference does)."""
    horizon = progress + L + brake
    best = math.inf
    k = max(1, np.searchsorted(vs, progress - 0.5 * L, side="right"))
    while k < stop_i and vs[k] <= horizon:
        v = vertex_speed[k]
        if v < math.inf:
            d = vs[k] - L - progress
            vd = math.sqrt(v * v + 2.0 * a * d) if d > 0.0 else v
            best = min(best, vd)
        k += 1
    return best


@njit(cache=True, inline="always")
def _pid_axis(b, c, setpoint, measurement, step, moved, dt, gains, integral, last_error,
              last_meas):  # pragma: no cover - compiled
    """PID.update (eq. 34-37) of axis c (x, y, or 2: yaw, angular) of trial b, in its order;
    gains rows: kp, ki, kd, integral limit, output limit. Returns the action."""
    error = setpoint - measurement  # eq. 35
    if c == 2:
        error = wrap(error)
    derivative = 0.0
    if step:
        new = integral[b, c] + error * dt  # eq. 36 with Δt, clamped (anti-windup)
        integral[b, c] = min(max(new, -gains[3, c]), gains[3, c])
        delta = measurement - last_meas[b, c]
        if c == 2:
            delta = wrap(delta)
        derivative = -(delta / dt)  # eq. 37 on the measurement
    if moved:
        last_meas[b, c] = measurement
    last_error[b, c] = error
    u = gains[0, c] * error + gains[1, c] * integral[b, c] + gains[2, c] * derivative  # eq. 34
    return min(max(u, -gains[4, c]), gains[4, c])


# rows of the follower kernel's float configuration (see BatchedPurePursuit.__init__)
(_L, _WINDOW, _POS_TOL, _HEADING_TOL, _V_MAX, _SLOWDOWN, _A_MAX, _BRAKE, _V_MIN, _W_MAX,
 _ALPHA_MAX, _LENGTH) = range(12)


def _make_follow(stamp: str):
    """The follower's update for every trial in one call (wraps and hypot from core.kernels:
    keyed by ``stamp``)."""

    @njit(cache=True)
    def follow(x, y, theta, t_ns, cfg, gains, vx, vy, vs, ss, sx, sy, dx, dy, seg_len, ca, cdx, cdy, h0,
               h1, stop_i, stop_s, stop_heading, vertex_speed, leg, progress, target_s, target,
               target_heading, cross_track, done, reached, last_t_ns, has_last_t, last, first,
               integral, last_error, pid_last_meas, pid_last_t_ns, pid_has_last,
               out):  # pragma: no cover - compiled
        """PurePursuitFollower.update (holonomic) per trial, its order and arithmetic; the
        three PIDs are PID.update (eq. 34-37). Writes the (N, 3) body twists into ``out``."""
        if len(stamp) < 0:  # never true: references the stamp so that it keys the cache
            return
        L = cfg[_L]
        window = cfg[_WINDOW]
        length = cfg[_LENGTH]
        n_seg = seg_len.shape[0]
        n_legs = stop_s.shape[0]
        for b in range(x.shape[0]):
            out[b, 0] = 0.0
            out[b, 1] = 0.0
            out[b, 2] = 0.0
            if done[b]:
                last[b, 0] = 0.0
                last[b, 1] = 0.0
                last[b, 2] = 0.0
                continue
            xb = x[b]
            yb = y[b]
            tb = theta[b]
            is_first = first[b]
            first[b] = False
            has = has_last_t[b]
            lt = last_t_ns[b]
            dt = (t_ns - lt) * 1e-9 if has and t_ns > lt else 0.0
            if not has or t_ns > lt:
                last_t_ns[b] = t_ns
            has_last_t[b] = True
            while True:  # 1. progress, 6. end of leg (holonomic: position and heading together)
                lg = leg[b]
                si = stop_i[lg]
                le = stop_s[lg]
                prog = progress[b]
                s_hi = le if is_first else min(le, prog + window)
                s_min = min(max(prog, 0.0), length)
                s_max = min(max(s_hi, s_min), length)
                sn, dn = _nearest_point(xb, yb, s_min, s_max, vs, ss, sx, sy, dx, dy, seg_len)
                prog = max(prog, sn)
                progress[b] = prog
                cross_track[b] = dn
                de = py_hypot(vx[si] - xb, vy[si] - yb)
                sh = stop_heading[lg]
                at = de <= cfg[_POS_TOL] and le - prog <= L
                reached[b] = at
                if not (at and abs(wrap(sh - tb)) <= cfg[_HEADING_TOL]):
                    break
                progress[b] = le
                target_s[b] = le
                leg[b] = lg + 1
                reached[b] = False
                for c in range(3):
                    integral[b, c] = 0.0
                    last_error[b, c] = 0.0
                pid_has_last[b] = False
                if lg + 1 >= n_legs:
                    done[b] = True
                    last[b, 0] = 0.0
                    last[b, 1] = 0.0
                    last[b, 2] = 0.0
                    break
            if done[b]:
                continue
            prog = progress[b]
            ex = vx[si]
            ey = vy[si]
            # 2. target point (monotonic in arc length)
            s_t = le
            if not (de <= L and le - prog <= window):
                hit = _furthest_intersection(xb, yb, L, prog, min(le, prog + window), vs, ss, sx, sy,
                                             ca, cdx, cdy, seg_len)
                s_t = sn if hit < 0.0 else hit
            ts = max(target_s[b], s_t)
            end = ts >= le
            ts = min(ts, le)
            target_s[b] = ts
            seg = _segment_at(vs, ts, n_seg)
            s_c = min(max(ts, 0.0), length)
            f = (s_c - vs[seg]) / seg_len[seg]
            if end:
                tx, ty, th = ex, ey, sh
            else:
                tx = sx[seg] + f * dx[seg]
                ty = sy[seg] + f * dy[seg]
                fh = min(max(f, 0.0), 1.0)
                th = wrap(h0[seg] + fh * wrap(h1[seg] - h0[seg]))
            target[b, 0] = tx
            target[b, 1] = ty
            target_heading[b] = th
            # 4. speed cap: approach ramp and braking to the leg end, turn profile ahead
            d_rem = max(le - prog, de)
            v_max = cfg[_V_MAX]
            v_cap = v_max
            if cfg[_SLOWDOWN] > 0.0:
                v_cap = min(v_cap, v_max * d_rem / cfg[_SLOWDOWN])
            cap = min(min(v_cap, math.sqrt(2.0 * cfg[_A_MAX] * d_rem)),
                      _turn_speed_cap(prog, si, L, cfg[_A_MAX], cfg[_BRAKE], vs, vertex_speed))
            v_cap = max(cap, cfg[_V_MIN])
            # 3. command: three PIDs in the field frame (eq. 34), speed-capped
            step = pid_has_last[b] and t_ns > pid_last_t_ns[b]  # the three PIDs share a clock
            moved = not pid_has_last[b] or t_ns > pid_last_t_ns[b]
            pdt = (t_ns - pid_last_t_ns[b]) / NS_PER_S if step else 0.0
            ux = _pid_axis(b, 0, tx, xb, step, moved, pdt, gains, integral, last_error, pid_last_meas)
            uy = _pid_axis(b, 1, ty, yb, step, moved, pdt, gains, integral, last_error, pid_last_meas)
            wz = _pid_axis(b, 2, th, tb, step, moved, pdt, gains, integral, last_error, pid_last_meas)
            if moved:
                pid_last_t_ns[b] = t_ns
            pid_has_last[b] = True
            w_max = cfg[_W_MAX]
            wz = min(max(wz, -w_max), w_max)
            speed = py_hypot(ux, uy)
            if speed > v_cap:
                k = v_cap / speed
                ux = ux * k
                uy = uy * k
            # 5. acceleration limits on the field-frame velocity
            dvx = ux - last[b, 0]
            dvy = uy - last[b, 1]
            dv = py_hypot(dvx, dvy)
            max_dv = cfg[_A_MAX] * dt
            if dv > max_dv:
                k = max_dv / dv
                ux = last[b, 0] + dvx * k
                uy = last[b, 1] + dvy * k
            dw = wz - last[b, 2]
            max_dw = cfg[_ALPHA_MAX] * dt
            if abs(dw) > max_dw:
                wz = last[b, 2] + math.copysign(max_dw, dw)
            last[b, 0] = ux
            last[b, 1] = uy
            last[b, 2] = wz
            c = math.cos(tb)
            s = math.sin(tb)
            out[b, 0] = c * ux + s * uy
            out[b, 1] = -s * ux + c * uy
            out[b, 2] = wz

    return follow


_follow = _make_follow(source_stamp(__file__))


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
        cfg = self.config
        self._cfg = np.array((  # in the order of the _L, _WINDOW, ... rows
            cfg.lookahead_distance, cfg.search_window_factor * cfg.lookahead_distance,
            cfg.goal_position_tolerance, cfg.goal_heading_tolerance, cfg.max_linear_velocity,
            cfg.slowdown_distance, cfg.max_linear_acceleration,
            cfg.max_linear_velocity ** 2 / (2.0 * cfg.max_linear_acceleration),  # as the reference
            cfg.min_approach_velocity, cfg.max_angular_velocity, cfg.max_angular_acceleration, p.length))
        gains = (cfg.pid_x, cfg.pid_y, cfg.pid_yaw)
        self._gains = np.array([[getattr(g, a) for g in gains]
                                for a in ("kp", "ki", "kd", "integral_limit", "output_limit")])
        self.reset()
        self._constants = (self._cfg, self._gains, self._vx, self._vy, self._vs, self._ss, self._sx, self._sy,
                           self._dx, self._dy, self._len, self._ca, self._cdx, self._cdy, self._h0, self._h1,
                           self._stop_i, self._stop_s, self._stop_heading, self._vertex_speed)
        z = np.zeros(n)
        self._follow = compiled_entry(_follow, z, z, z, 0, *self._constants, *self._state(), np.zeros((n, 3)))

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
        # the three PIDs (x, y, yaw) per trial: reset together, so they share one clock
        self._integral = np.zeros((n, 3))
        self._last_error = np.zeros((n, 3))
        self._pid_last_measurement = np.zeros((n, 3))
        self._pid_last_t_ns = np.zeros(n, dtype=np.int64)
        self._pid_has_last = np.zeros(n, dtype=bool)

    def _state(self) -> tuple[np.ndarray, ...]:
        """The arrays the kernel updates in place, in its argument order."""
        return (self.leg, self.progress, self.target_s, self.target, self.target_heading,
                self.cross_track_error, self.done, self._position_reached, self._last_t_ns,
                self._has_last_t, self._last, self._first, self._integral, self._last_error,
                self._pid_last_measurement, self._pid_last_t_ns, self._pid_has_last)

    @property
    def leg_count(self) -> int:
        return len(self._stop_s)

    # -- control ---------------------------------------------------------------------------
    def update(self, x: np.ndarray, y: np.ndarray, theta: np.ndarray, t_ns: int) -> np.ndarray:
        """(N, 3) body-frame commands (vx, vy, wz) for the poses (N,) measured at ``t_ns``."""
        x, y, theta = (np.ascontiguousarray(v, dtype=float) for v in (x, y, theta))
        if x.shape != (self.n,) or y.shape != (self.n,) or theta.shape != (self.n,):
            raise ValueError(f"x, y, theta must have shape ({self.n},)")
        with np.errstate(over="ignore", invalid="ignore"):
            summed_finite = np.isfinite(x + y + theta).all()  # one test for the common case
        if not summed_finite:
            bad = np.flatnonzero(~(np.isfinite(x) & np.isfinite(y) & np.isfinite(theta)))
            if len(bad):
                i = int(bad[0])
                raise ValueError(f"pose must be finite, got ({x[i]}, {y[i]}, {theta[i]}) in trial {i}")
        out = np.empty((self.n, 3))
        self._follow(x, y, theta, int(t_ns), *self._constants, *self._state(), out)
        return out
