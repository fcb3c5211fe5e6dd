"""The closed-loop demo: sim_node + ekf_node + pure_pursuit_node as separate processes over DDS.

Wired only by the YAMLs in config/. Drives seed 000's test path (or the FTC cycle path for N
cycles), records every topic to a rosbag2 file, then prints the RMSE table of
/odometry/filtered and of dead reckoning against ground truth and writes the plots.

    ekf_demo [--drive mecanum|tank|swerve] [--sim-params FILE] [--path seed000|cycle] [--cycles N]
             [--rtf 1.0] [--out output/demo] [--storage mcap] [--camera poses|images] [--cameras 1|2]
             [--joint-states [dead|driven]] [--ramp] [--odom-dropout START:DURATION]
             [--bump T:DX:DY]
             [--view [--view-port 8765]]

``--drive``: seed 000's mecanum robot (the default), the tank, or the swerve, whose module states
the EKF fuses (tools/demo_drives.py); the swerve's table adds the modules' own dead reckoning.
``--sim-params FILE``: the simulated robot's YAML instead of the drive's config/sim*.yaml.

``--camera images``: the simulator renders the field's AprilTags and tag_localizer turns the
images into the camera poses ekf_node fuses (tools/demo_images.py); the report adds
``tag fixes: N accepted, M rejected``. ``--cameras 2``: a second camera facing backward
(config/sim.yaml ``camera1``; with images its own tag_localizer in namespace camera1), both fused
(config/ekf_two_cameras.yaml). ``--single-tag METHOD``: tag_localizer's ``single_tag`` instead of
config/tag_localizer.yaml's (``corners``: ekf_node gets a ``tag_cornersN`` per tag, demo_images.py).

``--joint-states``: the EKF reads the dead wheels as sensor_msgs/JointState (``joint_states``,
config/ekf_joint_states.yaml) instead of the odometry twist; ``--joint-states driven``: the
drive's own four wheels instead, quantised, at jittered intervals (sim.yaml's
``wheel_encoders``, config/ekf_driven_wheels.yaml); the table adds both inputs
replayed offline from the same bag, with their mean velocity standard deviations.
With the driven wheels or the swerve the notes add the slip flags (inputs/slip.py), judged
against the simulator's true slip, beside the expected false-alarm count (tools/slip_report.py).
``--bump T:DX:DY``: the simulator pushes the robot by (DX, DY) m over 0.3 s from sim time T while
its driven wheels or modules keep their speeds; the notes add the position error 2 s later, with slip
detection and with the same bag replayed without it.
``--ramp``: the simulator's ramp (config/sim.yaml ``ramp``) is on the path's eastbound leg; the
EKF fuses the IMU's roll and pitch and projects the dead wheels' velocity onto the horizontal
plane (docs/ekf_node.md, Ramps and tilt); the table adds the same bag replayed without that
compensation, and the RMSE from the ramp on.

``--view``: field_view runs alongside (ekf_node and pure_pursuit_node publish their markers) and
the demo prints its URL, http://127.0.0.1:8765/ (docs/field_view.md).

The table keeps a row for the same bag replayed without cmd_vel (``replay: without cmd_vel``);
below it, ``NEES live pose mean`` and ``NEES live twist mean`` (χ²(3) each: the recorded
/odometry/filtered with the covariances ekf_node published, against the truth at each estimate's
own stamp: sim_node publishes the truth at every /clock stamp too, ``ground_truth.at_clock``;
tools.consistency.live_nees), the run's mean NEES and each input's mean NIS (the bag replayed
with the run's parameters) and, with ``--odom-dropout``, the position error during the dropout.

sim_node and pure_pursuit_node run at SCHED_FIFO when the system allows it (``robot_priority``),
and the recorder is drained before the bag is closed: a busy computer starves the recorder, not
the simulated physics or the path follower, and the bag holds the whole run (docs/under_load.md).

Exit status: 0 on success; 1 if a node died or the path was not completed in time.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from ekf_localization.control.field_path import config_dir
from ekf_localization.core.units import ns_to_seconds
from ekf_localization.tools import demo_images
from ekf_localization.tools.demo_analysis import (
    EKF_PARAMS,
    EKF_TWIST_PARAMS,
    TOPIC_CAMERA,
    TOPIC_DEAD_WHEELS,
    TOPIC_FILTERED,
    TOPIC_PATH,
    TOPIC_TRUTH,
    analyse,
    tilt_overrides,
)
from ekf_localization.tools.demo_drives import (
    DRIVES,
    MODULE_DEAD_RECKONING_ROW,
    TOPIC_JOINTS,
    module_dead_reckoning,
)
from ekf_localization.tools.demo_params import (
    known_start,
    placed_start,
    write_ekf_params,
    write_view_sim_params,
)
from ekf_localization.vision.heading_prior import SINGLE_TAG_METHODS

# After the run: the recorder takes the messages DDS already delivered until none came for
# DRAIN_QUIET_S (wall), at most DRAIN_LIMIT_S. On a busy CPU it is seconds behind the nodes
# (its depth is 1000 per topic), and a bag closed without draining ends seconds before the run.
DRAIN_QUIET_S, DRAIN_LIMIT_S = 1.0, 60.0
WORLD_PRIORITY = 50  # sim_node's SCHED_FIFO: the drive's, as controller_manager's, above ekf_node's 40
# pure_pursuit_node's: a robot's controller, light (50 Hz) but never starved, even by a world that
# cannot keep up with --rtf and then takes a whole core at its own SCHED_FIFO
FOLLOWER_PRIORITY = 45
PATHS = {"seed000": "seed000_test_path.yaml", "cycle": "ftc_cycle.yaml"}
NODE_MODULES = {
    "sim_node": "sim_robot.ros.sim_node",
    "ekf_node": "ekf_localization.nodes.ekf_node",
    "pure_pursuit_node": "ekf_localization.nodes.pure_pursuit_node",
    "field_view": "ekf_localization.tools.field_view",
    demo_images.NODE: demo_images.MODULE,
}
VIEW_SIM_PARAMS = "sim_view.yaml"  # sim.yaml with the run's field overrides, for field_view
EKF_YAML = {None: "ekf.yaml", "dead": "ekf_joint_states.yaml", "driven": "ekf_driven_wheels.yaml"}
EKF_TWO_CAMERAS = "ekf_two_cameras.yaml"  # --cameras 2: pose0 and pose1
SIM_JOINT_STATES = {"dead": "dead_wheels.publish_joint_states:=true",  # by --joint-states
                    "driven": "wheel_encoders.publish_joint_states:=true"}
# --ramp: the IMU's roll and pitch are the tilt (imu0 fuses them) and the dead wheels are projected
# sim_node holds simulated time at 0 until this topic has a publisher: the demo creates one
# once the recorder has matched every publisher of these topics, so the bag holds the run from
# its start.
RECORDER_READY = "/ekf_demo/recorder_ready"
RECORDED_BEFORE_START = (TOPIC_TRUTH, TOPIC_DEAD_WHEELS, TOPIC_CAMERA, "/imu/data", "/clock",
                         TOPIC_FILTERED, "/cmd_vel", TOPIC_PATH)
# ... and once the nodes' subscriptions are matched too (this process's own included), so no
# node misses the first messages: (topic, subscriptions in the graph).
# /clock: ekf_node's and pure_pursuit_node's time sources, this node's and its recording.
SUBSCRIBED_BEFORE_START = ((TOPIC_DEAD_WHEELS, 2), (TOPIC_CAMERA, 2), ("/imu/data", 2), ("/cmd_vel", 2),
                           (TOPIC_FILTERED, 3), ("/clock", 4))


def start_conditions(joint_states: bool) -> tuple[tuple[str, ...], tuple[tuple[str, int], ...]]:
    """(topics recorded, (topic, subscriptions)) before sim time starts; with --joint-states the
    EKF subscribes joint_states and only the recorder odometry/dead_wheels."""
    if not joint_states:
        return RECORDED_BEFORE_START, SUBSCRIBED_BEFORE_START
    subscribed = tuple((t, 1) if t == TOPIC_DEAD_WHEELS else (t, n) for t, n in SUBSCRIBED_BEFORE_START)
    return RECORDED_BEFORE_START + (TOPIC_JOINTS,), subscribed + ((TOPIC_JOINTS, 2),)


def node_command(name: str) -> list[str]:
    exe = shutil.which(name)
    return [exe] if exe else [sys.executable, "-m", NODE_MODULES[name]]


@dataclass
class NodeProcess:
    name: str
    proc: subprocess.Popen
    log: Path

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout: float = 5.0) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=timeout)

    def tail(self, n: int = 15) -> str:
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""


def _floats(values) -> str:
    """A ROS parameter list of doubles (always with a decimal point)."""
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def start_nodes(args: argparse.Namespace, out: Path) -> list[NodeProcess]:
    """Start the three nodes with the package's YAMLs: the EKF starts at the path's start, the
    robot where a team would really have put it (``placed_start``)."""
    from ekf_localization.control.field_path import load_path

    cfg = config_dir()
    drive = DRIVES[args.drive]
    sim_yaml = args.sim_params or cfg / drive.sim_yaml
    path_file = args.path_file or cfg / "paths" / PATHS[args.path]
    cycles = args.cycles if args.path == "cycle" and args.path_file is None else None
    x0, y0, th0 = load_path(path_file, cycles).start
    placed = placed_start(x0, y0, th0, args.seed)
    sim_time = ["-p", "use_sim_time:=true"]
    sim_args = ["--params-file", str(sim_yaml), "-p", f"real_time_factor:={float(args.rtf)!r}",
                "-p", "publish_clock:=true", "-p", f"initial_pose:={_floats(placed)}",
                "-p", f"wait_for_topics:=[odometry/filtered, cmd_vel, {RECORDER_READY}]",
                "-p", f"seed:={args.seed}", "-p", "ground_truth.at_clock:=true"]
    if args.path == "cycle":
        sim_args += ["-p", "field.preset:=freight_frenzy"]
    if args.joint_states or drive.joint_states:  # the swerve's module states, whatever --sim-params says
        sim_args += ["-p", SIM_JOINT_STATES[args.joint_states or "driven"]]
    cameras = getattr(args, "cameras", 1)
    if cameras == 2:
        sim_args += ["-p", "camera1.enabled:=true"]
    if args.ramp:
        sim_args += ["-p", "ramp.enabled:=true"]
    if getattr(args, "dropout", None):
        sim_args += ["-p", f"dead_wheels.dropout:={_floats(args.dropout)}"]
    if getattr(args, "bump_push", None):
        sim_args += ["-p", f"bump:={_floats(args.bump_push)}"]
    images = getattr(args, "camera", "poses") == "images"
    if images:
        sim_args += demo_images.sim_arguments(cfg)
    pp_args = ["--params-file", str(cfg / "pure_pursuit.yaml"), *sim_time, "-p", f"path_file:={path_file}",
               "-p", f"mode:={drive.pursuit_mode}"]
    if cycles is not None:
        pp_args += ["-p", f"cycles:={cycles}"]
    if cameras == 2:
        ekf_yaml = cfg / EKF_TWO_CAMERAS
    else:
        ekf_yaml = cfg / (EKF_YAML[args.joint_states] if args.drive == "mecanum" else drive.ekf_yaml)
    start = known_start(ekf_yaml, x0, y0, th0)
    single_tag = getattr(args, "single_tag", None)
    if images:  # single_tag corners: a tag_cornersN input per tag and camera
        start.update(demo_images.ekf_overrides(cfg, Path(sim_yaml), cameras, single_tag))
    if args.ramp:
        start.update(tilt_overrides(bool(args.joint_states)))
    ekf_params = write_ekf_params(ekf_yaml, out / EKF_PARAMS, start)
    if args.joint_states:
        twist_start = known_start(cfg / "ekf.yaml", x0, y0, th0)
        if args.ramp:
            twist_start.update(tilt_overrides(False))
        write_ekf_params(cfg / "ekf.yaml", out / EKF_TWIST_PARAMS, twist_start)
    specs = {
        "sim_node": sim_args,
        "ekf_node": ["--params-file", str(ekf_params), *sim_time],
        "pure_pursuit_node": pp_args,
    }
    if images:
        for camera in range(cameras):  # tag_localizer, camera1/tag_localizer
            specs[demo_images.node_label(camera)] = demo_images.node_arguments(cfg, camera, single_tag)
    if getattr(args, "view", False):
        specs["ekf_node"] += ["-p", "publish_markers:=true"]
        specs["pure_pursuit_node"] += ["-p", "publish_markers:=true"]
        sim_view = write_view_sim_params(Path(sim_yaml), out / VIEW_SIM_PARAMS,
                                         "freight_frenzy" if args.path == "cycle" else None, args.ramp)
        specs["field_view"] = [*sim_time, "-p", f"port:={args.view_port}",
                               "-p", f"sim_params_file:={sim_view}"]
    procs = []
    for name, ros_args in specs.items():
        log = out / f"{name.replace('/', '_')}.log"
        fh = open(log, "w")  # noqa: SIM115 - closed when the process ends
        cmd = [*node_command(name.rpartition("/")[2]), "--ros-args", *ros_args]
        procs.append(NodeProcess(name, subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT,
                                                        start_new_session=True), log))
        if name in ("sim_node", "pure_pursuit_node"):
            robot_priority(procs[-1], WORLD_PRIORITY if name == "sim_node" else FOLLOWER_PRIORITY)
    return procs


def robot_priority(node: NodeProcess, priority: int) -> None:
    """Run the simulated world or the path follower at SCHED_FIFO ``priority`` when allowed (their
    threads, made later, inherit it), as a robot runs its drive and its controller. The world is
    physics, which a busy computer does not slow down: at normal priority a starved sim_node runs
    its overdue steps before the commands already sent to it, so its drive acts on them late
    while every other node got them on time. A world that cannot keep up with ``--rtf`` then
    holds a core, and at normal priority the follower would get almost none (a few commands a
    second) while the drive keeps the last one."""
    from ekf_localization.ros.scheduling import use_fifo

    refused = use_fifo(priority, node.proc.pid)
    if refused:
        print(f"ekf_demo: {node.name} at normal priority: {refused}", flush=True)


def run_closed_loop(args: argparse.Namespace, out: Path, bag: Path) -> tuple[bool, str, float]:
    """Start the nodes, record, show progress. Returns (ok, message, wall seconds)."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from std_msgs.msg import Bool, Empty, Float64

    from ekf_localization.core.units import stamp_to_ns
    from ekf_localization.ros.node_runner import init_rclpy, running
    from ekf_localization.tools.bag_recorder import BagRecorder, drain

    init_rclpy([])  # Ctrl-C / SIGTERM end the loop below; the nodes are stopped and the bag closed after it
    # The recorder stamps messages with sim time (/clock), the clock every node runs on.
    images = getattr(args, "camera", "poses") == "images"
    cameras = getattr(args, "cameras", 1)
    rec = BagRecorder(bag, storage=args.storage, exclude=demo_images.image_topics(cameras) if images else (),
                      parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    ex = SingleThreadedExecutor()
    ex.add_node(rec)
    state = {"progress": 0.0, "done": False, "truth": None, "est": None}
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    rec.create_subscription(Float64, "/pure_pursuit/progress",
                            lambda m: state.__setitem__("progress", m.data), 10)
    rec.create_subscription(Bool, "/pure_pursuit/done", lambda m: state.__setitem__("done", m.data), latched)
    rec.create_subscription(Odometry, TOPIC_TRUTH, lambda m: state.__setitem__("truth", m), 10)
    rec.create_subscription(Odometry, TOPIC_FILTERED, lambda m: state.__setitem__("est", m), 10)
    procs = start_nodes(args, out)
    if getattr(args, "view", False):
        print(f"field view: http://127.0.0.1:{args.view_port}/  (open it in a browser; "
              f"field_view's log: {out / 'field_view.log'})", flush=True)
    joints = bool(args.joint_states) or DRIVES[args.drive].joint_states
    recorded_before_start, subscribed_before_start = start_conditions(joints)
    subscribed_before_start += demo_images.subscribed_before_start(images, cameras)
    t0 = time.monotonic()
    last_print = 0.0
    ok, message = False, ""
    try:
        ready_pub = None
        while running(ex):
            ex.spin_once(timeout_sec=0.05)
            now = time.monotonic() - t0
            if (ready_pub is None and all(rec.matched(t) for t in recorded_before_start)
                    and all(rec.count_subscribers(t) >= n for t, n in subscribed_before_start)):
                ready_pub = rec.create_publisher(Empty, RECORDER_READY, latched)
                ready_pub.publish(Empty())
            dead = [p for p in procs if not p.alive()]
            if dead:
                message = "; ".join(f"{p.name} exited with {p.proc.returncode}:\n{p.tail()}" for p in dead)
                break
            if state["done"]:
                ok, message = True, "path completed"
                end = time.monotonic() + 0.5
                while time.monotonic() < end:
                    ex.spin_once(timeout_sec=0.05)
                break
            if now > args.timeout:
                message = f"path not completed within {args.timeout:.0f} s (wall)"
                break
            if now - last_print >= 1.0:
                last_print = now
                if ready_pub is None:
                    missing = [t for t in recorded_before_start if not rec.matched(t)]
                    print(f"[{now:6.1f} s] waiting for the nodes; recorder not yet matched on {missing}",
                          flush=True)
                    continue
                err = ""
                tr, es = state["truth"], state["est"]
                if tr is not None and es is not None:
                    d = math.hypot(tr.pose.pose.position.x - es.pose.pose.position.x,
                                   tr.pose.pose.position.y - es.pose.pose.position.y)
                    sim_t = ns_to_seconds(stamp_to_ns(tr.header.stamp))
                    err = f"  sim {sim_t:6.1f} s  EKF position error {d * 100:5.1f} cm"
                counts = sum(rec.counts.values())
                print(f"[{now:6.1f} s] along path {state['progress']:6.2f} m{err}  "
                      f"recorded {counts} msgs", flush=True)
        else:
            message = "interrupted"
    finally:
        died = [p for p in procs if not p.alive()]
        for p in procs:
            p.stop()
        # A busy CPU leaves the recorder behind the nodes: take what DDS still holds before closing
        drain(ex, rec, quiet_s=DRAIN_QUIET_S, limit_s=DRAIN_LIMIT_S)
        rec.close()
        ex.shutdown()
        rec.destroy_node()
        rclpy.shutdown()
        signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C stops the analysis
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if died and ok:
        ok, message = False, "; ".join(f"{p.name} died ({p.proc.returncode})" for p in died)
    return ok, message, time.monotonic() - t0


def choose_domain() -> int | None:
    """Run on a ROS_DOMAIN_ID of its own: the caller's ROS_DOMAIN_ID when set, otherwise the first
    free id (ekf_localization/tools/domain_id.py: no participant on this machine, no other demo's
    lock), exported to the nodes. Returns the fd of the id's lock, to keep open for the run."""
    from ekf_localization.tools import domain_id

    given = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if given:
        fd = domain_id.try_lock(int(given))
        if fd is None:
            print(f"ekf_demo: warning: another demo runs on ROS_DOMAIN_ID={given}; their topics mix "
                  "(unset ROS_DOMAIN_ID to let the demo pick a free one)", file=sys.stderr)
        return fd
    domain, fd = domain_id.pick_free_domain(*domain_id.domain_range())
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    return fd


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ekf_demo", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--drive", choices=list(DRIVES), default="mecanum",
                        help="the simulated robot and its filter configuration (tools/demo_drives.py)")
    parser.add_argument("--sim-params", type=Path, default=None, metavar="FILE",
                        help="sim_node's YAML (the simulated robot) instead of the drive's config/sim*.yaml")
    parser.add_argument("--path", choices=sorted(PATHS), default="seed000")
    parser.add_argument("--path-file", type=Path, default=None, help="a path YAML instead of --path")
    parser.add_argument("--cycles", type=int, default=3, help="cycles of the FTC cycle path")
    parser.add_argument("--rtf", type=float, default=1.0,
                        help="real-time factor of the simulator (e.g. 3.0 = three times faster)")
    parser.add_argument("--out", type=Path, default=Path("output/demo"))
    parser.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    parser.add_argument("--seed", type=int, default=0, help="simulator random seed")
    parser.add_argument("--timeout", type=float, default=300.0, help="wall-clock limit, s")
    parser.add_argument("--ramp", action="store_true",
                        help="drive over the simulator's ramp, with tilt compensation (and a replay without)")
    parser.add_argument("--camera", choices=["poses", "images"], default="poses",
                        help="poses: the simulator's finished camera poses; images: rendered AprilTag "
                             "images through tag_localizer")
    parser.add_argument("--cameras", type=int, choices=[1, 2], default=1,
                        help="2: a second camera facing backward (sim.yaml camera1), fused as pose1 "
                             "(config/ekf_two_cameras.yaml); not with --joint-states")
    parser.add_argument("--single-tag", choices=SINGLE_TAG_METHODS, default=None,
                        help="with --camera images: tag_localizer's single_tag (default: "
                             "config/tag_localizer.yaml's)")
    parser.add_argument("--joint-states", nargs="?", const="dead", choices=["dead", "driven"], default=None,
                        help="EKF from sensor_msgs/JointState: the dead wheels' "
                             "(config/ekf_joint_states.yaml) or, 'driven', the drive's own wheels "
                             "(config/ekf_driven_wheels.yaml)")
    parser.add_argument("--odom-dropout", default=None, metavar="START:DURATION",
                        help="silence the dead-wheel odometry from START s of sim time for DURATION s "
                             "(sim_node's dead_wheels.dropout)")
    parser.add_argument("--bump", default=None, metavar="T:DX:DY",
                        help="push the simulated robot by (DX, DY) m in the field frame over 0.3 s from "
                             "sim time T s, its driven wheels keeping their speeds (sim_node's bump); the "
                             "report adds the error 2 s later with slip detection and without")
    parser.add_argument("--view", action="store_true",
                        help="also start field_view (the live field in a browser) and print its URL")
    parser.add_argument("--view-port", type=int, default=8765, help="field_view's port on 127.0.0.1")
    args = parser.parse_args(argv)
    from ekf_localization.ros import extras

    if extras.check("ekf_demo", "rosbags", *(("aiohttp",) if args.view else ())):
        return 2
    args.dropout = None
    if args.odom_dropout is not None:
        try:
            args.dropout = [float(v) for v in args.odom_dropout.split(":")]
        except ValueError:
            args.dropout = []
        if len(args.dropout) != 2 or not all(math.isfinite(v) and v >= 0 for v in args.dropout):
            parser.error("--odom-dropout must be START:DURATION in seconds, e.g. 3.0:0.5")
    if args.drive != "mecanum" and (args.joint_states or args.ramp):
        parser.error("--joint-states and --ramp run the mecanum robot (--drive mecanum)")
    if args.sim_params is not None and not args.sim_params.is_file():
        parser.error(f"--sim-params: no such file: {args.sim_params}")
    args.bump_push = None
    if args.bump is not None:
        try:
            args.bump_push = [float(v) for v in args.bump.split(":")]
        except ValueError:
            args.bump_push = []
        if len(args.bump_push) != 3 or not all(math.isfinite(v) for v in args.bump_push) \
                or args.bump_push[0] < 0:
            parser.error("--bump must be T:DX:DY (s, m, m), e.g. 5:0:0.3")
    if args.cameras == 2 and (args.joint_states or args.drive != "mecanum"):
        parser.error("--cameras 2 runs config/ekf_two_cameras.yaml, whose dead wheels are the odometry "
                     "twist: not with --joint-states or another --drive")
    if not (args.rtf > 0 and math.isfinite(args.rtf)):
        parser.error("--rtf must be a positive number")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    try:
        domain_lock = choose_domain()  # noqa: F841 - held (open) until the process exits
    except (RuntimeError, ValueError) as exc:
        print(f"ekf_demo: {exc}", file=sys.stderr)
        return 2
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "bag"
    if bag.exists():
        shutil.rmtree(bag)
    print(f"ekf_demo: path={args.path} rtf={args.rtf:g} ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} -> {out}",
          flush=True)
    ok, message, wall = run_closed_loop(args, out, bag)
    print(f"ekf_demo: {message} after {wall:.1f} s wall", flush=True)
    if not bag.exists() or not (bag / "metadata.yaml").exists():
        print("ekf_demo: no bag was written", file=sys.stderr)
        return 1
    from ekf_localization.tools.bag_io import bag_size_bytes

    try:
        extra = {}
        if args.drive == "swerve":  # the modules' own odometry beside the dead wheels'
            modules = module_dead_reckoning(bag, out / EKF_PARAMS)
            extra = {MODULE_DEAD_RECKONING_ROW: modules} if modules is not None else {}
        table = analyse(bag, out, bool(args.joint_states), args.ramp, args.camera == "images", extra,
                        cameras=args.cameras,
                        slip=args.joint_states == "driven" or args.drive == "swerve",
                        bump_s=args.bump_push[0] if args.bump_push else None)
    except RuntimeError as exc:
        print(f"ekf_demo: {exc}", file=sys.stderr)
        return 1
    print()
    print(table)
    (out / "rmse.txt").write_text(table + "\n")
    print(f"\nbag: {bag} ({bag_size_bytes(bag) / 1e6:.1f} MB); plots: {out / 'trajectory.png'}, "
          f"{out / 'errors.png'}; node logs: {out}/*.log\n"
          f"replay it offline: bag_replay {bag} --params {out / EKF_PARAMS} --out {out / 'replay'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
