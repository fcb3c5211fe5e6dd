"""Run the EKF offline over a bag, with the same YAML as ekf_node, as fast as the CPU allows.

Reads rosbag2 (MCAP or sqlite3, e.g. recorded by `ros2 bag record` or `bag_recorder`) and
ROS 1 bags with `rosbags`. Messages go through exactly the code ekf_node runs
(:mod:`ekf_localization.ros.conversions` -> :class:`ekf_localization.core.localizer.Localizer`),
in the order the recorder received them, with the receive time as the filter's clock.

Output times: by default the stamps of the ``/odometry/filtered`` messages recorded in the
bag (so the replay can be compared one-to-one with the online node), else a grid at the
YAML's ``frequency``. Writes ``filtered.csv``, a bag with the replayed ``/odometry/filtered``,
the RMSE table when a ground-truth topic exists, and plots.

    bag_replay BAG [--params config/ekf.yaml] [--node-name ekf_node] [--out output/replay]
               [--set NAME=VALUE ...] [--truth-topic /ground_truth/odom] [--grid] [--report]
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ekf_localization.core.config import (
    EkfConfig,
    ParameterError,
    parameters_from_yaml,
    parse_ekf_config,
    parse_parameter_value,
)
from ekf_localization.core.localizer import Estimate, Innovation, Localizer
from ekf_localization.core.stamps import ns_to_sec_nanosec, stamp_to_ns
from ekf_localization.core.units import METRES_PER_INCH
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.conversions import (
    control_from_message,
    feed_transforms,
    message_to_measurement,
    odometry_arrays,
)
from ekf_localization.tools import bag_io
from ekf_localization.tools.consistency import InnovationLog
from ekf_localization.tools.evaluation import Trajectory, errors, format_rmse_table, rmse

OUTPUT_TOPIC = "/odometry/filtered"
CONTROL_TOPIC = "/cmd_vel"
TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"


def _abs(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


@dataclass
class ReplayResult:
    estimates: list[Estimate] = field(default_factory=list)
    messages: int = 0
    seconds: float = 0.0
    localizer: Localizer | None = None

    def trajectory(self) -> Trajectory:
        """Planar trajectory [x y θ vx vy ω] with the (x, y, θ) covariance."""
        k = len(self.estimates)
        states = np.zeros((k, 6))
        covs = np.zeros((k, 3, 3))
        t = np.zeros(k, dtype=np.int64)
        for i, est in enumerate(self.estimates):
            pose, pcov, twist, _ = odometry_arrays(est)
            t[i] = est.stamp_ns
            states[i] = [pose[0], pose[1], pose[5], twist[0], twist[1], twist[5]]
            covs[i] = pcov[np.ix_([0, 1, 5], [0, 1, 5])]
        return Trajectory(t, states, covs)


def load_config(params: Path, node_name: str = "ekf_node", overrides: list[str] | None = None) -> EkfConfig:
    """The node's parameters from its YAML, with NAME=VALUE overrides (YAML syntax values)."""
    values = parameters_from_yaml(params, node_name)
    for item in overrides or []:
        name, sep, text = item.partition("=")
        if not sep or not name:
            raise ParameterError(item, "NAME=VALUE", item, what="--set")
        values[name.strip()] = parse_parameter_value(text)
    return parse_ekf_config(values, MODELS)


def missing_inputs(bag: Path | str, config: EkfConfig) -> str | None:
    """Why the bag cannot be replayed with ``config`` (none of its input topics), or None."""
    types = bag_io.topic_types(bag)
    wanted = [_abs(inp.topic) for inp in config.inputs] + ([CONTROL_TOPIC] if config.use_control else [])
    if any(t in types for t in wanted):
        return None
    has = ", ".join(sorted(types)) or "no topics"
    return (f"bag '{bag}' has none of the input topics of the parameters ({', '.join(wanted) or 'none'}); "
            f"expected a bag recording at least one of them (it has: {has})")


@dataclass(frozen=True, eq=False)
class ReplayInput:
    """A bag's input messages read and converted once, in receive order, for repeated replays.

    ``events``: (receive ns, input name, ``CONTROL_TOPIC`` or ``TF_TOPIC``, Measurement /
    ControlCommand / TF message, or None for an unreadable message). Valid for any config with
    the same input topics, kinds and ``use_control`` (``key``): only the noise may differ, as
    when tuning.
    """

    events: tuple[tuple[int, str, object], ...]
    recorded_stamps: tuple[int, ...]  # header stamps of the recorded output topic (may be empty)
    key: tuple
    static_transforms: tuple[object, ...] = ()  # /tf_static messages


