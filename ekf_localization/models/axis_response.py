"""One axis of the drive response: the exact solution of dv/dt = sat((c − v)/τ) over a step
(models/drive_response.py's module docstring), with its derivative in v0. Shared by the per-axis,
wheel-space and swerve responses."""

from __future__ import annotations

import math

import numpy as np

_MAX_PHASES = 8  # at most: ramp, lag, cross zero, ramp, lag (a few spare)


def axis_response(v0: float, c: float, T: float, tau: float, acc: float, dec: float,
                  out: np.ndarray) -> None:
    """One axis over T seconds: out = [v(T), ∂v(T)/∂v0, ∫v dt, ∂(∫v dt)/∂v0].

    tau >= 0 (s); acc, dec > 0 (units/s², ``math.inf`` = no limit). Derivatives are carried
    through the phases in forward mode (a phase that ends at an event has a duration that
    depends on v0).
    """
    v = v0
    dv = 1.0
    t = T  # time left and its derivative
    dt = 0.0
    D = 0.0  # displacement and its derivative
    dD = 0.0
    at_lag_boundary = False
    for _ in range(_MAX_PHASES):
        if t <= 0.0:
            break
        e = c - v
        if e == 0.0 and tau <= 0.0:  # on the command, no lag: held there (a deviation is undone at once)
            D += c * t
            dD += c * dt
            dv = 0.0
            t = 0.0
            break
        sgn = 1.0 if e > 0.0 else -1.0
        shrinking = v != 0.0 and (v > 0.0) != (e > 0.0)  # |v| decreasing: decelerating
        limit = dec if shrinking else acc
        crosses = shrinking and c != 0.0 and (c > 0.0) != (v > 0.0)  # passes through v = 0
        if tau > 0.0 and (at_lag_boundary or abs(e) <= limit * tau):  # exponential approach
            at_lag_boundary = False
            if crosses:
                t_zero = tau * math.log(e / c)  # c - e·exp(-t/τ) = 0
                if t_zero < t:
                    dtz = -tau * dv / e
                    E = c / e
                    D += c * t_zero + (v - c) * tau * (1.0 - E)
                    dD += c * dtz + dv * tau * (1.0 - E) + (v - c) * E * dtz
                    v = 0.0
                    dv = 0.0
                    t -= t_zero
                    dt -= dtz
                    continue
            E = math.exp(-t / tau)
            dE = -E * dt / tau
            D += c * t + (v - c) * tau * (1.0 - E)
            dD += c * dt + dv * tau * (1.0 - E) + (v - c) * E * dt
            dv = dv * E - e * dE
            v = c - e * E
            t = 0.0
            break
        if limit == math.inf:  # τ = 0 and no limit: on the command at once (eq. 25)
            v = c
            dv = 0.0
            continue
        rate = sgn * limit  # ramp at the limit until the lag takes over, or v = 0
        v_end = c - sgn * limit * tau
        if crosses and -v * sgn < (v_end - v) * sgn:
            v_end = 0.0
        else:
            at_lag_boundary = tau > 0.0
        t_end = (v_end - v) / rate
        if t_end >= t:
            D += v * t + 0.5 * rate * t * t
            dD += dv * t + v * dt + rate * t * dt
            v += rate * t
            dv += rate * dt
            t = 0.0
            break
        dte = -dv / rate
        D += v * t_end + 0.5 * rate * t_end * t_end
        dD += dv * t_end + v * dte + rate * t_end * dte
        v = v_end
        dv = 0.0
        t -= t_end
        dt -= dte
    if t > 0.0:  # pragma: no cover - more phases than a lag with two limits can have
        D += v * t
        dD += dv * t + v * dt
    out[0] = v
    out[1] = dv
    out[2] = D
    out[3] = dD
