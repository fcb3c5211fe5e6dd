"""Slip and collision detection for driven-wheel odometry (no ROS imports).

A driven wheel (a mecanum or differential drive's own wheel, a swerve module) measures the
robot's motion only while it grips the floor. A wheel that spins, or a push by another robot
while the wheels keep their speeds, makes its odometry wrong with a bias, not with noise.
:class:`SlipCheck` is the Localizer's check across inputs (core.fusion_context.CrossCheck)
for every jointN input with ``slip_detection``. Each wheel message's update (H, z, R) is tested
against (docs/models.md, "Slip detection"):

1. **disagreement**: the wheels' weighted least-squares twist fit v̂ = (HᵀR⁻¹H)⁻¹HᵀR⁻¹z on the
   state's twist columns, and the residual χ² = (z − Hv̂)ᵀR⁻¹(z − Hv̂) with rows − rank(H)
   degrees of freedom (mecanum 4 − 3 = 1; a differential drive has none to spare);
2. **yaw rate**: the fitted yaw rate against the IMU's gyro over the same interval, less a
   gyro bias tracked while the wheels grip, χ²(1);
3. **acceleration**: the change of the fitted twist over ``slip_window`` (plus ω × v) against
   the IMU's mean acceleration over it, less a tracked bias, χ²(2) (an axis the wheels cannot
   resolve is left out; a state without vy does not slide: vy = 0);
4. **camera**: a run of ``slip_camera_run`` consecutive position fixes (any other input's update
   whose model depends on x or y: a camera's pose, tags) beyond their own rejection threshold
   (the robot is not where the wheels say).

Tests 1-3 fail when their χ² exceeds the quantile of ``slip_false_alarm_probability``, and the
wheels are declared slipping once a test has failed for ``slip_persistence`` (test 4: at the
run's last fix). Then the input's wheel updates are **refused** (REJECT_SLIP) until every test
has passed for ``slip_hold``; the input's ``SourceStats.slips`` counts the event, a WARN names
the input, and x and y get ``slip_pose_variance`` more variance (yaw ``slip_yaw_variance``) so
that the next camera fix is accepted rather than gated: once when the slip is found and once
when it ends (fixes during a push shrink the covariance while the push goes on).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import chdtri

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.fusion_context import FusionContext
from ekf_localization.core.measurements import REJECT_SLIP
from ekf_localization.core.part_plans import PartPlan
from ekf_localization.core.units import NS_PER_S, seconds_to_ns
from ekf_localization.inputs.kind import ParameterSpec

VX, VY, VYAW = 6, 7, 11  # robot_localization fields of the body twist the tests use
TESTS = ("disagreement", "yaw_rate", "acceleration", "camera")
IMU_KEEP_NS = 2 * NS_PER_S  # IMU samples kept for the windows
UNRESOLVED = 1e11  # a fitted twist component with a larger variance: the wheels do not see it


def _positive(v: float) -> bool:
    return math.isfinite(v) and v > 0.0


def _non_negative(v: float) -> bool:
    return math.isfinite(v) and v >= 0.0


SLIP_PARAMETERS = (
    ParameterSpec("slip_detection", "bool", False, "",
                  "check each wheel message for slip and collisions (driven-wheel geometries; "
                  "docs/models.md, Slip detection): refused while slipping, pose covariance widened"),
    ParameterSpec("slip_false_alarm_probability", "float", 1.0e-5, "",
                  "per test: its bound is the χ² quantile with this tail probability",
                  lambda v: 0.0 < v < 0.5, "a probability in (0.0, 0.5)"),
    ParameterSpec("slip_persistence", "float", 0.04, "s",
                  "a test must fail this long (consecutive messages) before the wheels are slipping",
                  _non_negative, "a time >= 0 s"),
    ParameterSpec("slip_hold", "float", 0.3, "s",
                  "the wheels grip again once every test has passed this long", _non_negative,
                  "a time >= 0 s"),
    ParameterSpec("slip_window", "float", 0.1, "s",
                  "the acceleration test compares velocity changes over this window", _positive,
                  "a time > 0 s"),
    ParameterSpec("slip_yaw_rate_variance", "float", 3.0e-4, "(rad/s)²",
                  "added to the yaw-rate test's variance (gyro scale error, wheel scrub)", _non_negative,
                  "a variance >= 0"),
    ParameterSpec("slip_acceleration_variance", "float", 0.1, "(m/s²)²",
                  "added to the acceleration test's variance per axis (vibration, a drive's jerk)",
                  _non_negative, "a variance >= 0"),
    ParameterSpec("slip_bias_time", "float", 10.0, "s",
                  "time constant of the gyro and accelerometer bias estimates (while the wheels grip)",
                  _positive, "a time > 0 s"),
    ParameterSpec("slip_camera_run", "float", 3.0, "",
                  "consecutive gated absolute pose fixes that mean slip (0: no camera test)",
                  lambda v: math.isfinite(v) and v >= 0.0 and v == int(v), "a whole number >= 0"),
    ParameterSpec("slip_pose_variance", "float", 0.25, "m²",
                  "added to x and y variance when slip is found (a push of up to ~2·sqrt(this))",
                  _non_negative, "a variance >= 0"),
    ParameterSpec("slip_yaw_variance", "float", 0.01, "rad²", "added to yaw variance when slip is found",
                  _non_negative, "a variance >= 0"),
)


@dataclass(frozen=True)
class SlipSettings:
    """An input's ``slip_*`` parameters (SLIP_PARAMETERS), times in ns."""

    false_alarm_probability: float = 1.0e-5
    persistence_ns: int = 40_000_000
    hold_ns: int = 300_000_000
    window_ns: int = 100_000_000
    yaw_rate_variance: float = 3.0e-4
    acceleration_variance: float = 0.1
    bias_time: float = 10.0
    camera_run: int = 3
    pose_variance: float = 0.25
    yaw_variance: float = 0.01

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> SlipSettings | None:
        """The settings of a jointN input's parsed values; None with ``slip_detection`` off."""
        if not values["slip_detection"]:
            return None
        return cls(values["slip_false_alarm_probability"], seconds_to_ns(values["slip_persistence"]),
                   seconds_to_ns(values["slip_hold"]), seconds_to_ns(values["slip_window"]),
                   values["slip_yaw_rate_variance"], values["slip_acceleration_variance"],
                   values["slip_bias_time"], int(values["slip_camera_run"]), values["slip_pose_variance"],
                   values["slip_yaw_variance"])

    def bound(self, dof: int) -> float:
        """The χ² a test with ``dof`` degrees of freedom must exceed to fail."""
        return float(chdtri(dof, self.false_alarm_probability))


