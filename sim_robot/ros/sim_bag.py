"""Record a simulated drive straight to a rosbag2 file: the ROS-free simulator world, no DDS.

For tests, benchmarks and tuning experiments that need a bag with ground truth in seconds
rather than a closed-loop demo run. The world is the demo's (``config/sim.yaml``, the file
sim_node reads, unless ``--sim-params`` names another). The robot starts at the field centre
(config/ekf.yaml's initial state) and follows a fixed command pattern (``--drive``: a wobbling
circle, or the calibration drive of docs/ekf_calibrate.md); messages are the ones sim_node
publishes (:mod:`sim_robot.ros.sim_messages`) on the demo's topics, written at their receive
times (the camera's after its latency).

``reported_dead_wheel_variance_factor`` multiplies the twist covariance the odometry messages
carry, so a run whose true encoder noise differs from what the sensor reports can be made
(e.g. true noise ×4 in ``world_config``, reported factor 1/4: the messages claim the default).

    python -m sim_robot.ros.sim_bag OUT [--duration 20.0] [--seed 0] [--drive circle|calibration]
           [--dead-wheel-variance-factor 4.0] [--no-truth] [--joint-states [dead|driven]]
           [--sim-params config/sim.yaml]

``--joint-states`` (or ``--joint-states dead``) adds /joint_states with the dead wheels' encoder
positions; ``--joint-states driven`` with the drive's own wheels instead (the world's
``wheel_encoders``: mecanum's four or the tank's two, turning with the world's true
``mecanum.*`` or ``tank.*`` geometry), as sim_node's ``wheel_encoders.publish_joint_states``.

``--dead-wheel-variance-factor F`` makes the encoders' true noise variance F times the default
while the messages still report the default covariance.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

from ekf_localization.core.units import ns_to_seconds, seconds_to_ns
from ekf_localization.ros import extras
from sim_robot.world.world import World, WorldConfig

TOPIC_TYPES = {
    "/odometry/dead_wheels": "nav_msgs/msg/Odometry",
    "/camera/pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/imu/data": "sensor_msgs/msg/Imu",
    "/ground_truth/odom": "nav_msgs/msg/Odometry",
    "/cmd_vel": "geometry_msgs/msg/TwistStamped",
}
# written only when asked for (``topics``, ``--joint-states``): the dead wheels' encoder positions
JOINT_STATES = "/joint_states"
OPTIONAL_TOPIC_TYPES = {JOINT_STATES: "sensor_msgs/msg/JointState"}
POD_JOINTS = ("left_pod", "right_pod", "lateral_pod")  # config/sim.yaml's dead_wheels.joint_names
START_POSE = (0.0, 0.0, 0.0)  # x m, y m, yaw rad: config/ekf.yaml's initial_state
COMMAND_PERIOD_NS = 20_000_000  # a new command every 20 ms (pure_pursuit_node's rate)


def demo_world_config(sim_params: Path | str | None = None) -> WorldConfig:
    """The simulator world sim_node builds from ``sim_params`` (default: the package's config/sim.yaml).

    Raises ParameterError (from the schema) when the file does not load.
    """
    return demo_world(sim_params)[0]


def demo_world(sim_params: Path | str | None = None,
               driven_joint_states: bool = False) -> tuple[WorldConfig, tuple[str, ...]]:
    """(the world, the driven wheels' joint names) of ``sim_params``; ``driven_joint_states``: with
    the drive's wheel encoders on (``wheel_encoders.publish_joint_states``, the dead wheels' off),
    else the names are empty. Raises ParameterError when the file does not load."""
    from ekf_localization.control.field_path import config_dir
    from ekf_localization.ros.parameters import parameters_from_yaml
    from sim_robot.ros.sim_params import parse_parameters

    path = Path(sim_params) if sim_params is not None else config_dir() / "sim.yaml"
    values = parameters_from_yaml(path, "sim_node")
    if driven_joint_states:
        values = {**values, "wheel_encoders.publish_joint_states": True,
                  "dead_wheels.publish_joint_states": False}
    world, node = parse_parameters(values)
    return world, tuple(node.driven_joint_names) if driven_joint_states else ()


def command(t: float) -> np.ndarray:
    """The body twist [vx vy wz] commanded at ``t`` s: a circle of about 0.7 m radius, with wobble."""
    return np.array([0.4 + 0.1 * math.sin(0.9 * t), 0.1 * math.cos(0.6 * t),
                     0.6 + 0.15 * math.sin(0.45 * t)])


def calibration_command(t: float) -> np.ndarray:
    """A calibration drive's body twist [vx vy wz] at ``t`` s, repeating every 65 s: 3.25 turns in
    place at +1 rad/s, pushes back and forth and sideways and back while facing the +y wall's
    images, 1.5 turns at -0.5 rad/s, the same pushes facing the -y wall, a quarter turn back to the
    start heading. Turn rates that differ, and straight runs, separate a gyro's scale from its
    bias; pushes seen by the camera give the dead-wheel pods' scales and angles."""
    phase = t % 65.0
    pushes = ((3.0, (-0.3, 0.0, 0.0)), (3.0, (0.3, 0.0, 0.0)),
              (3.0, (0.0, 0.3, 0.0)), (3.0, (0.0, -0.3, 0.0)))
    steps = ((6.5 * math.pi, (0.0, 0.0, 1.0)), *pushes, (6.0 * math.pi, (0.0, 0.0, -0.5)), *pushes,
             (0.5 * math.pi, (0.0, 0.0, 1.0)))
    end = 0.0
    for length, twist in steps:
        end += length
        if phase < end:
            return np.array(twist)
    return np.zeros(3)


DRIVES = {"circle": command, "calibration": calibration_command}


def simulated_messages(duration_s: float, seed: int = 0, world_config: WorldConfig | None = None,
                       reported_dead_wheel_variance_factor: float = 1.0,
                       drive: str = "circle",
                       driven_joints: tuple[str, ...] = ()) -> list[tuple[str, int, object]]:
    """(topic, receive time ns, message) of the drive, in receive order.

    ``driven_joints``: /joint_states are the drive's wheel encoders under these names (the
    world's ``wheel_encoders`` must be on, :func:`demo_world`), else the dead wheels'.

    ``world_config`` None: the ``WorldConfig()`` defaults (no camera latency; benchmarks/
    bench_localizer.py's workload), not the demo's world (:func:`demo_world_config`, what
    :func:`write_sim_bag` and the command use by default). ``drive``: a name in :data:`DRIVES`.
    """
    from geometry_msgs.msg import TwistStamped

    from sim_robot.ros import sim_messages
    from sim_robot.world.camera_sensor import CameraReading
    from sim_robot.world.dead_wheel_sensor import DeadWheelReading
    from sim_robot.world.imu_sensor import ImuReading
    from sim_robot.world.wheel_encoder_sensor import WheelEncoderReading
    from sim_robot.world.world import TruthReading

    world_config = world_config or WorldConfig()
    world = World(world_config, n_trials=1, seed=seed)
    world.reset(np.array(START_POSE))
    out: list[tuple[str, int, object]] = []
    for k in range(seconds_to_ns(duration_s) // COMMAND_PERIOD_NS):
        cmd = DRIVES[drive](ns_to_seconds(k * COMMAND_PERIOD_NS))
        world.set_command(cmd)
        msg = TwistStamped()
        msg.header.stamp = sim_messages.stamp(world.t_ns)
        msg.header.frame_id = "base_link"
        msg.twist.linear.x, msg.twist.linear.y, msg.twist.angular.z = (float(v) for v in cmd)
        out.append(("/cmd_vel", world.t_ns, msg))
        for r in world.advance(COMMAND_PERIOD_NS):
            if isinstance(r, TruthReading):
                out.append(("/ground_truth/odom", r.stamp_ns,
                            sim_messages.ground_truth(r, r.stamp_ns, "map", "base_link")))
            elif isinstance(r, DeadWheelReading):
                if reported_dead_wheel_variance_factor != 1.0:
                    r = dataclasses.replace(r, twist_cov=r.twist_cov * reported_dead_wheel_variance_factor)
                out.append(("/odometry/dead_wheels", r.stamp_ns,
                            sim_messages.dead_wheel_odometry(r, r.stamp_ns, "odom", "base_link")))
                if not driven_joints:
                    out.append((JOINT_STATES, r.stamp_ns, sim_messages.joint_states(
                        r, r.stamp_ns, POD_JOINTS, world_config.dead_wheels.wheel_radius)))
            elif isinstance(r, WheelEncoderReading) and driven_joints:
                out.append((JOINT_STATES, r.stamp_ns,
                            sim_messages.wheel_joint_states(r, r.stamp_ns, driven_joints)))
            elif isinstance(r, ImuReading):
                out.append(("/imu/data", r.stamp_ns, sim_messages.imu(r, r.stamp_ns, "base_link")))
            elif isinstance(r, CameraReading) and r.visible[0]:
                out.append(("/camera/pose", r.arrival_ns, sim_messages.camera_pose(r, r.stamp_ns, "map")))
    out.sort(key=lambda m: m[1])  # stable: equal receive times keep their publish order
    return out


def write_sim_bag(path: Path | str, duration_s: float = 20.0, seed: int = 0,
                  world_config: WorldConfig | None = None, reported_dead_wheel_variance_factor: float = 1.0,
                  topics: tuple[str, ...] | None = None, drive: str = "circle",
                  driven_joints: tuple[str, ...] = ()) -> Path:
    """Simulate ``duration_s`` of driving and write it as an MCAP rosbag2 at ``path``.

    ``topics`` limits what is written (e.g. without ``/ground_truth/odom``; default
    :data:`TOPIC_TYPES`, add :data:`JOINT_STATES` for the pods' encoders, or the driven wheels'
    with ``driven_joints``: :func:`simulated_messages`); ``world_config`` None: the demo's world
    (:func:`demo_world_config`).
    """
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    keep = set(TOPIC_TYPES if topics is None else topics)
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {t: w.add_connection(t, ty, typestore=ts)
                 for t, ty in (TOPIC_TYPES | OPTIONAL_TOPIC_TYPES).items() if t in keep}
        for topic, t_ns, msg in simulated_messages(duration_s, seed, world_config or demo_world_config(),
                                                   reported_dead_wheel_variance_factor, drive, driven_joints):
            if topic in conns:
                w.write(conns[topic], t_ns, serialize_message(msg))
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sim_bag", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path, help="bag directory to create")
    parser.add_argument("--duration", type=float, default=20.0, help="s of driving")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dead-wheel-variance-factor", type=float, default=1.0)
    parser.add_argument("--drive", choices=sorted(DRIVES), default="circle",
                        help="the command pattern: circle (a wobbling circle) or calibration (turns in "
                        "place at two rates, straight pushes)")
    parser.add_argument("--no-truth", action="store_true", help="leave /ground_truth/odom out")
    parser.add_argument("--joint-states", nargs="?", const="dead", choices=("dead", "driven"), default=None,
                        help="also write /joint_states: the dead wheels' encoder positions (rad), or "
                        "(driven) the drive's own wheels'")
    parser.add_argument("--sim-params", type=Path, default=None,
                        help="sim_node YAML of the world (default: config/sim.yaml, the demo's)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if extras.check("sim_bag", "rosbags"):
        return 2
    f = args.dead_wheel_variance_factor
    if not (math.isfinite(f) and f > 0 and args.duration > 0):
        print("sim_bag: --dead-wheel-variance-factor and --duration must be > 0", file=sys.stderr)
        return 2
    if args.out.exists():
        print(f"sim_bag: {args.out} exists", file=sys.stderr)
        return 2
    from ekf_localization.ros.parameters import ParameterError

    try:
        world, driven_joints = demo_world(args.sim_params, args.joint_states == "driven")
    except (ParameterError, OSError, ValueError) as exc:
        print(f"sim_bag: --sim-params {args.sim_params}: {exc}".replace("\n", " "), file=sys.stderr)
        return 2
    if f != 1.0:
        noise = world.dead_wheels.noise
        scaled = dataclasses.replace(noise, speed_variance_coeff=noise.speed_variance_coeff * f,
                                     variance_floor=noise.variance_floor * f)
        world = dataclasses.replace(world, dead_wheels=dataclasses.replace(world.dead_wheels, noise=scaled))
    topics = tuple(t for t in TOPIC_TYPES if not (args.no_truth and t == "/ground_truth/odom"))
    topics += (JOINT_STATES,) if args.joint_states else ()
    write_sim_bag(args.out, args.duration, args.seed, world, 1.0 / f, topics, args.drive, driven_joints)
    print(f"sim_bag: wrote {args.out} ({args.duration:g} s, seed {args.seed}, dead-wheel variance x{f:g})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
