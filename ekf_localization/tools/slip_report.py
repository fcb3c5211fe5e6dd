"""Slip detection on recorded demo runs: its flags judged against the simulator's true slip, the
expected false-alarm count beside the observed one, and the error after a bump.

    python -m ekf_localization.tools.slip_report RUN_DIR [RUN_DIR ...] [--bump T] [--after 2.0]

Each RUN_DIR is an ``ekf_demo --joint-states driven`` or ``--drive swerve`` output (its ``bag``
and ``ekf_params.yaml``).
The bag is replayed with the run's parameters (slip detection as configured) and with every
input's ``slip_detection`` off. A flag (the wheels declared slipping) is **true** when the
simulator's true slip, the truth's body velocity less the velocity its wheels' actual speeds
imply (the JointState velocities, through the inverse of the wheel rows; a swerve: the largest
module's velocity vector less the truth's at its place), exceeds
``TRUE_SLIP_SPEED`` within ``JUDGE_WINDOW_S`` of it; otherwise it is a false alarm. With
``--bump T`` the position error ``--after`` seconds after T (the push of ``ekf_demo --bump``)
is printed for both replays, and whether a camera fix fell between the push's end and then.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.special import chdtrc

from ekf_localization.core.units import NS_PER_S, seconds_to_ns, stamp_to_ns
from ekf_localization.inputs.joint import driven_rows
from ekf_localization.inputs.slip import SlipCheck, expected_false_alarms
from ekf_localization.models.registry import MODELS

TOPIC_TRUTH, TOPIC_CAMERA, TOPIC_JOINTS = "/ground_truth/odom", "/camera/pose", "/joint_states"
TRUE_SLIP_SPEED = 0.1  # m/s: the body moves this much faster than its wheels say
JUDGE_WINDOW_S = (-0.5, 0.1)  # s around a flag in which the true slip is looked for
BUMP_DURATION_S = 0.3
POSE_COMPONENTS = 3  # x, y, yaw of a camera fix (its gate's χ² dof)


@dataclass
class RunSummary:
    """One run: its flags (stamps, ns), how many were false, the counts the expectation needs."""

    name: str
    flags: list[int]
    false_flags: int
    seconds: float
    wheel_rate_hz: float
    camera_fixes: int
    error_with: float = math.nan  # m, position error ``after`` s after the bump
    error_without: float = math.nan
    fix_in_window: bool = False


def _settings(run: Path, detection: bool):
    from ekf_localization.tools.replay import load_settings

    settings = load_settings(run / "ekf_params.yaml")
    if detection:
        return settings
    inputs = tuple(replace(i, settings=replace(i.settings, slip=None)) if getattr(i.settings, "slip", None)
                   else i for i in settings.config.inputs)
    return replace(settings, config=replace(settings.config, inputs=inputs))


def _flags(loc) -> list[int]:
    return sorted(t for c in loc.checks if isinstance(c, SlipCheck) for w in c.wheels.values()
                  for t in w.declared_ns)


def true_slip(bag: Path, config) -> tuple[np.ndarray, np.ndarray]:
    """(stamps, |true slip| m/s) at each JointState of the first slip-checked input: the truth's
    planar body velocity less the one the wheels' actual speeds imply (swerve modules: the
    largest module's, :func:`swerve_true_slip`)."""
    from ekf_localization.tools import bag_io

    inp = next(i for i in config.inputs if getattr(i.settings, "slip", None) is not None)
    s = inp.settings
    if s.steer_names:
        return swerve_true_slip(bag, s)
    spec = MODELS[config.model]
    H = driven_rows(spec, s)
    cols = [spec.state_fields.index(f) for f in (6, 7, 11) if f in spec.state_fields]
    M_inv = np.linalg.pinv(H[:, cols])
    truth = bag_io.read_odometry(bag, TOPIC_TRUTH)
    t_out, slip = [], []
    for m in bag_io.iter_messages(bag, [TOPIC_JOINTS]):
        msg = m.msg
        index = {n: k for k, n in enumerate(msg.name)}
        if len(msg.velocity) != len(msg.name) or not all(n in index for n in s.names):
            continue
        w = np.array([msg.velocity[index[n]] for n in s.names]) * s.signs
        v = np.zeros(3)
        v[[(6, 7, 11).index(spec.state_fields[c]) for c in cols]] = M_inv @ (s.wheel_radius * w)
        t = stamp_to_ns(msg.header.stamp)
        vt = [np.interp(t, truth.t_ns, truth.states[:, k]) for k in (3, 4)]
        t_out.append(t)
        slip.append(math.hypot(vt[0] - v[0], vt[1] - v[1]))
    return np.array(t_out, dtype=np.int64), np.array(slip)


