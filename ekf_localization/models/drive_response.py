"""How a drive's body velocity follows its commanded twist (a replacement for seed 000 eq. 25).

Seed 000 eq. 25 takes the commanded velocity as the next velocity. A real drive (and the
simulator, ``sim_robot/world/drives.py``) lags it: motors have an acceleration limit and a
response time. Per body axis (ẋ, ẏ, θ̇), independently, the velocity ``v`` obeys

    dv/dt = sat((c - v) / τ)

a first-order lag of time constant τ toward the command c whose rate is clipped to the
acceleration limit while |v| grows and to the deceleration limit while it shrinks. The
solution over a step T is computed exactly (piecewise: ramp at the limit, exponential
approach, the switch between the limits at v = 0), so T need not be small and ten 10 ms
steps equal one 100 ms step. τ = 0 with no limits is eq. 25 itself (v' = c).

The deviation of the true velocity from this response is an Ornstein-Uhlenbeck process of
stationary variance σ² (``velocity_variance``) and correlation time τ: its exact discrete
covariance over T for the velocity and the displacement it integrates (:func:`axis_noise`)
is independent of the step too; τ = 0 gives seed 000's per-step variance (eq. 26).

Everything here is plain scalar Python per trial (the response is piecewise: phases that end
at events); :class:`DriveResponse` holds and checks the parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ekf_localization.models.axis_response import axis_response
from ekf_localization.models.swerve import SwerveKinematics
from ekf_localization.models.swerve_response import swerve_modules, swerve_params

N_AXES = 3  # ẋ, ẏ, θ̇ (body frame)
# kernel parameter vector: τ, acceleration, deceleration, σ² per axis, then the wheel mode's
# [acceleration limit, speed limit, k, (k, 3) twist -> wheels, (3, k) wheels -> twist] (k = 0: per axis,
# or with more entries the swerve mode's, models/swerve_response.swerve_params)
N_AXIS_PARAMS = 4 * N_AXES


_REACHED = 1e-12  # rad/s: a wheel-speed error this small is the target reached (benchmarks/fuzz.py)

def axis_noise(T: float, tau: float, var: float, out: np.ndarray) -> None:
    """Exact covariance over T of an OU deviation (stationary variance var, time constant τ)
    and of the displacement it integrates: out = [Var(∫), Cov(∫, v), Var(v)].

    With white noise of density q = 2·var/τ driving dv/dt = -v/τ + w:
    Var(v) = var (1 - E²), Cov = var τ (1 - E)², Var(∫) = 2 var τ (T - 2τ(1 - E) + τ(1 - E²)/2),
    E = exp(-T/τ). τ = 0: Var(v) = var, nothing integrated (eq. 26's per-step variance).
    """
    if tau <= 0.0:
        out[0] = 0.0
        out[1] = 0.0
        out[2] = var
        return
    E = math.exp(-T / tau)
    om = -math.expm1(-T / tau)  # 1 - E, accurate for small T/τ
    om2 = om * (1.0 + E)  # 1 - E²
    out[2] = var * om2
    out[1] = var * tau * om * om
    # T - 2τ(1-E) + τ(1-E²)/2 cancels badly for T << τ: its series is T³/(3τ²) - T⁴/(4τ³) + ...
    x = T / tau
    if x < 1e-3:
        core = tau * x * x * x * (1.0 / 3.0 - x / 4.0 + x * x / 10.0)
    else:
        core = T - 2.0 * tau * om + 0.5 * tau * om2
    out[0] = 2.0 * var * tau * core


def body_response(v: np.ndarray, c: np.ndarray, T: float, params: np.ndarray,
                  out: np.ndarray) -> None:
    """The three axes: out (3, 4) rows of :func:`axis_response` for ẋ, ẏ, θ̇."""
    for a in range(N_AXES):
        axis_response(v[a], c[a], T, params[a], params[N_AXES + a], params[2 * N_AXES + a], out[a])


# --- a planar body [x y θ ẋ ẏ θ̇] with body-frame velocities (the mecanum state) ------------------

def body_axes(v: np.ndarray, c: np.ndarray, T: float, dp: tuple[float, ...], r: list[list[float]]) -> None:
    """Per-axis mode: r (3 rows of 8 floats) [v(T), ∫v dt, ∂v(T)/∂v0 (3), ∂∫/∂v0 (3)], diagonal
    derivatives."""
    tmp = [0.0] * 4
    for a in range(N_AXES):
        axis_response(v[a], c[a], T, dp[a], dp[N_AXES + a], dp[2 * N_AXES + a], tmp)
        r[a][0] = tmp[0]
        r[a][1] = tmp[2]
        for m in range(N_AXES):
            r[a][2 + m] = 0.0
            r[a][5 + m] = 0.0
        r[a][2 + a] = tmp[1]
        r[a][5 + a] = tmp[3]


def wheel_space(v: np.ndarray, c: np.ndarray, T: float, dp: tuple[float, ...], r: list[list[float]]) -> None:
    """Wheel mode (the simulator's drive, sim_robot/world/drives.py): the wheel targets are the
    command's wheel speeds scaled together to the speed limit; the wheels approach them along a
    straight line in wheel space (every wheel's error shrinks by the same factor), their largest
    error s following the lag τ with its rate clipped to the wheel acceleration limit. s obeys
    :func:`axis_response` toward 0; v(T) = c' - e0·s(T)/s0 with e0 = c' - v0 in the body frame."""
    tau = dp[0]
    acc = dp[12]
    limit = dp[13]
    k = int(dp[14])
    inv = dp[15:15 + 3 * k]  # (k, 3) row-major: body twist -> wheel speeds
    fwd = dp[15 + 3 * k:15 + 6 * k]  # (3, k) row-major: wheel speeds -> body twist
    c0, c1, c2 = c
    w = [inv[3 * j] * c0 + inv[3 * j + 1] * c1 + inv[3 * j + 2] * c2 for j in range(k)]  # the command's
    peak = max(0.0, *(abs(wj) for wj in w))
    scale = limit / peak if peak > limit else 1.0
    w = [scale * wj for wj in w]
    ce = [0.0] * 3  # the target the drive reaches: the command within the speed limit
    for i in range(3):
        acc_i = 0.0
        for j in range(k):
            acc_i += fwd[k * i + j] * w[j]
        ce[i] = acc_i
    e0 = [ce[0] - v[0], ce[1] - v[1], ce[2] - v[2]]
    s0 = 0.0
    jstar = 0
    for j in range(k):
        ej = abs(inv[3 * j] * e0[0] + inv[3 * j + 1] * e0[1] + inv[3 * j + 2] * e0[2])
        if ej > s0:
            s0 = ej
            jstar = j
    tmp = [0.0] * 4
    if s0 < _REACHED:  # the target is reached (a denormal s0 made s0 * s0 zero: a division by it)
        E = math.exp(-T / tau) if tau > 0.0 else 0.0
        for i in range(3):
            r[i][0] = ce[i]
            r[i][1] = ce[i] * T
            for m in range(3):
                r[i][2 + m] = E if i == m else 0.0
                r[i][5 + m] = (tau * (1.0 - E) if tau > 0.0 else 0.0) if i == m else 0.0
        return
    axis_response(s0, 0.0, T, tau, acc, acc, tmp)
    g = tmp[0] / s0
    dg = (tmp[1] * s0 - tmp[0]) / (s0 * s0)
    h = tmp[2] / s0
    dh = (tmp[3] * s0 - tmp[2]) / (s0 * s0)
    ejs = inv[3 * jstar] * e0[0] + inv[3 * jstar + 1] * e0[1] + inv[3 * jstar + 2] * e0[2]
    sigma = 1.0 if ejs > 0.0 else -1.0
    for i in range(3):  # ∂s0/∂v0 = -σ inv[j*]: ∂v/∂v0 = g I + σ g' e0 ⊗ inv[j*], ∂D/∂v0 alike
        r[i][0] = ce[i] - e0[i] * g
        r[i][1] = ce[i] * T - e0[i] * h
        for m in range(3):
            r[i][2 + m] = (g if i == m else 0.0) + sigma * dg * e0[i] * inv[3 * jstar + m]
            r[i][5 + m] = (h if i == m else 0.0) + sigma * dh * e0[i] * inv[3 * jstar + m]


def pose_step(th: float, dx: float, dy: float, dth: float, G: list[list[float]]) -> tuple[float, float]:
    """Field-frame displacement of a body displacement (dx, dy) while turning by dth from th.

    The body displacement is rotated by the mid-step heading and scaled by sinc(dth/2): the
    pose exponential, exact for a constant twist over the step at any step length (seed 000's
    eq. 22 rotates by the start heading: an error of first order in the step, which adds up over
    a path at 10 ms steps against the simulator's 1 ms ticks). G (2 rows of 4 floats) receives
    the derivatives of the displacement by (θ, dx, dy, dth).
    """
    h = 0.5 * dth
    if abs(h) < 1e-4:
        sc = 1.0 - h * h / 6.0
        dsc = -h / 3.0
    else:
        sh = math.sin(h)
        sc = sh / h
        dsc = (h * math.cos(h) - sh) / (h * h)
    phi = th + h
    c = math.cos(phi)
    s = math.sin(phi)
    rx = c * dx - s * dy
    ry = s * dx + c * dy
    G[0][0] = -sc * ry
    G[1][0] = sc * rx
    G[0][1] = sc * c
    G[0][2] = -sc * s
    G[1][1] = sc * s
    G[1][2] = sc * c
    G[0][3] = 0.5 * (dsc * rx - sc * ry)
    G[1][3] = 0.5 * (dsc * ry + sc * rx)
    return sc * rx, sc * ry


def step_of(dp: tuple[float, ...]):
    """The response of the parameter vector's mode: wheel space, swerve modules
    (models/swerve_response.py, which builds on :func:`axis_response`) or per axis."""
    if dp[14] > 0.0:
        return wheel_space
    if len(dp) > 15:
        return swerve_modules
    return body_axes


def planar_row(x: list[float], vx_c: float, vy_c: float, w_c: float, dt: float, dp: tuple[float, ...],
               r: list[list[float]], step=None) -> tuple[list[float], list[float]]:
    """A planar body [x y θ ẋ ẏ θ̇] (body-frame velocities, ``x`` as Python floats) driven by the
    response: f (6) and F (36, row-major) as Python floats; r is scratch (3 rows of 8 floats).

    Pose: x' = x + Exp(d) (:func:`pose_step`), θ' = θ + d_θ with d the exact body-frame
    displacement of the responding velocity; velocity: the response itself.
    """
    x0, x1, th, v0, v1, v2 = x
    (step or step_of(dp))([v0, v1, v2], [vx_c, vy_c, w_c], dt, dp, r)
    G = [[0.0] * 4, [0.0] * 4]
    r0, r1, r2 = r
    px, py = pose_step(th, r0[1], r1[1], r2[1], G)
    (g0, a0, b0, c0), (g1, a1, b1, c1) = G
    _, _, d00, d01, d02, s0, s1, s2 = r0  # ∂v/∂v0 and ∂∫/∂v0 of each axis
    _, _, d10, d11, d12, t0, t1, t2 = r1
    _, _, d20, d21, d22, w0, w1, w2 = r2
    return ([x0 + px, x1 + py, th + r2[1], r0[0], r1[0], r2[0]],
            [1.0, 0.0, g0,
             a0 * s0 + b0 * t0 + c0 * w0, a0 * s1 + b0 * t1 + c0 * w1, a0 * s2 + b0 * t2 + c0 * w2,
             0.0, 1.0, g1,
             a1 * s0 + b1 * t0 + c1 * w0, a1 * s1 + b1 * t1 + c1 * w1, a1 * s2 + b1 * t2 + c1 * w2,
             0.0, 0.0, 1.0, w0, w1, w2,
             0.0, 0.0, 0.0, d00, d01, d02,
             0.0, 0.0, 0.0, d10, d11, d12,
             0.0, 0.0, 0.0, d20, d21, d22])


def planar_f_and_jacobian(Xs: np.ndarray, V: np.ndarray, dt: float,
                          dp: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """f (N, 6) and F (N, 6, 6) of :func:`planar_row` per trial, each array built once from a
    flat list of the rows' Python floats (cheaper than filling arrays, or nested lists)."""
    r = [[0.0] * 8 for _ in range(3)]
    step = step_of(dp)
    f: list[float] = []
    F: list[float] = []
    for x, v in zip(Xs.tolist(), V.tolist(), strict=True):
        fb, Fb = planar_row(x, *v, dt, dp, r, step)
        f += fb
        F += Fb
    N = Xs.shape[0]
    return np.array(f).reshape(N, 6), np.array(F).reshape(N, 6, 6)


@lru_cache(maxsize=8)
def _axis_noises(dt: float, dp: tuple[float, ...]) -> tuple[list[float], ...]:
    """:func:`axis_noise` of the three axes over dt (the same for every state: found once per step)."""
    q = [[0.0] * 3 for _ in range(3)]
    for a in range(3):
        axis_noise(dt, dp[a], dp[9 + a], q[a])
    return tuple(q)


def planar_noise(Xs: np.ndarray, dt: float, dp: tuple[float, ...], pose_rate: np.ndarray) -> np.ndarray:
    """Per trial: the drive's exact OU noise (axis_noise) with the body-frame x, y terms
    rotated into the field frame, plus pose_variance_rate · dt on x, y, θ."""
    (qx, cx, vx), (qy, cy, vy), (qt, ct, vt) = _axis_noises(dt, dp)
    rx, ry, rt = (rate * dt for rate in pose_rate.tolist())
    flat: list[float] = []  # every trial's 36 entries, row-major: one array built from them
    for th in Xs[:, 2].tolist():
        c = math.cos(th)
        s = math.sin(th)
        # pose block R diag(q_x, q_y) Rᵀ, pose-velocity block R diag(c_x, c_y)
        xy = c * s * (qx - qy)
        x3, x4, y3, y4 = c * cx, -s * cy, s * cx, c * cy
        flat += (c * c * qx + s * s * qy + rx, xy, 0.0, x3, x4, 0.0,
                 xy, s * s * qx + c * c * qy + ry, 0.0, y3, y4, 0.0,
                 0.0, 0.0, qt + rt, 0.0, 0.0, ct,
                 x3, y3, 0.0, vx, 0.0, 0.0,
                 x4, y4, 0.0, 0.0, vy, 0.0,
                 0.0, 0.0, ct, 0.0, 0.0, vt)
    return np.array(flat).reshape(Xs.shape[0], 6, 6)


@dataclass(frozen=True)
class DriveResponse:
    """Parameters of the drive response, per body axis (ẋ, ẏ, θ̇).

    time_constant_s: τ of the lag, s (0 = no lag). acceleration_limit / deceleration_limit:
    m/s² for ẋ, ẏ and rad/s² for θ̇ (``math.inf`` = none). velocity_variance: stationary
    variance of the true velocity about the response, (m/s)² and (rad/s)². latency_ns:
    the drive responds this long after a command's stamp (applied by the Localizer).
    With ``module_positions`` the response is a swerve's (models/swerve_response.py): the
    modules turn at most ``steer_rate_limit`` and their speeds follow the ẋ axis's parameters.
    """

    time_constant_s: np.ndarray = field(default_factory=lambda: np.zeros(N_AXES))
    acceleration_limit: np.ndarray = field(default_factory=lambda: np.full(N_AXES, math.inf))
    deceleration_limit: np.ndarray = field(default_factory=lambda: np.full(N_AXES, math.inf))
    velocity_variance: np.ndarray = field(default_factory=lambda: np.zeros(N_AXES))
    latency_ns: int = 0
    wheels_from_twist: np.ndarray | None = None  # (k, 3): the wheel mode's inverse kinematics
    wheel_acceleration_limit: float = math.inf  # rad/s², wheel mode
    wheel_speed_limit: float = math.inf  # rad/s, wheel mode: targets scaled together below it
    steer_rate_limit: float = math.inf  # rad/s, swerve mode (models/swerve_response.py)
    module_positions: np.ndarray | None = None  # (n, 2) m: the swerve mode's modules

    def __post_init__(self) -> None:
        checks = (("time_constant_s", False, False), ("acceleration_limit", True, True),
                  ("deceleration_limit", True, True), ("velocity_variance", False, False))
        for name, positive, infinite in checks:
            v = np.array(getattr(self, name), dtype=float)
            if v.shape == ():
                v = np.full(N_AXES, float(v))
            ok = v.shape == (N_AXES,) and not np.any(np.isnan(v)) and (infinite or np.all(np.isfinite(v)))
            ok = ok and (np.all(v > 0.0) if positive else np.all(v >= 0.0))
            if not ok:
                what = "> 0 (inf = no limit)" if positive else ">= 0, finite"
                raise ValueError(f"{name} must be {N_AXES} values {what}, got {getattr(self, name)!r}")
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        if isinstance(self.latency_ns, bool) or not isinstance(self.latency_ns, int | np.integer) \
                or self.latency_ns < 0:
            raise ValueError(f"latency_ns must be a non-negative int, got {self.latency_ns!r}")
        for name in ("wheel_acceleration_limit", "wheel_speed_limit"):
            v = float(getattr(self, name))
            if not v > 0.0:
                raise ValueError(f"{name} must be > 0 (inf = no limit), got {v!r}")
        if self.wheels_from_twist is not None:
            M = np.array(self.wheels_from_twist, dtype=float)
            if M.ndim != 2 or M.shape[1] != N_AXES or M.shape[0] < 2 or not np.all(np.isfinite(M)):
                raise ValueError(f"wheels_from_twist must be a finite (k, 3) matrix, got {M!r}")
            if np.ptp(self.time_constant_s) != 0.0:
                raise ValueError("the wheel mode has one time constant: time_constant_s must be equal, "
                                 f"got {self.time_constant_s!r}")
            M.setflags(write=False)
            object.__setattr__(self, "wheels_from_twist", M)
        if self.module_positions is not None:
            if self.wheels_from_twist is not None:
                raise ValueError("module_positions (swerve mode) and wheels_from_twist (wheel mode) exclude "
                                 "each other")
            if not float(self.steer_rate_limit) > 0.0:
                raise ValueError("steer_rate_limit must be > 0 (inf = no limit), "
                                 f"got {self.steer_rate_limit!r}")
            object.__setattr__(self, "module_positions", SwerveKinematics(self.module_positions).positions)
        object.__setattr__(self, "_params", self._make_params())

    def _make_params(self) -> tuple[float, ...]:
        axes = [self.time_constant_s, self.acceleration_limit, self.deceleration_limit,
                self.velocity_variance]
        M = self.wheels_from_twist
        if M is None:
            p = np.concatenate([*axes, [math.inf, math.inf, 0.0]])
            if self.module_positions is not None:
                p = np.concatenate([p, swerve_params(self.steer_rate_limit, self.module_positions)])
        else:
            p = np.concatenate([*axes, [self.wheel_acceleration_limit, self.wheel_speed_limit, M.shape[0]],
                                M.ravel(), np.linalg.pinv(M).ravel()])
        return tuple(p.tolist())  # Python floats: the per-trial scalar code reads them one at a time

    @property
    def params(self) -> tuple[float, ...]:
        """τ, acceleration, deceleration, σ² per axis, then the wheel mode's limits and matrices
        (the flat vector the functions above read; computed once)."""
        return self._params  # type: ignore[attr-defined]

    def respond(self, v: np.ndarray, c: np.ndarray, dt: float) -> np.ndarray:
        """(3, 4): per axis [v(dt), ∂v/∂v0, ∫v dt, ∂∫/∂v0] from body velocity v toward command c
        (per-axis mode)."""
        out = np.empty((N_AXES, 4))
        body_response(np.ascontiguousarray(v, dtype=float), np.ascontiguousarray(c, dtype=float),
                      float(dt), self.params, out)
        return out

    def noise(self, dt: float) -> np.ndarray:
        """(3, 3): per axis [Var(∫), Cov(∫, v), Var(v)] over dt (:func:`axis_noise`)."""
        out = np.empty((N_AXES, 3))
        for a in range(N_AXES):
            axis_noise(float(dt), float(self.time_constant_s[a]), float(self.velocity_variance[a]), out[a])
        return out
