"""Fit ekf_node's noise parameters to recorded bags; write the tuned YAML and a consistency report.

    ekf_tune BAG [BAG ...] --params START.yaml --out DIR [--truth-topic T] [--holdout BAG]
             [--objective auto|truth|likelihood] [--jobs N] [--max-evals N]
             [--decades D] [--bound NAME=LO:HI ...] [--scale-start Q,R] [--node-name ekf_node]
             [--fit-timing] [--fit-command [--odometry-sampling instantaneous|interval_average]]

What is fitted and the objectives: :mod:`ekf_localization.tools.tuning`; the staged fit:
:mod:`ekf_localization.tools.tune_search` (docs/ekf_tune.md has the details and the measured
figures); the report: :mod:`ekf_localization.tools.tune_report`. This module reads the input
(bags, start YAML, options) and writes the output. ``--fit-command`` first identifies the
command latency and the drive's time constant from each bag (:mod:`ekf_localization.tools.command_fit`)
and starts the noise fit from their medians.

Writes DIR/tuned.yaml (config/ekf.yaml's format), DIR/report.md and its PNGs. Exit status 0;
2 on bad input (one line on stderr); 130 after Ctrl-C (the best configuration so far is written).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.measurements import N_FIELDS
from ekf_localization.inputs import KINDS
from ekf_localization.models.registry import MODELS
from ekf_localization.ros import extras
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml
from ekf_localization.tools import bag_io, command_fit
from ekf_localization.tools.replay import CONTROL_TOPIC, abs_topic, read_replay_input
from ekf_localization.tools.tune_report import write_report
from ekf_localization.tools.tune_search import Progress, Tuner
from ekf_localization.tools.tuning import (
    DEFAULT_DECADES,
    PROG,
    TIMING_DECADES,
    BagData,
    Problem,
    UsageError,
    effective_values,
    make_knobs,
    scaled_noise,
)

DEFAULT_TRUTH_TOPIC = "/ground_truth/odom"


# --- input checks -----------------------------------------------------------------------------

def load_bag(path: Path, config: EkfConfig, truth_topic: str | None) -> BagData:
    """Read a bag for tuning; UsageError if it is unreadable or lacks a configured topic."""
    if not path.exists():
        raise UsageError(f"no bag at {path}")
    try:
        types = bag_io.topic_types(path)
    except bag_io.BagError as exc:
        raise UsageError(str(exc)) from None
    missing = [f"{inp.name} ({abs_topic(inp.topic)})" for inp in config.inputs
               if abs_topic(inp.topic) not in types]
    if missing:
        raise UsageError(f"bag {path} has no messages for the configured input(s) " + ", ".join(missing)
                         + "; its topics: " + ", ".join(sorted(types)))
    truth = None
    if truth_topic is not None and abs_topic(truth_topic) in types:
        truth = bag_io.read_odometry(path, abs_topic(truth_topic))
    try:
        data = read_replay_input(path, config)
    except bag_io.BagError as exc:
        raise UsageError(str(exc)) from None
    if not data.events:
        raise UsageError(f"bag {path} has no messages on the configured input topics")
    return BagData(path, data, truth)


def _parse_factors(text: str) -> tuple[float, float]:
    try:
        q, r = (float(v) for v in text.split(","))
    except ValueError:
        q = r = math.nan
    if not (math.isfinite(q) and math.isfinite(r) and q > 0 and r > 0):
        raise UsageError(f"--scale-start {text!r}: expected Q_FACTOR,R_FACTOR, two finite numbers > 0")
    return q, r


def parse_bounds(items: list[str]) -> dict[str, tuple[float, float]]:
    out = {}
    for item in items:
        name, sep, rng = item.partition("=")
        lo_s, sep2, hi_s = rng.partition(":")
        try:
            lo, hi = float(lo_s), float(hi_s)
        except ValueError:
            lo = hi = math.nan
        if not (sep and sep2 and name) or not (math.isfinite(lo) and math.isfinite(hi)):
            raise UsageError(f"--bound {item!r}: expected NAME=LO:HI with finite numbers")
        if not (0.0 < lo < hi):
            raise UsageError(f"--bound {item!r} cannot be met: a variance needs 0 < LO < HI")
        out[name.strip()] = (lo, hi)
    return out


# --- output -----------------------------------------------------------------------------------

def write_tuned_yaml(path: Path, values: dict[str, Any], node_name: str, header: str) -> None:
    """The parameters as a ROS 2 params file (floats always with a decimal point or exponent)."""

    class _Dumper(yaml.SafeDumper):
        pass

    def _float(dumper, v: float):
        text = repr(float(v))
        if "e" in text and "." not in text.split("e")[0]:
            mant, exp = text.split("e")
            text = f"{mant}.0e{exp}"
        return dumper.represent_scalar("tag:yaml.org,2002:float", text)

    _Dumper.add_representer(float, _float)
    lines = [f"{node_name}:", "  ros__parameters:"]
    for key, value in values.items():
        if isinstance(value, list) and len(value) == N_FIELDS * N_FIELDS:  # a 15x15 matrix: 15 per line
            rows = [", ".join(_float(_Dumper(None), float(v)).value for v in value[i:i + N_FIELDS])
                    for i in range(0, len(value), N_FIELDS)]
            pad = " " * (len(key) + 7)
            lines.append(f"    {key}: [" + (",\n" + pad).join(rows) + "]")
            continue
        flow = None if isinstance(value, list) else False  # lists inline, as config/ekf.yaml writes them
        text = yaml.dump({key: value}, Dumper=_Dumper, sort_keys=False, default_flow_style=flow,
                         width=1_000_000, allow_unicode=True).rstrip("\n")
        lines.extend("    " + line for line in text.splitlines())
    path.write_text(header + "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bags", type=Path, nargs="+", metavar="BAG", help="bags to fit on")
    parser.add_argument("--params", type=Path, required=True, help="start configuration (ekf_node YAML)")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--node-name", default="ekf_node")
    parser.add_argument("--truth-topic", default=None,
                        help=f"ground-truth nav_msgs/Odometry topic (default {DEFAULT_TRUTH_TOPIC} "
                        "when present)")
    parser.add_argument("--objective", choices=("auto", "truth", "likelihood"), default="auto",
                        help="auto: truth when every bag has the truth topic, else likelihood")
    parser.add_argument("--holdout", type=Path, action="append", default=[],
                        help="a bag not fitted on, reported before/after")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes")
    parser.add_argument("--max-evals", type=int, default=60, help="replays of the bag set, at most")
    parser.add_argument("--decades", type=float, default=DEFAULT_DECADES,
                        help="default bounds: this many decades either side of each start value")
    parser.add_argument("--scale-start", default=None, metavar="Q_FACTOR,R_FACTOR",
                        help="multiply the start's process noise by Q_FACTOR and every input's variance "
                        "scale by R_FACTOR first (a deliberately bad start, e.g. 100,0.01)")
    parser.add_argument("--fit-timing", action="store_true",
                        help="also fit control_latency and the non-zero control_time_constant entries "
                        f"(±{TIMING_DECADES:g} decade)")
    parser.add_argument("--fit-command", action="store_true",
                        help="first identify control_latency and control_time_constant from each bag's "
                        "cmd_vel and odometry (output error of the drive response); the noise fit starts "
                        "from their medians (DIR/command_fit.md)")
    parser.add_argument("--odometry-sampling", choices=command_fit.SAMPLINGS, default="interval_average",
                        help="with --fit-command: the odometry twist is the velocity at its stamp "
                        "(instantaneous: the simulator's default) or the mean since the previous message "
                        "(interval_average: an encoder read out at a rate)")
    parser.add_argument("--separate-xy", action="store_true",
                        help="fit the x and y pose diffusion separately (default: one knob when the "
                        "start gives them the same value)")
    parser.add_argument("--bound", action="append", default=[], metavar="NAME=LO:HI",
                        help="bounds of one fitted parameter, e.g. odom0_variance_scale=0.1:100.0")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if extras.check(PROG, "rosbags"):
        return 2
    try:
        return _run(args)
    except UsageError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2


def _fit_command(args: argparse.Namespace, values: dict[str, Any],
                 config: EkfConfig) -> tuple[dict[str, Any], EkfConfig]:
    """The start values with control_latency and control_time_constant (vx, vy, vyaw) set to
    the medians of each bag's command fit; the table goes to stdout and DIR/command_fit.md."""
    if not config.use_control or config.model != "mecanum":
        raise UsageError("--fit-command needs use_control and the mecanum model")
    odom = next((i for i in config.inputs if KINDS[i.kind].message_type == "nav_msgs/msg/Odometry"), None)
    if odom is None:
        raise UsageError("--fit-command needs an odometry input (odomN) to compare the commands with")
    fits = []
    for bag in args.bags:
        try:
            data = command_fit.read_bag(bag, CONTROL_TOPIC, abs_topic(odom.topic))
        except (ValueError, bag_io.BagError) as exc:
            raise UsageError(str(exc)) from None
        fits.append(command_fit.fit_bag(data, config, args.odometry_sampling))
    latency, tau = command_fit.median_timing(fits)
    table = command_fit.table(fits)
    print(f"{PROG}: command fit ({args.odometry_sampling} odometry)\n{table}")
    (args.out / "command_fit.md").write_text(
        f"# Command fit ({args.odometry_sampling} odometry; docs/ekf_tune.md)\n\n{table}\n")
    out = dict(values)
    out["control_latency"] = latency
    out["control_time_constant"] = [tau if i in (0, 1, 5) else float(v)  # vx vy vyaw
                                    for i, v in enumerate(values["control_time_constant"])]
    return out, parse_ekf_config(out, MODELS)