def swerve_true_slip(bag: Path, settings) -> tuple[np.ndarray, np.ndarray]:
    """(stamps, m/s) per module-state message: the largest |uᵢ − A_i v| over the modules, uᵢ the
    module's velocity vector from its drive and steer joints (core.swerve_states, the message's
    velocities) and v the truth's body twist (the simulator's World.swerve.slip, plus a push)."""
    from dataclasses import replace as _replace

    from ekf_localization.core.swerve_states import SwerveSpeeds
    from ekf_localization.inputs.joint import read
    from ekf_localization.models.swerve import SwerveKinematics, module_vectors
    from ekf_localization.tools import bag_io

    speeds = SwerveSpeeds(_replace(settings, use_velocities=True))
    A = SwerveKinematics(settings.module_positions).module_rows
    truth = bag_io.read_odometry(bag, TOPIC_TRUTH)
    t_out, slip = [], []
    for m in bag_io.iter_messages(bag, [TOPIC_JOINTS]):
        sample, reason = speeds.update(read(m.msg))
        if sample is None or reason is not None:
            continue
        t = sample.stamp_ns
        v = np.array([np.interp(t, truth.t_ns, truth.states[:, k]) for k in (3, 4, 5)])
        rest = (module_vectors(sample.speeds, sample.angles) - A @ v).reshape(-1, 2)
        t_out.append(t)
        slip.append(float(np.max(np.hypot(rest[:, 0], rest[:, 1]))))
    return np.array(t_out, dtype=np.int64), np.array(slip)


def _error_at(traj, truth, t: int) -> float:
    k = int(np.argmin(np.abs(traj.t_ns - t)))
    x, y = (np.interp(traj.t_ns[k], truth.t_ns, truth.states[:, j]) for j in (0, 1))
    return math.hypot(traj.states[k, 0] - x, traj.states[k, 1] - y)


def summarise(run: Path, bump_s: float | None = None, after_s: float = 2.0) -> RunSummary:
    """Replay ``run``'s bag with and without slip detection (module docstring)."""
    from ekf_localization.tools import bag_io
    from ekf_localization.tools.replay import replay

    bag = run / "bag"
    on = _settings(run, True)
    res = replay(bag, on, "recorded")
    flags = _flags(res.localizer)
    t, slip = true_slip(bag, on.config)
    lo, hi = (seconds_to_ns(w) for w in JUDGE_WINDOW_S)
    false = sum(not np.any(slip[(t >= f + lo) & (t <= f + hi)] > TRUE_SLIP_SPEED) for f in flags)
    truth = bag_io.read_odometry(bag, TOPIC_TRUTH)
    cam_t, _ = bag_io.read_poses(bag, TOPIC_CAMERA)
    seconds = (truth.t_ns[-1] - truth.t_ns[0]) / NS_PER_S
    out = RunSummary(run.name, flags, false, seconds, len(t) / max(seconds, 1e-9), len(cam_t))
    if bump_s is not None:
        at = seconds_to_ns(bump_s + after_s)
        out.error_with = _error_at(res.trajectory(), truth, at)
        out.error_without = _error_at(replay(bag, _settings(run, False), "recorded").trajectory(), truth, at)
        start = seconds_to_ns(bump_s + BUMP_DURATION_S)
        out.fix_in_window = bool(np.any((cam_t > start) & (cam_t <= at)))
    return out