def twist_fit(H: np.ndarray, z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Weighted least squares z = H v: (v̂, its covariance (HᵀR⁻¹H)⁻¹, residual χ², dof = rows −
    rank). H (m, k) on the twist only; columns it cannot resolve get v̂ = 0 and a huge variance."""
    L = np.linalg.cholesky(R)
    A = np.linalg.solve(L, H)  # whitened: A v = b, b ~ N(Av, I)
    b = np.linalg.solve(L, z)
    v, _, rank, _ = np.linalg.lstsq(A, b, rcond=None)
    r = b - A @ v
    C = np.linalg.pinv(A.T @ A)
    C[np.diag(C) == 0.0, np.diag(C) == 0.0] = 1e12
    return v, C, float(r @ r), int(H.shape[0] - rank)


class _Test:
    """One test's failing run: since when it has failed, and when it last failed."""

    def __init__(self) -> None:
        self.since: int | None = None
        self.last_fail: int | None = None

    def note(self, failed: bool | None, t: int) -> int:
        """Record a result (None: no result); how long it has failed (ns, -1: not failing)."""
        if failed is None:
            return -1 if self.since is None else t - self.since
        if not failed:
            self.since = None
            return -1
        self.last_fail = t
        if self.since is None:
            self.since = t
        return t - self.since


class WheelSlip:
    """One watched wheel input's tests and slip state."""

    def __init__(self, name: str, settings: SlipSettings, ctx: FusionContext) -> None:
        self.name, self.s, self._ctx = name, settings, ctx
        self._stats = ctx.stats[name]
        self._col = {f: ctx.field_to_state[f] for f in (VX, VY, VYAW) if f in ctx.field_to_state}
        self.declared_ns: list[int] = []  # when slip was declared (kept across resets: for tools)
        self.reset()

    def reset(self) -> None:
        self.tests = {t: _Test() for t in TESTS}
        self.slipping = False
        self._fits: deque[tuple[int, np.ndarray, np.ndarray]] = deque()  # (t, [vx vy w], cov 3x3)
        self._gyro_bias = 0.0
        self._accel_bias = np.zeros(2)
        self._run = 0
        self.last: dict[str, float] = {}  # each test's last χ² (for tools and tests)

    def _twist(self, H: np.ndarray, z: np.ndarray,
               R: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, int]:
        """The fit on the state's twist columns, as [vx vy w]: a component the wheels cannot resolve
        has a huge variance; a state without vy (a differential drive, which does not slide) has
        vy = 0 exactly."""
        fields = list(self._col)
        cols = [self._col[f] for f in fields]
        v, C, c2, dof = twist_fit(H[:, cols], z, R)
        idx = [(VX, VY, VYAW).index(f) for f in fields]
        v3, C3 = np.zeros(3), np.eye(3) * 1e12
        v3[idx] = v
        C3[np.ix_(idx, idx)] = C
        if VY not in self._col:
            C3[1, 1] = 0.0
        return v3, C3, c2, dof

    def check(self, plan: PartPlan, z: np.ndarray, R: np.ndarray, t: int, imu: ImuBuffer) -> str | None:
        H = getattr(plan.model, "H", None)
        if H is None or not (np.all(np.isfinite(z)) and np.all(np.isfinite(R))):
            return None
        try:
            v, C, c2, dof = self._twist(np.asarray(H, float), np.asarray(z, float), np.asarray(R, float))
        except np.linalg.LinAlgError:
            return None
        s, results = self.s, {}
        if dof > 0:
            self.last["disagreement"] = c2
            results["disagreement"] = c2 > s.bound(dof)
        prev_t = self._fits[-1][0] if self._fits else None
        self._fits.append((t, v, C))
        while len(self._fits) > 2 and self._fits[1][0] <= t - 2 * s.window_ns:
            self._fits.popleft()
        if C[2, 2] < UNRESOLVED and prev_t is not None:
            results["yaw_rate"] = self._yaw_rate(v[2], C[2, 2], prev_t, t, imu)
        results["acceleration"] = self._acceleration(t, imu)
        failing = [(name, self.tests[name].note(results.get(name), t)) for name in TESTS[:3]]
        if any(d >= s.persistence_ns for _, d in failing):
            self._declare(t, ", ".join(f"{n} χ² {self.last.get(n, math.nan):.1f}" for n, d in failing
                                       if d >= s.persistence_ns))
        elif self.slipping and all(tst.last_fail is None or t - tst.last_fail >= s.hold_ns
                                   for tst in self.tests.values()):
            self.slipping = False  # the motion while slipping is unknown: the next fix sets it
            self._widen(t)
        return REJECT_SLIP if self.slipping else None

    def _yaw_rate(self, w: float, w_var: float, t0: int, t: int, imu: ImuBuffer) -> bool | None:
        """Test 2 over the fit's interval (about the previous fit's stamp to this one's)."""
        half = (t - t0) // 2
        g = imu.mean(t - half, t + half)
        if g is None:
            return None
        rate, rate_var, _, _ = g
        r = w - (rate - self._gyro_bias)
        c2 = r * r / (w_var + rate_var + self.s.yaw_rate_variance)
        self.last["yaw_rate"] = c2
        failed = c2 > self.s.bound(1)
        if not failed and not self.slipping:
            self._gyro_bias += min(1.0, (t - t0) / NS_PER_S / self.s.bias_time) * (rate - w - self._gyro_bias)
        return failed

    def _acceleration(self, t: int, imu: ImuBuffer) -> bool | None:
        """Test 3: the fits' velocity change over the window against the IMU's mean acceleration."""
        old = [f for f in self._fits if f[0] <= t - self.s.window_ns]
        if not old:
            return None
        t0, v0, C0 = old[-1]
        _, v1, C1 = self._fits[-1]
        a = imu.mean(t0, t)
        if a is None:
            return None
        _, _, acc, acc_var = a
        T = (t - t0) / NS_PER_S
        w = 0.5 * (v0[2] + v1[2])
        wheels = (v1[:2] - v0[:2]) / T + w * np.array([-0.5 * (v0[1] + v1[1]), 0.5 * (v0[0] + v1[0])])
        r = acc - self._accel_bias - wheels
        axes = [k for k in (0, 1) if max(C0[k, k], C1[k, k]) < UNRESOLVED]
        if not axes:
            return None
        S = (C0[:2, :2] + C1[:2, :2]) / (T * T) + acc_var + self.s.acceleration_variance * np.eye(2)
        r, S = r[axes], S[np.ix_(axes, axes)]
        c2 = float(r @ np.linalg.solve(S, r))
        self.last["acceleration"] = c2
        failed = c2 > self.s.bound(len(axes))
        if not failed and not self.slipping:
            self._accel_bias += min(1.0, T / self.s.bias_time) * (acc - wheels - self._accel_bias)
        return failed

    def note_fix(self, gated: bool, t: int) -> None:
        """Test 4: an absolute pose fix, gated or not."""
        self._run = self._run + 1 if gated else 0
        self.tests["camera"].note(gated, t)
        if self.s.camera_run and self._run >= self.s.camera_run:
            self._declare(t, f"{self._run} camera fixes in a row beyond their gate")

    def _declare(self, t: int, why: str) -> None:
        if self.slipping:
            return
        self.slipping = True
        self.declared_ns.append(t)
        self._stats.slips += 1
        self._ctx.warn(f"{self.name}: wheel slip or collision ({why}): wheel speeds refused, pose "
                       "covariance widened")
        self._widen(t)

    def _widen(self, t: int) -> None:
        """x, y (and yaw) variances up by slip_pose_variance (slip_yaw_variance) from ``t`` on."""
        var = np.zeros(len(self._ctx.x_is_angle))
        for field, add in ((0, self.s.pose_variance), (1, self.s.pose_variance), (5, self.s.yaw_variance)):
            if field in self._ctx.field_to_state:
                var[self._ctx.field_to_state[field]] = add
        if np.any(var > 0.0):
            self._ctx.widen(self.name, var, t)


class ImuBuffer:
    """The IMU's recent gyro z and planar acceleration in base_link, with their variances."""

    def __init__(self) -> None:
        self._samples: deque[tuple[int, float, float, np.ndarray, np.ndarray]] = deque()

    def clear(self) -> None:
        self._samples.clear()

    def add(self, t: int, rate: float, rate_var: float, acc: np.ndarray, acc_cov: np.ndarray) -> None:
        if self._samples and t <= self._samples[-1][0]:
            if t < self._samples[-1][0] - IMU_KEEP_NS:  # a clock going back: start again
                self._samples.clear()
            else:
                return  # out of order: the windows take samples in stamp order
        self._samples.append((t, rate, rate_var, acc, acc_cov))
        while self._samples[0][0] < t - IMU_KEEP_NS:
            self._samples.popleft()

    def mean(self, t0: int, t1: int) -> tuple[float, float, np.ndarray, np.ndarray] | None:
        """Mean gyro z, its variance, mean acceleration [x y], its covariance over (t0, t1]; None
        without a sample there."""
        inside = [s for s in self._samples if t0 < s[0] <= t1]
        if not inside:
            return None
        n = len(inside)
        rate = sum(s[1] for s in inside) / n
        rate_var = sum(s[2] for s in inside) / (n * n)
        acc = sum(s[3] for s in inside) / n
        acc_cov = sum(s[4] for s in inside) / (n * n)
        return rate, rate_var, acc, acc_cov


class SlipCheck:
    """The Localizer's check across inputs for every watched wheel input (module docstring)."""

    def __init__(self, ctx: FusionContext) -> None:
        self._ctx = ctx
        self.wheels: dict[str, WheelSlip] = {}
        self.imu = ImuBuffer()
        self._xy = [ctx.field_to_state[f] for f in (0, 1) if f in ctx.field_to_state]

    def watch(self, name: str, settings: SlipSettings) -> WheelSlip:
        self.wheels[name] = WheelSlip(name, settings, self._ctx)
        return self.wheels[name]

    def reset(self) -> None:
        self.imu.clear()
        for w in self.wheels.values():
            w.reset()

    def note_imu(self, t: int, rate: float, rate_var: float, acc: np.ndarray, acc_cov: np.ndarray) -> None:
        """An IMU message's gyro z (rad/s) and [ax ay] (m/s²) in base_link, with (co)variances."""
        if math.isfinite(rate) and math.isfinite(rate_var) and np.all(np.isfinite(acc)) \
                and np.all(np.isfinite(acc_cov)):
            self.imu.add(t, float(rate), float(rate_var), np.asarray(acc, float), np.asarray(acc_cov, float))

    def check(self, source: str, plan: PartPlan, z: np.ndarray, R: np.ndarray, stamp_ns: int) -> str | None:
        wheel = self.wheels.get(source)
        if wheel is not None:
            return wheel.check(plan, z, R, stamp_ns, self.imu)
        if self.wheels and math.isfinite(plan.gate):
            gated = self._gated(plan, z, R, stamp_ns)
            if gated is not None:
                for w in self.wheels.values():
                    w.note_fix(gated, stamp_ns)
        return None

    def _gated(self, plan: PartPlan, z: np.ndarray, R: np.ndarray, t: int) -> bool | None:
        """Whether a position fix (an update whose model depends on x or y: a camera's pose, a tag)
        lies beyond its gate from the estimate at its stamp (None: not a position fix, or unknown)."""
        est = self._ctx.estimate_at(t)
        if est is None or not est.is_finite():
            return None
        x = est.state
        model = plan.model
        h = np.asarray(model.h(x[None]))[0]
        J = np.asarray(model.jacobian(x[None]))[0]
        if not self._xy or not np.any(J[:, self._xy]):
            return None
        y = np.asarray(z, float) - h
        ang = np.asarray(model.z_is_angle, bool)
        y[ang] = wrap_angles(y[ang])
        ok = np.isfinite(y)
        if not ok.any():
            return None
        S = (J @ est.covariance @ J.T + np.asarray(R, float))[np.ix_(ok, ok)]
        try:
            d2 = float(y[ok] @ np.linalg.solve(S, y[ok]))
        except np.linalg.LinAlgError:
            return None
        return d2 > plan.gate ** 2


def monitor(ctx: FusionContext) -> SlipCheck:
    """The context's one SlipCheck, registered in ``ctx.checks`` on first use."""
    for c in ctx.checks:
        if isinstance(c, SlipCheck):
            return c
    check = SlipCheck(ctx)
    ctx.checks.append(check)
    return check


def wanted(ctx: FusionContext) -> bool:
    """Whether any input of the context's configuration asks for slip detection."""
    return any(getattr(inp.settings, "slip", None) is not None for inp in ctx.config.inputs)


def expected_false_alarms(settings: SlipSettings, seconds: float, wheel_rate_hz: float,
                          disagreement_dof: int = 1, camera_fixes: int = 0, gate_tail: float = 0.0) -> dict:
    """Expected false slip declarations over ``seconds`` of driving without slip, per test.

    A per-message test (disagreement, yaw rate) at ``wheel_rate_hz`` declares slip after
    n = ⌊persistence · rate⌋ + 1 consecutive failures (at the mean rate); its messages are taken
    as independent, so it runs seconds · rate tests each failing a run with probability p^n. The
    acceleration test's overlapping windows are one independent test per window (a failure
    there persists over the window): seconds / window tests of probability p. The camera test:
    each of
    ``camera_fixes`` fixes starts a run of ``camera_run`` gated fixes with probability
    ``gate_tail``^run (the gate's χ² tail)."""
    p = settings.false_alarm_probability
    n = math.floor(settings.persistence_ns / NS_PER_S * wheel_rate_hz + 1e-9) + 1
    messages = seconds * wheel_rate_hz
    out = {"disagreement": messages * p ** n if disagreement_dof > 0 else 0.0,
           "yaw_rate": messages * p ** n,
           "acceleration": seconds / (settings.window_ns / NS_PER_S) * p,
           "camera": camera_fixes * gate_tail ** settings.camera_run if settings.camera_run else 0.0}
    out["total"] = sum(out.values())
    return out