def _input_key(config: EkfConfig) -> tuple:
    return (tuple((_abs(i.topic), i.name, i.kind) for i in config.inputs), config.use_control)


def read_replay_input(bag: Path | str, config: EkfConfig, output_topic: str = OUTPUT_TOPIC) -> ReplayInput:
    """Read the messages of ``config``'s inputs (and cmd_vel with ``use_control``) from ``bag``."""
    inputs = {_abs(inp.topic): inp for inp in config.inputs}
    types = bag_io.topic_types(bag)
    out_topic = _abs(output_topic)
    stamps: tuple[int, ...] = ()
    if out_topic in types:
        stamps = tuple(sorted({stamp_to_ns(m.msg.header.stamp)
                               for m in bag_io.iter_messages(bag, [out_topic])}))
    static_topics = [TF_STATIC_TOPIC] if TF_STATIC_TOPIC in types else []
    static = tuple(m.msg for m in bag_io.iter_messages(bag, static_topics))
    topics = [t for t in types if t in inputs or (config.use_control and t == CONTROL_TOPIC)
              or (t == TF_TOPIC and t not in inputs)]
    events = []
    for m in bag_io.iter_messages(bag, topics):
        now = m.log_time_ns
        if m.topic == TF_TOPIC and m.topic not in inputs:
            events.append((now, TF_TOPIC, m.msg))
            continue
        if m.topic == CONTROL_TOPIC and m.topic not in inputs:
            events.append((now, CONTROL_TOPIC, control_from_message(m.msg, now)))
            continue
        inp = inputs[m.topic]
        try:
            item = message_to_measurement(inp.kind, m.msg)
        except (AttributeError, TypeError, ValueError):
            item = None
        events.append((now, inp.name, item))
    return ReplayInput(tuple(events), stamps, _input_key(config), static)


def replay(bag: Path | str | ReplayInput, config: EkfConfig, output_stamps: str = "recorded",
           output_topic: str = OUTPUT_TOPIC, ties: str = "inputs_first",
           innovation_listener: Callable[[Innovation], None] | None = None) -> ReplayResult:
    """Feed the bag through a Localizer in receive order; collect estimates.

    ``bag``: a bag path, or a :class:`ReplayInput` read from one (to replay it many times).
    ``output_stamps``: "recorded" = at the header stamps of the ``output_topic`` messages in
    the bag, each taken when the bag's clock (receive times) reaches it, as the node's timer
    did (falls back to "grid" if there are none); "grid" = every 1/frequency of bag time.
    ``ties``: an input received in the same clock tick as an output is fused before
    ("inputs_first") or after ("outputs_first") that output; the online node's executor may
    have done either. ``innovation_listener`` receives every update's innovation.
    """
    if ties not in ("inputs_first", "outputs_first"):
        raise ValueError(f"ties must be 'inputs_first' or 'outputs_first', got {ties!r}")
    source = bag if isinstance(bag, ReplayInput) else read_replay_input(bag, config, output_topic)
    if source.key != _input_key(config):
        raise ValueError("the ReplayInput was read for other inputs or another use_control")
    loc = make_localizer(config)
    loc.innovation_listener = innovation_listener
    res = ReplayResult(localizer=loc)
    if output_stamps == "recorded" and not source.recorded_stamps:
        output_stamps = "grid"
    stamps = source.recorded_stamps if output_stamps == "recorded" else ()
    # /tf_static holds for all time (as in tf2): loaded before the first message; /tf in receive order
    for msg in source.static_transforms:
        feed_transforms(loc.transforms, msg, static=True)
    period = config.publish_period_ns
    next_grid: int | None = None
    k = 0
    t0 = time.perf_counter()

    def emit(t_ns: int) -> None:
        est = loc.advance_to(t_ns) if output_stamps == "grid" else loc.estimate_at(t_ns)
        if est is not None and est.is_finite():
            res.estimates.append(est)

    for now, name, item in source.events:
        if output_stamps == "grid":
            if next_grid is None:
                next_grid = now - now % period + period
            while next_grid <= now:
                emit(next_grid)
                next_grid += period
        else:  # the node's timer fired at these stamps before this message arrived
            while k < len(stamps) and (stamps[k] < now or (ties == "outputs_first" and stamps[k] == now)):
                emit(stamps[k])
                k += 1
        res.messages += 1
        if name == TF_TOPIC:
            feed_transforms(loc.transforms, item, static=False)
        elif name == CONTROL_TOPIC:
            loc.add_control(item, now)
        elif item is None:
            loc.stats[name].received += 1
            loc.stats[name].rejected["unreadable message"] += 1
        else:
            loc.add_measurement(name, item, now)
    for t in stamps[k:]:
        emit(t)
    res.seconds = time.perf_counter() - t0
    return res


