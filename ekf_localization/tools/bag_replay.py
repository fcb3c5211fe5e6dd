"""Run the EKF offline over a bag, with the same YAML as ekf_node, as fast as the CPU allows.

Reads rosbag2 (MCAP or sqlite3, e.g. recorded by `ros2 bag record` or `bag_recorder`) and
ROS 1 bags with `rosbags`, through :mod:`ekf_localization.tools.replay` (exactly the code
ekf_node runs, in the order the recorder received the messages, with the receive time as the
filter's clock); the RMSE table and plots are :mod:`ekf_localization.tools.report`.

Output times: by default the stamps of the ``/odometry/filtered`` messages recorded in the
bag (so the replay can be compared one-to-one with the online node), else a grid at the
YAML's ``frequency``. Writes ``filtered.csv``, a bag with the replayed ``/odometry/filtered``,
the RMSE table when a ground-truth topic exists, and plots.

    bag_replay BAG [--params config/ekf.yaml] [--node-name ekf_node] [--out output/replay]
               [--set NAME=VALUE ...] [--truth-topic /ground_truth/odom] [--grid] [--report]
               [--html OUT.html [--field-params config/sim.yaml]]

``--html OUT.html`` writes the field view of the replay (docs/field_view.md) as one
self-contained HTML file with a time slider.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from ekf_localization.control.field_path import config_dir
from ekf_localization.core.localizer import Estimate
from ekf_localization.core.units import ns_to_sec_nanosec
from ekf_localization.ros import extras
from ekf_localization.ros.conversions import odometry_arrays
from ekf_localization.ros.parameters import ParameterError
from ekf_localization.tools import bag_io
from ekf_localization.tools.consistency import NEES_SAMPLES_PER_SECOND, InnovationLog
from ekf_localization.tools.evaluation import Trajectory
from ekf_localization.tools.replay import (
    OUTPUT_TOPIC,
    ReplayResult,
    abs_topic,
    load_settings,
    missing_inputs,
    replay,
)
from ekf_localization.tools.report import write_report


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


def report(bag: Path, result: ReplayResult, out: Path, truth_topic: str,
           dead_reckoning_topic: str | None) -> str | None:
    """RMSE table and plots when the bag has ground truth. Returns the table or None."""
    types = bag_io.topic_types(bag)
    if abs_topic(truth_topic) not in types:
        return None
    truth = bag_io.read_odometry(bag, abs_topic(truth_topic))
    estimates = {"replayed EKF": result.trajectory()}
    plotted = ["replayed EKF"]
    if OUTPUT_TOPIC in types:
        estimates["recorded /odometry/filtered"] = bag_io.read_odometry(bag, OUTPUT_TOPIC)
    if dead_reckoning_topic and abs_topic(dead_reckoning_topic) in types:
        name = f"dead reckoning ({dead_reckoning_topic})"
        estimates[name] = bag_io.read_odometry(bag, abs_topic(dead_reckoning_topic))
        plotted.append(name)
    return write_report(out, truth, estimates, plotted, title=f"RMSE against {truth_topic}",
                        plot_title="Offline replay")


def write_consistency_report(out: Path, bag: Path, params: Path, result: ReplayResult,
                             innovations: InnovationLog, truth_topic: str) -> Path:
    """``out``/report.md: the consistency section (NIS per input, NEES with truth) of this replay."""
    from ekf_localization.tools.consistency import consistency_section, pose_nees

    nees = None
    if abs_topic(truth_topic) in bag_io.topic_types(bag):
        nees = pose_nees(result.trajectory(), bag_io.read_odometry(bag, abs_topic(truth_topic)))
    section = consistency_section(innovations.per_input(), nees, out, "consistency.png",
                                  "Consistency of the replay")
    path = out / "report.md"
    path.write_text(f"# bag_replay report\n\n- bag: `{bag}`\n- parameters: `{params}`\n\n"
                    "NIS: 95% band of the mean of K independent χ²(m) values; NEES: pose (x, y, θ), band "
                    f"counting {NEES_SAMPLES_PER_SECOND:g} independent samples per second "
                    "(docs/ekf_tune.md).\n\n" + section)
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
    parser.add_argument("--html", type=Path, default=None, metavar="OUT.html",
                        help="also write the field view of the replay as one self-contained HTML file "
                        "(time slider; docs/field_view.md)")
    parser.add_argument("--field-params", default="config/sim.yaml",
                        help="sim_node YAML whose field (wall images, ramp) --html draws")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if extras.check("bag_replay", "rosbags"):
        return 2
    params = args.params
    if params is None:
        params = config_dir() / "ekf.yaml"
    try:
        settings = load_settings(params, args.node_name, args.overrides)
        config = settings.config
    except ParameterError as exc:
        print(f"bag_replay: {exc}", file=sys.stderr)
        return 2
    try:
        missing = missing_inputs(args.bag, config)
        if missing is not None:
            print(f"bag_replay: {missing}", file=sys.stderr)
            return 2
        field = None
        if args.html is not None:
            from ekf_localization.tools.view_export import load_field

            field = load_field(args.field_params, "--field-params", "option")
        innovations = InnovationLog() if args.report or args.html is not None else None
        result = replay(args.bag, settings, "grid" if args.grid else "recorded",
                        innovation_listener=innovations)
    except (bag_io.BagError, ParameterError) as exc:
        print(f"bag_replay: {exc}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    traj = result.trajectory()
    rate = result.messages / result.seconds if result.seconds > 0 else float("inf")
    print(f"bag_replay: {result.messages} messages -> {len(traj)} estimates in {result.seconds:.2f} s "
          f"({rate:,.0f} msg/s)")
    if result.followed_log:
        print("  followed ekf_node's fusion log (the live filter's order and clock)"
              + (f"; {result.missing} fused messages are not in the bag (the recorder missed them): "
                 "from the first, the replay can differ from the live output" if result.missing else ""))
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
    table = report(args.bag, result, args.out, args.truth_topic, args.dead_reckoning_topic)
    if table:
        print()
        print(table)
        (args.out / "rmse.txt").write_text(table + "\n")
    plots = ", trajectory.png, errors.png" if table else ""
    if args.html is not None:
        from ekf_localization.tools.view_export import view_data, web_dir, write_html

        data = view_data(args.bag, config, result, innovations, field, args.truth_topic)
        write_html(args.html, data, web_dir(), title=f"ekf_localization replay of {args.bag.name}")
        plots += f", {args.html} ({len(data['frames'])} frames)"
    if args.report:
        path = write_consistency_report(args.out, args.bag, params, result, innovations, args.truth_topic)
        plots += f", {path.name}, consistency.png"
    print(f"\nwrote {args.out / 'filtered.csv'}, {out_bag}{plots}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
