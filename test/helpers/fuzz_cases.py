"""Property-based fuzzing (hypothesis) of the Localizer, the message conversions and the parsers.

Shared by test/test_fuzz.py (a small budget in the suite) and benchmarks/fuzz.py (>= 10 000
cases). Each ``check_*`` function is one case; it raises AssertionError on a broken invariant:

* Localizer: random sequences of good driving, invalid and absurd messages, stale, future,
  zero and repeated stamps, resets, set_pose calls and clock jumps. No exception; every
  output finite with a symmetric positive-definite covariance; output stamps strictly
  increasing while the clock does not go back; the counters add up (per input: messages
  received = messages given; parts applied + rejected = the parts each call reported; per
  command and set_pose: applied + rejected = received); after 3 s of good data the estimate
  is back within 0.15 m of the truth.
* Conversions: any field values of the five input message types (NaN, inf, 1e300, denormals,
  any frame) convert without an exception and the Localizer rejects or fuses every part of
  them (counted as such), finitely.
* Parsing: any values for ekf_node, pure_pursuit_node and sim_node parameters give a config
  or the parser's own error (never another exception); the rcl pre-check never raises.
"""

from __future__ import annotations

import itertools
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
from hypothesis import strategies as st

from ekf_localization.core.localizer import CONTROL_SOURCE, SET_POSE_SOURCE, AddResult
from ekf_localization.core.measurements import (
    ControlCommand,
    ImuMeasurement,
    OdometryMeasurement,
    PoseMeasurement,
)
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml
from helpers.localizer_scenario import SEC, T0, Event, camera, drive, imu, odometry, position_error
from helpers.ros_helpers import REPO

STEP = 10_000_000

# --- values -----------------------------------------------------------------------------------

WILD = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e300, -1e300, 1e-300, 5e-324, 1e100, math.nan, math.inf, -math.inf]),
    st.floats(-10.0, 10.0))
FRAMES = st.sampled_from(["map", "odom", "base_link", "/map", "", "camera", "odom "])


EKF_YAML = parameters_from_yaml(REPO / "config" / "ekf.yaml")
CONFIG = parse_ekf_config(EKF_YAML | {"use_control": True}, MODELS)  # cmd_vel exercised too

# --- Localizer sequences ------------------------------------------------------------------------


@dataclass(frozen=True)
class Op:
    kind: str
    args: tuple


OPS = st.one_of(
    st.tuples(st.just("good"), st.floats(0.02, 1.0)),
    st.tuples(st.just("bad"), st.sampled_from(["odom0", "pose0", "imu0"]),
              st.lists(WILD, min_size=9, max_size=9), FRAMES,
              st.sampled_from(["now", "stale", "future", "far_future", "zero", "repeat"])),
    st.tuples(st.just("burst"), st.sampled_from(["odom0", "pose0", "imu0"]), WILD, st.integers(1, 20)),
    st.tuples(st.just("set_pose"), st.lists(WILD, min_size=3, max_size=3), FRAMES,
              st.sampled_from(["now", "zero", "old", "older_than_history", "future"]), WILD),
    st.tuples(st.just("control"), st.lists(WILD, min_size=3, max_size=3)),
    st.tuples(st.just("reset")),
    st.tuples(st.just("clock_back"), st.floats(0.01, 3.0)),
    st.tuples(st.just("gap"), st.sampled_from([0.5, 5.0, 100.0, 1e5])),
)
SEQUENCES = st.lists(OPS, min_size=1, max_size=8)


class _Run:
    """Feeds a Localizer, publishing at 50 Hz of clock time, and checks every output."""

    def __init__(self) -> None:
        self.loc = make_localizer(CONFIG)
        self.now = T0
        self.last_out: int | None = None
        self.next_out = T0
        self.outputs = 0
        self.seed = 0
        self.calls: Counter[str] = Counter()  # add_measurement calls per input, and commands, set_pose
        self.parts: Counter[str] = Counter()  # parts each add_measurement call reported per input

    def publish_until(self, t: int) -> None:
        while self.next_out <= t:
            est = self.loc.advance_to(self.next_out)
            if est is not None:
                check_estimate(est)
                assert self.last_out is None or est.stamp_ns > self.last_out, (est.stamp_ns, self.last_out)
                self.last_out = est.stamp_ns
                self.outputs += 1
            self.next_out += 20_000_000

    def feed(self, ev: Event) -> None:
        self.publish_until(ev.now_ns)
        result = self.loc.add_measurement(ev.source, ev.measurement, ev.now_ns)
        self.calls[ev.source] += 1
        self.parts[ev.source] += reported_parts(result)

    def call(self, source: str, method, *args) -> str | None:
        """``set_pose`` / ``add_control``: counted as one call of ``source``."""
        self.calls[source] += 1
        return method(*args)

    def check_counters(self) -> None:
        """The Localizer's counters against what it was given and what each call reported."""
        stats = self.loc.stats
        for source, n in self.calls.items():
            st = stats[source]
            assert st.received == n, (source, st.received, n)
            done = st.applied + st.rejected_total
            if source in (CONTROL_SOURCE, SET_POSE_SOURCE):
                assert done == n, (source, st.applied, dict(st.rejected), n)
            else:  # a rewind may turn a part from applied to gated, never drop or add one
                assert done == self.parts[source], (source, st.applied, dict(st.rejected), self.parts[source])
            assert all(v >= 0 for v in st.rejected.values()) and st.applied >= 0, (source, st)

    def good(self, seconds: float) -> None:
        self.seed += 1
        for ev in drive(seconds, seed=self.seed, start_ns=self.now):
            self.feed(ev)
        self.now += int(seconds * SEC) // STEP * STEP

    def advance_clock(self, to: int) -> None:
        """Time passes without data (the 50 Hz output in between is skipped: only the last one)."""
        self.now = max(self.now, to)
        self.next_out = max(self.next_out, self.now - 20_000_000)
        self.publish_until(self.now)

    def clock_back(self, seconds: float) -> None:
        self.now = max(STEP, self.now - int(seconds * SEC))
        self.last_out = None  # the output restarts with the clock
        self.next_out = self.now