def write_csv(path: Path, traj: Trajectory) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["stamp_ns", "x_m", "y_m", "yaw_rad", "vx_mps", "vy_mps", "wz_radps",
                    "x_variance", "y_variance", "yaw_variance"])
        for k in range(len(traj)):
            s = traj.states[k]
            c = traj.covariances[k]
            w.writerow([int(traj.t_ns[k]), *(f"{v:.9g}" for v in s),
                        f"{c[0, 0]:.9g}", f"{c[1, 1]:.9g}", f"{c[2, 2]:.9g}"])


def write_bag(path: Path, estimates: list[Estimate], frame_id: str, child_frame_id: str,
              topic: str = OUTPUT_TOPIC) -> None:
    """The replayed estimates as nav_msgs/Odometry in a new rosbag2 (MCAP)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from ekf_localization.core.angles import yaw_to_quaternion

    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection(topic, "nav_msgs/msg/Odometry", typestore=ts)
        for est in estimates:
            pose, pcov, twist, tcov = odometry_arrays(est)
            sec, nsec = ns_to_sec_nanosec(est.stamp_ns)
            qx, qy, qz, qw = yaw_to_quaternion(float(pose[5]))
            msg = T["nav_msgs/msg/Odometry"](
                header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                                frame_id=frame_id),
                child_frame_id=child_frame_id,
                pose=T["geometry_msgs/msg/PoseWithCovariance"](
                    pose=T["geometry_msgs/msg/Pose"](
                        position=T["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]),
                                                              z=float(pose[2])),
                        orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)),
                    covariance=pcov.ravel().astype(np.float64)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](
                        linear=T["geometry_msgs/msg/Vector3"](x=float(twist[0]), y=float(twist[1]),
                                                              z=float(twist[2])),
                        angular=T["geometry_msgs/msg/Vector3"](x=float(twist[3]), y=float(twist[4]),
                                                               z=float(twist[5]))),
                    covariance=tcov.ravel().astype(np.float64)))
            writer.write(conn, int(est.stamp_ns), ts.serialize_cdr(msg, "nav_msgs/msg/Odometry"))


def report(bag: Path, result: ReplayResult, config: EkfConfig, out: Path, truth_topic: str,
           dead_reckoning_topic: str | None) -> str | None:
    """RMSE table and plots when the bag has ground truth. Returns the table or None."""
    from ekf_localization.tools.plots import plot_errors, plot_trajectories

    types = bag_io.topic_types(bag)
    if _abs(truth_topic) not in types:
        return None
    truth = bag_io.read_odometry(bag, _abs(truth_topic))
    replayed = result.trajectory()
    rows = {"replayed EKF": rmse(replayed, truth)}
    series = {"replayed EKF": errors(replayed, truth)}
    estimates = {"replayed EKF": replayed}
    if OUTPUT_TOPIC in types:
        online = bag_io.read_odometry(bag, OUTPUT_TOPIC)
        rows["recorded /odometry/filtered"] = rmse(online, truth)
    if dead_reckoning_topic and _abs(dead_reckoning_topic) in types:
        dead = bag_io.read_odometry(bag, _abs(dead_reckoning_topic))
        rows[f"dead reckoning ({dead_reckoning_topic})"] = rmse(dead, truth)
        series["dead reckoning"] = errors(dead, truth)
        estimates["dead reckoning"] = dead
    table = format_rmse_table(rows, title=f"RMSE against {truth_topic}")
    t0 = truth.t_ns[0]
    plot_trajectories(out / "trajectory.png", truth, estimates, field_half_size=72 * METRES_PER_INCH,
                      title="Offline replay: truth vs estimates")
    sig = np.sqrt(np.clip(np.diagonal(replayed.covariances, axis1=1, axis2=2), 0, None))
    plot_errors(out / "errors.png", {k: ((t - t0) * 1e-9, e) for k, (t, e) in series.items()},
                sigmas={"replayed EKF": ((replayed.t_ns - t0) * 1e-9, sig)},
                title="Offline replay: error against ground truth")
    return table


def write_consistency_report(out: Path, bag: Path, params: Path, result: ReplayResult,
                             innovations: InnovationLog, truth_topic: str) -> Path:
    """``out``/report.md: the consistency section (NIS per input, NEES with truth) of this replay."""
    from ekf_localization.tools.consistency import consistency_section, pose_nees

    nees = None
    if _abs(truth_topic) in bag_io.topic_types(bag):
        nees = pose_nees(result.trajectory(), bag_io.read_odometry(bag, _abs(truth_topic)))
    section = consistency_section(innovations.per_input(), nees, out, "consistency.png",
                                  "Consistency of the replay")
    path = out / "report.md"
    path.write_text(f"# bag_replay report\n\n- bag: `{bag}`\n- parameters: `{params}`\n\n"
                    "NIS: 95% band of the mean of K independent χ²(m) values; NEES: pose (x, y, θ), band "
                    "counting one independent sample per second (docs/ekf_tune.md).\n\n" + section)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bag_replay", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bag", type=Path, help="rosbag2 directory (MCAP/sqlite3) or ROS 1 .bag file")
    parser.add_argument("--params", type=Path, default=None, help="ekf_node YAML (default: config/ekf.yaml)")
    parser.add_argument("--node-name", default="ekf_node", help="node section to read in the YAML")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="NAME=VALUE",
                        help="override a parameter, e.g. --set pose0_rejection_threshold=3.0")
    parser.add_argument("--out", type=Path, default=Path("output/replay"))
    parser.add_argument("--grid", action="store_true",
                        help="output at the YAML frequency instead of the recorded output stamps")
    parser.add_argument("--truth-topic", default="/ground_truth/odom")
    parser.add_argument("--dead-reckoning-topic", default="/odometry/dead_wheels")
    parser.add_argument("--report", action="store_true",
                        help="also write report.md: NIS per input over time against its χ² band, "
                        "and the pose NEES when the bag has ground truth (as ekf_tune's report)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    params = args.params
    if params is None:
        from ekf_localization.tools.demo import config_dir

        params = config_dir() / "ekf.yaml"
    try:
        config = load_config(params, args.node_name, args.overrides)
    except ParameterError as exc:
        print(f"bag_replay: {exc}", file=sys.stderr)
        return 2
    try:
        missing = missing_inputs(args.bag, config)
        if missing is not None:
            print(f"bag_replay: {missing}", file=sys.stderr)
            return 2
        innovations = InnovationLog() if args.report else None
        result = replay(args.bag, config, "grid" if args.grid else "recorded",
                        innovation_listener=innovations)
    except bag_io.BagError as exc:
        print(f"bag_replay: {exc}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    traj = result.trajectory()
    rate = result.messages / result.seconds if result.seconds > 0 else float("inf")
    print(f"bag_replay: {result.messages} messages -> {len(traj)} estimates in {result.seconds:.2f} s "
          f"({rate:,.0f} msg/s)")
    for name, st in result.localizer.stats.items():
        if st.received:
            rej = ", ".join(f"{k}: {v}" for k, v in st.rejected.items()) or "none"
            print(f"  {name:10s} received {st.received:6d}  rejected: {rej}")
    write_csv(args.out / "filtered.csv", traj)
    out_bag = args.out / "filtered_bag"
    if out_bag.exists():
        import shutil

        shutil.rmtree(out_bag)
    write_bag(out_bag, result.estimates, config.world_frame, config.base_link_frame)
    table = report(args.bag, result, config, args.out, args.truth_topic, args.dead_reckoning_topic)
    if table:
        print()
        print(table)
        (args.out / "rmse.txt").write_text(table + "\n")
    plots = ", trajectory.png, errors.png" if table else ""
    if innovations is not None:
        path = write_consistency_report(args.out, args.bag, params, result, innovations, args.truth_topic)
        plots += f", {path.name}, consistency.png"
    print(f"\nwrote {args.out / 'filtered.csv'}, {out_bag}{plots}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
