"""Read rosbag2 (MCAP, sqlite3) and ROS 1 bags into plain arrays with the `rosbags` library."""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

try:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
except ImportError:  # an optional extra (ros/extras.py): open_reader says what to install
    AnyReader = None

from ekf_localization.core.angles import quaternion_to_yaw
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.ros import extras
from ekf_localization.tools.evaluation import Trajectory


def odometry_state(msg) -> tuple[int, np.ndarray, np.ndarray]:
    """nav_msgs/Odometry -> (stamp ns, [x y θ vx vy ω] with body twist, 3x3 pose covariance x,y,yaw)."""
    p = msg.pose.pose
    q = p.orientation
    t = msg.twist.twist
    state = np.array([p.position.x, p.position.y, quaternion_to_yaw(q.x, q.y, q.z, q.w),
                      t.linear.x, t.linear.y, t.angular.z])
    c = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)
    idx = [0, 1, 5]
    return stamp_to_ns(msg.header.stamp), state, c[np.ix_(idx, idx)]


def pose_stamped_state(msg) -> tuple[int, np.ndarray, np.ndarray]:
    """geometry_msgs/PoseWithCovarianceStamped -> (stamp ns, [x y θ], 3x3 covariance)."""
    p = msg.pose.pose
    q = p.orientation
    c = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)
    idx = [0, 1, 5]
    return (stamp_to_ns(msg.header.stamp), np.array([p.position.x, p.position.y,
                                            quaternion_to_yaw(q.x, q.y, q.z, q.w)]),
            c[np.ix_(idx, idx)])


@dataclass
class BagMessage:
    topic: str
    msgtype: str
    log_time_ns: int  # when the recorder received it
    msg: object


BAG_FORM = "a rosbag2 directory (metadata.yaml and its MCAP or sqlite3 files) or a ROS 1 .bag file"


class BagError(Exception):
    """A bag that cannot be read: the message names it, the problem and the expected form."""


@contextmanager
def _reading(path: Path) -> Iterator[None]:
    """Turn whatever the bag readers raise on a broken bag into one BagError."""
    try:
        yield
    except BagError:
        raise
    except Exception as exc:  # rosbags raises many types (reader, MCAP, zstd, struct, sqlite, OS errors)
        text = " ".join(str(exc).split()) or type(exc).__name__
        raise BagError(f"cannot read bag '{path}' ({text}): expected {BAG_FORM}") from exc


def open_reader(bag: Path | str) -> AnyReader:
    """An opened AnyReader for a rosbag2 directory (MCAP/sqlite3) or a ROS 1 .bag file.

    Raises BagError for a missing or unreadable bag.
    """
    path = Path(bag)
    if AnyReader is None:
        raise BagError(extras.install_hint("reading a bag", "rosbags"))
    if not path.exists():
        raise BagError(f"no bag at '{path}': expected {BAG_FORM}")
    with _reading(path):
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    return reader


def iter_messages(bag: Path | str, topics: list[str] | None = None) -> Iterator[BagMessage]:
    """Deserialized messages in log-time order, optionally only from ``topics``."""
    path = Path(bag)
    reader = open_reader(path)
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        if not conns:  # rosbags reads every connection when given none
            return
        with _reading(path):
            for conn, t, raw in reader.messages(connections=conns):
                yield BagMessage(conn.topic, conn.msgtype, int(t), _deserialize(reader, raw, conn.msgtype))
    finally:
        with _reading(path):
            reader.close()


def _deserialize(reader: AnyReader, raw: bytes, msgtype: str):
    """The message; rclpy's deserializer when rosbags refuses the length: Fast CDR pads the end
    of some messages (a sensor_msgs/JointState with empty velocity and effort) by more than the
    3 bytes rosbags accepts."""
    try:
        return reader.deserialize(raw, msgtype)
    except Exception as exc:
        if "size mismatch" not in str(exc):
            raise
        try:
            from rclpy.serialization import deserialize_message

            package, _, name = msgtype.split("/")
            cls = getattr(importlib.import_module(f"{package}.msg"), name)
        except (ImportError, AttributeError, ValueError):
            raise exc from None
        return deserialize_message(bytes(raw), cls)


def topic_types(bag: Path | str) -> dict[str, str]:
    path = Path(bag)
    reader = open_reader(path)
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        with _reading(path):
            reader.close()


def read_odometry(bag: Path | str, topic: str) -> Trajectory:
    """Every nav_msgs/Odometry on ``topic`` as a Trajectory (stamps from the headers)."""
    ts, xs, cs = [], [], []
    for m in iter_messages(bag, [topic]):
        t, x, c = odometry_state(m.msg)
        ts.append(t)
        xs.append(x)
        cs.append(c)
    if not ts:
        return Trajectory(np.zeros(0, np.int64), np.zeros((0, 6)), np.zeros((0, 3, 3)))
    return Trajectory(np.array(ts), np.array(xs), np.array(cs))


def read_poses(bag: Path | str, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamps ns (K,), poses (K, 3)) of PoseWithCovarianceStamped messages on ``topic``."""
    ts, ps = [], []
    for m in iter_messages(bag, [topic]):
        t, p, _c = pose_stamped_state(m.msg)
        ts.append(t)
        ps.append(p)
    return np.array(ts, dtype=np.int64), np.array(ps).reshape(-1, 3)


def bag_size_bytes(bag: Path | str) -> int:
    path = Path(bag)
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