def _stamp(run: _Run, how: str) -> int:
    return {"now": run.now, "stale": run.now - 3 * SEC, "future": run.now + 400_000_000,
            "far_future": run.now + 10 * SEC, "zero": 0, "repeat": run.now - STEP,
            "old": run.now - 300_000_000, "older_than_history": run.now - 900_000_000}[how]


def _bad_measurement(source: str, v: list[float], frame: str, stamp: int):
    cov6 = np.diag(np.abs(v[3:9])) if v[8] >= 0 else np.full((6, 6), v[8])
    if source == "odom0":
        return OdometryMeasurement(stamp, frame or "odom", "base_link", np.array(v[:6]), cov6,
                                   np.array(v[3:9]), cov6)
    if source == "pose0":
        return PoseMeasurement(stamp, frame, np.array(v[:6]), cov6)
    return ImuMeasurement(stamp, frame, np.array(v[:3]), cov6[:3, :3], np.array(v[3:6]), cov6[3:, 3:],
                          np.array(v[6:9]), np.full((3, 3), v[8]))


def check_sequence(ops: list, settle: bool = True) -> _Run:
    """One Localizer case: the ops, then 3 s of good data; see the module docstring. Without
    ``settle``, the ops only (every invariant but the return to the truth: ten times faster)."""
    run = _Run()
    run.good(0.5 if settle else 0.1)
    for op in ops:
        kind = op[0]
        if kind == "good":
            run.good(op[1])
        elif kind == "bad":
            _, source, v, frame, how = op
            run.feed(Event(source, _bad_measurement(source, v, frame, _stamp(run, how)), run.now))
        elif kind == "burst":
            _, source, value, n = op
            for k in range(n):
                t = run.now + k * 1_000_000
                meas = {"odom0": odometry(t, value, 0.0, value), "pose0": camera(t, value, value, 0.0),
                        "imu0": imu(t, 0.0, value)}[source]
                run.feed(Event(source, meas, t))
            run.advance_clock(run.now + n * 1_000_000)
        elif kind == "set_pose":
            _, v, frame, how, var = op
            xyyaw = np.array([v[0], v[1], 0.0, 0.0, 0.0, v[2]])
            pose = PoseMeasurement(_stamp(run, how), frame, xyyaw, np.diag(np.full(6, var)))
            run.call(SET_POSE_SOURCE, run.loc.set_pose, pose, run.now)
        elif kind == "control":
            twist = np.array([op[1][0], op[1][1], 0.0, 0.0, 0.0, op[1][2]])
            run.call(CONTROL_SOURCE, run.loc.add_control, ControlCommand(run.now, twist), run.now)
        elif kind == "reset":
            run.loc.reset("fuzz")
        elif kind == "clock_back":
            run.clock_back(op[1])
        elif kind == "gap":
            run.advance_clock(run.now + int(op[1] * SEC))
        run.check_counters()
    if not settle:
        return run
    run.good(3.0)
    run.check_counters()
    est = run.loc.advance_to(run.now)
    if est is None:  # nothing new since the last output at this very time
        est = run.loc.estimate_at(run.now)
    assert est is not None
    check_estimate(est)
    err = position_error(est, run.now)
    assert err < 0.15, f"{err:.3f} m from the truth after 3 s of good data"
    return run


def reported_parts(result: AddResult) -> int:
    """How many parts one add_measurement call says it applied or rejected (a message rejected as a
    whole, e.g. for its stamp, is one)."""
    return len(result.applied) + len(result.rejected)