def _run(args: argparse.Namespace) -> int:
    if args.jobs < 1 or args.max_evals < 1 or not (args.decades > 0):
        raise UsageError("--jobs and --max-evals must be >= 1 and --decades > 0")
    try:
        values = parameters_from_yaml(args.params, args.node_name)
        start_config = parse_ekf_config(values, MODELS)
    except ParameterError as exc:
        raise UsageError(f"start config {args.params} does not load: {exc}") from None
    values = effective_values(values, start_config)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.scale_start is not None:
        factors = _parse_factors(args.scale_start)
        values = scaled_noise(values, start_config, *factors)
        start_config = parse_ekf_config(values, MODELS)
        write_tuned_yaml(args.out / "start.yaml", values, args.node_name,
                         f"# ekf_tune: {args.params} with --scale-start {args.scale_start}\n")
    if args.fit_command:
        values, start_config = _fit_command(args, values, start_config)
    knobs = make_knobs(values, start_config, args.decades, parse_bounds(args.bound), args.fit_timing,
                       tie_position=not args.separate_xy)
    truth_topic = args.truth_topic or DEFAULT_TRUTH_TOPIC
    bags = [load_bag(b, start_config, truth_topic) for b in args.bags]
    holdouts = [load_bag(b, start_config, truth_topic) for b in args.holdout]
    objective = args.objective
    if objective == "auto":
        objective = "truth" if all(b.truth is not None for b in bags) else "likelihood"
    if objective == "truth":
        lacking = [str(b.path) for b in bags if b.truth is None]
        if lacking:
            raise UsageError(f"objective 'truth' needs {truth_topic} in every bag; missing in "
                             + ", ".join(lacking))
    elif args.truth_topic is not None and any(b.truth is None for b in bags):
        raise UsageError(f"--truth-topic {args.truth_topic} is not in every bag")
    problem = Problem(values, knobs, bags, objective)

    progress = Progress(args.max_evals)
    t0 = time.monotonic()
    interrupted = False
    tuner = Tuner(problem, args.jobs, args.max_evals, progress)
    try:
        with tuner:
            ended = tuner.run()
    except KeyboardInterrupt:
        interrupted = True
        ended = "interrupted (Ctrl-C): the best configuration so far"
    progress.close()
    seconds = time.monotonic() - t0
    best_values = problem.values_at(tuner.best_x)
    scaled = f" with --scale-start {args.scale_start}" if args.scale_start else ""
    header = (f"# ekf_tune: fitted from {', '.join(str(b) for b in args.bags)} starting from {args.params}"
              f"{scaled}\n"
              f"# objective {objective}, {tuner.evals} evaluations in {seconds:.1f} s, {ended}\n"
              f"# report: report.md next to this file (docs/ekf_tune.md explains it)\n")
    write_tuned_yaml(args.out / "tuned.yaml", best_values, args.node_name, header)
    print(f"{PROG}: {ended}; {tuner.evals} evaluations in {seconds:.1f} s, best objective {tuner.best_f:.5g}")
    print(f"{PROG}: wrote {args.out / 'tuned.yaml'}")
    if interrupted:
        return 130
    write_report(args.out, problem, tuner, holdouts, ended, seconds, args)
    print(f"{PROG}: wrote {args.out / 'report.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
