"""Record live topics to a rosbag2 file (MCAP by default, or sqlite3) with the `rosbags` library.

Messages are taken raw (serialized CDR, exactly as they crossed DDS) and written with the
message definitions of ROS 2 Jazzy, so `ros2 bag info` / `ros2 bag play` on a real install
read the bag. Topics are discovered while recording; each is subscribed with a QoS that
matches its publishers (transient-local is kept, best-effort publishers get a best-effort
subscription), and the publishers' QoS is stored in the bag's metadata.

    bag_recorder -o <bag_dir> [--storage mcap|sqlite3] [--topics /a /b ...] [--ros-args ...]
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Iterable
from pathlib import Path

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ekf_localization.ros import extras
from ekf_localization.ros.conversions import message_type_class
from ekf_localization.ros.node_runner import init_rclpy, make_executor, spin_forever

try:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
except ImportError:  # an optional extra (ros/extras.py): main() and BagRecorder say what to install
    StoragePlugin = None

STORAGE_NAMES = ("mcap", "sqlite3")
STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3} if StoragePlugin else {}
_INFINITE = QosTime(sec=2147483647, nsec=4294967295) if StoragePlugin else None


def _bag_qos(reliability: int, durability: int) -> Qos:
    return Qos(history=QosHistory.UNKNOWN, depth=0, reliability=QosReliability(reliability),
               durability=QosDurability(durability), deadline=_INFINITE, lifespan=_INFINITE,
               liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=_INFINITE,
               avoid_ros_namespace_conventions=False)


class BagRecorder(Node):
    """Subscribes raw to topics as they appear and writes every message to one bag."""

    def __init__(self, output: Path | str, storage: str = "mcap", topics: Iterable[str] | None = None,
                 exclude: Iterable[str] = (), discovery_period_s: float = 0.2, **node_kwargs) -> None:
        if StoragePlugin is None:
            raise ImportError(extras.install_hint("BagRecorder", "rosbags"))
        super().__init__("bag_recorder", **node_kwargs)
        if storage not in STORAGES:
            raise ValueError(f"storage must be one of {sorted(STORAGES)}, got {storage!r}")
        self.output = Path(output)
        if self.output.exists():
            raise FileExistsError(f"bag output {self.output} already exists")
        self._typestore = get_typestore(Stores.ROS2_JAZZY)
        self._writer = Writer(self.output, version=9, storage_plugin=STORAGES[storage])
        self._writer.open()
        self._lock = threading.Lock()
        self._wanted = None if topics is None else {self._absolute(t) for t in topics}
        self._exclude = {self._absolute(t) for t in exclude}
        self._subs: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        self._closed = False
        self._discover()
        # Discovery runs on the steady clock: with use_sim_time, ROS time may not move yet.
        self._timer = self.create_timer(discovery_period_s, self._discover,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    @staticmethod
    def _absolute(topic: str) -> str:
        return topic if topic.startswith("/") else "/" + topic

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self._subs or topic in self._exclude:
                continue
            if self._wanted is not None and topic not in self._wanted:
                continue
            infra = topic.startswith("/rosout") or topic == "/parameter_events"
            if infra and self._wanted is None:
                continue
            type_name = types[0]
            if type_name not in self._typestore.types:
                self.get_logger().warning(f"not recording {topic}: unknown type {type_name}")
                self._subs[topic] = None
                continue
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            best_effort = any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos)
            latched = all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_LAST, depth=1000,
                reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)
            offered = [_bag_qos(int(i.qos_profile.reliability), int(i.qos_profile.durability))
                       for i in infos]
            with self._lock:
                conn = self._writer.add_connection(topic, type_name, typestore=self._typestore,
                                                   offered_qos_profiles=offered)
            self.counts[topic] = 0
            self._subs[topic] = self.create_subscription(
                message_type_class(type_name), topic, self._callback(topic, conn), qos, raw=True)

    def matched(self, topic: str) -> bool:
        """Whether the recording of ``topic`` has matched every publisher the graph shows: a
        publisher not yet matched (DDS discovery can take seconds) sends its first messages to
        the other subscribers only."""
        sub = self._subs.get(self._absolute(topic))
        return sub is not None and sub.get_publisher_count() >= max(self.count_publishers(topic), 1)

    def _callback(self, topic: str, conn):
        def write(data: bytes) -> None:
            stamp = self.get_clock().now().nanoseconds
            with self._lock:
                if self._closed:
                    return
                self._writer.write(conn, stamp, data)
            self.counts[topic] += 1
        return write

    def close(self) -> None:
        """Finish the bag (writes metadata.yaml). Safe to call twice."""
        with self._lock:
            if not self._closed:
                self._closed = True
                self._writer.close()


def drain(executor, rec: BagRecorder, quiet_s: float = 0.25, limit_s: float = 1.2) -> None:
    """After a stop signal: take what DDS already delivered or still delivers of what was sent
    before it, until no new message came for ``quiet_s`` (wall time: a timer's event ending a
    spin step early is not quiet) or ``limit_s`` passed (the node stops within 2 s)."""
    start = last_new = time.monotonic()
    count = sum(rec.counts.values())
    while executor.context.ok():
        now = time.monotonic()
        if now - last_new >= quiet_s or now - start >= limit_s:
            return
        executor.spin_once(timeout_sec=0.02)
        if (n := sum(rec.counts.values())) != count:
            count, last_new = n, time.monotonic()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    if extras.check("bag_recorder", "rosbags"):
        return 2
    non_ros = rclpy.utilities.remove_ros_args(argv)[1:]
    parser = argparse.ArgumentParser(prog="bag_recorder", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--output", required=True, help="bag directory to create")
    parser.add_argument("--storage", choices=sorted(STORAGE_NAMES), default="mcap")
    parser.add_argument("--topics", nargs="*", default=None, help="topics to record (default: all)")
    parser.add_argument("--exclude", nargs="*", default=[], help="topics not to record")
    args = parser.parse_args(non_ros)
    init_rclpy(argv)  # SIGINT / SIGTERM end the spin loop; the bag is then drained and closed
    try:
        rec = BagRecorder(args.output, args.storage, args.topics, args.exclude)
    except (ValueError, FileExistsError) as exc:
        print(f"bag_recorder: {exc}", file=sys.stderr)
        rclpy.shutdown()
        return 2
    rec.get_logger().info(f"recording to {rec.output} ({args.storage}); Ctrl-C to stop")
    executor = make_executor()
    executor.add_node(rec)
    try:
        spin_forever(executor)
        drain(executor, rec)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        rec.close()
        executor.shutdown()
        total = sum(rec.counts.values())
        print(f"bag_recorder: wrote {total} messages on {len(rec.counts)} topics to {rec.output}")
        rec.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