def check_estimate(est) -> None:
    """Finite, with a symmetric positive-definite covariance."""
    assert est.is_finite(), est
    P = est.covariance
    assert np.allclose(P, P.T, rtol=1e-9, atol=1e-12), P - P.T
    eig = np.linalg.eigvalsh(P)
    assert eig.min() > 0.0, eig


# --- message conversions ------------------------------------------------------------------------

def _fill(msg, values: list[float], frame: str, stamp: tuple[int, int]) -> None:
    """Every float field of ``msg`` (nested, arrays too) from ``values`` (cycled); frames, stamp."""
    it = itertools.cycle(values)

    def visit(m) -> None:
        for name, typ in m.get_fields_and_field_types().items():
            v = getattr(m, name)
            if typ == "double":
                setattr(m, name, next(it))
            elif typ.startswith("double[") or typ.startswith("sequence<double"):
                setattr(m, name, [next(it) for _ in range(len(v) if len(v) else 2)])
            elif typ == "string":
                setattr(m, name, frame)
            elif typ == "builtin_interfaces/Time":
                v.sec, v.nanosec = stamp
            elif typ == "sequence<string>":
                setattr(m, name, ["a", frame])
            elif hasattr(v, "get_fields_and_field_types"):
                visit(v)

    visit(msg)


MESSAGE_CASES = st.tuples(st.sampled_from(["odom", "pose", "twist", "imu", "joint"]),
                          st.lists(WILD, min_size=1, max_size=12), FRAMES,
                          st.tuples(st.integers(0, 2**31 - 1), st.integers(0, 999_999_999)))


def check_message(case) -> AddResult | None:
    from ekf_localization.ros.conversions import message_class, message_to_measurement

    kind, values, frame, stamp = case
    msg = message_class(kind)()
    _fill(msg, values, frame, stamp)
    meas = message_to_measurement(kind, msg)
    loc = make_localizer(CONFIG)
    source = {"odom": "odom0", "pose": "pose0", "imu": "imu0"}.get(kind)
    if source is None:  # no twist / joint input in config/ekf.yaml: converting is the case
        return
    now = stamp[0] * SEC + stamp[1]
    result = loc.add_measurement(source, meas, now)
    st = loc.stats[source]
    # every part is fused or rejected with a reason, and counted as the call said
    assert reported_parts(result) >= 1, result
    assert st.received == 1 and st.applied + st.rejected_total == reported_parts(result), (result, st)
    assert st.applied == len(result.applied), (result, st)
    est = loc.advance_to(now + STEP)
    if est is not None:
        check_estimate(est)
    return result


# --- parameter parsing --------------------------------------------------------------------------

ANY_VALUE = st.one_of(st.none(), st.booleans(), st.integers(-10, 10**6), WILD, st.text(max_size=8),
                      st.lists(st.one_of(st.booleans(), WILD, st.integers(-3, 3)), max_size=20))


def _names() -> tuple[list[str], list[str], list[str]]:
    from ekf_localization.ros.ekf_parameters import EKF_PARAMETERS
    from ekf_localization.ros.pure_pursuit_parameters import PURE_PURSUIT_PARAMETERS as PP
    from sim_robot.ros.sim_params import SIM_PARAMETERS as SIM

    ekf = sorted(EKF_PARAMETERS) + ["odom0", "odom0_config", "pose0", "pose0_config",
                                    "pose0_rejection_threshold", "imu0", "imu0_config", "odom0_queue_size",
                                    "bogus"]
    return ekf, sorted(PP), sorted(SIM)


EKF_NAMES, PP_NAMES, SIM_NAMES = _names()
PARAMETER_CASES = st.tuples(st.sampled_from(["ekf", "pure_pursuit", "sim"]),
                            st.dictionaries(st.sampled_from(sorted(set(EKF_NAMES + PP_NAMES + SIM_NAMES))),
                                            ANY_VALUE, max_size=6))


def check_parameters(case):
    """The node's config from the values, or the ParameterError the parser raised (anything else
    propagates)."""
    from ekf_localization.ros.params_file import value_problem
    from ekf_localization.ros.pure_pursuit_parameters import parse_settings
    from sim_robot.ros.sim_params import parse_parameters

    node, values = case
    for name, v in values.items():
        problem = value_problem(name, v)
        assert problem is None or name in problem
    if node == "ekf":
        parse, given = (lambda v: parse_ekf_config(EKF_YAML | v, MODELS)), EKF_NAMES
    elif node == "pure_pursuit":
        parse, given = parse_settings, PP_NAMES
    else:
        parse, given = parse_parameters, SIM_NAMES
    try:
        return parse({k: v for k, v in values.items() if k in given})
    except ParameterError as exc:
        assert str(exc), "a parameter error says what is wrong"
        return exc




def check_quick_sequence(ops: list) -> _Run:
    """:func:`check_sequence` without the 3 s of good data at the end."""
    return check_sequence(ops, settle=False)