def expected_line(runs: list[RunSummary], run_dir: Path) -> tuple[str, float]:
    """The expected false-alarm count over ``runs`` (inputs.slip.expected_false_alarms)."""
    config = _settings(run_dir, True).config
    inp = next(i for i in config.inputs if getattr(i.settings, "slip", None) is not None)
    gates = [g for i in config.inputs if i is not inp for _, g in i.rejection_thresholds if math.isfinite(g)]
    seconds = sum(r.seconds for r in runs)
    rate = sum(r.wheel_rate_hz * r.seconds for r in runs) / max(seconds, 1e-9)
    tail = float(chdtrc(POSE_COMPONENTS, min(gates) ** 2)) if gates else 0.0
    fixes = sum(r.camera_fixes for r in runs)
    e = expected_false_alarms(inp.settings.slip, seconds, rate, camera_fixes=fixes, gate_tail=tail)
    parts = ", ".join(f"{k} {v:.2g}" for k, v in e.items() if k != "total")
    return (f"expected false alarms over {len(runs)} drive(s), {seconds:.0f} s, wheels at {rate:.0f} Hz: "
            f"{e['total']:.3g} ({parts}); observed: {sum(r.false_flags for r in runs)}"), e["total"]


def demo_lines(run: Path, bump_s: float | None) -> list[str]:
    """ekf_demo's report lines for a run whose EKF checks its wheels for slip (none otherwise)."""
    if not any(getattr(i.settings, "slip", None) for i in _settings(run, True).config.inputs):
        return []
    r = summarise(run, bump_s)
    lines = [f"slip flags: {len(r.flags)} (false alarms against the simulator's true slip: {r.false_flags}); "
             + expected_line([r], run)[0]]
    if bump_s is not None:
        lines.append(f"position error 2 s after the bump at {bump_s:g} s: with slip detection "
                     f"{r.error_with * 100:.1f} cm, without (the bag replayed, detection off) "
                     f"{r.error_without * 100:.1f} cm; a camera fix in those 2 s: "
                     f"{'yes' if r.fix_in_window else 'no'}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="slip_report", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path, help="ekf_demo output directories")
    ap.add_argument("--bump", type=float, default=None, metavar="T", help="the bump's start, s of sim time")
    ap.add_argument("--after", type=float, default=2.0, help="the error this long after the bump, s")
    args = ap.parse_args(argv)
    rows = [summarise(r, args.bump, args.after) for r in args.runs]
    print(f"{'run':<10}{'flags':>6}{'false':>6}{'s':>6}" + (
        f"{'error with':>12}{'without':>10}{'  camera fix in the ' + format(args.after, 'g') + ' s'}"
        if args.bump is not None else ""))
    for r in rows:
        line = f"{r.name:<10}{len(r.flags):>6}{r.false_flags:>6}{r.seconds:>6.1f}"
        if args.bump is not None:
            fix = "yes" if r.fix_in_window else "no"
            line += f"{r.error_with * 100:>10.1f}cm{r.error_without * 100:>8.1f}cm  {fix}"
        print(line)
    if args.bump is not None:
        fixed = [r for r in rows if r.fix_in_window]
        for label, keep in (("all", rows), ("with a camera fix in the window", fixed)):
            if keep:
                w = np.array([r.error_with for r in keep]) * 100
                wo = np.array([r.error_without for r in keep]) * 100
                print(f"{label} ({len(keep)}): error {args.after:g} s after the bump, with detection mean "
                      f"{w.mean():.1f} cm (max {w.max():.1f}), without mean {wo.mean():.1f} cm "
                      f"(max {wo.max():.1f})")
    print(expected_line(rows, args.runs[0])[0])
    return 0


if __name__ == "__main__":
    sys.exit(main())
