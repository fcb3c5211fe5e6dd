"""Input messages taken as CDR bytes and read by rosbags, the bag tools' own reader.

rclpy turns each message it takes into Python objects; for a nav_msgs/Odometry that costs about
80 µs here, and at 1 kHz it is a large part of ekf_node's CPU (docs/performance.md). rosbags
reads the same bytes in about 23 µs into objects with the same fields, which
:mod:`ekf_localization.ros.conversions` reads as it reads a bag's. Bytes rosbags refuses are tried
with rclpy's own deserializer before the message is called unreadable, so nothing rclpy accepts
is lost. Without rosbags installed, :func:`cdr_reader` returns None and the node subscribes to
messages as usual.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable

import numpy as np

from ekf_localization.core.angles import rpy_to_quaternion
from ekf_localization.core.stamps import ns_to_sec_nanosec
from ekf_localization.ros.conversions import message_type_class, odometry_arrays


class UnreadableMessageError(ValueError):
    """Bytes that neither rosbags nor rclpy can read as the subscribed type."""


@functools.cache
def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def cdr_reader(type_name: str) -> Callable[[bytes], object] | None:
    """``read(raw) -> message`` for CDR bytes of ``type_name`` ("nav_msgs/msg/Odometry"), raising
    :class:`UnreadableMessageError`; None when rosbags is not importable (take messages instead)."""
    try:
        from rosbags.serde import SerdeError

        store = _typestore()
        store.get_msgdef(type_name)
    except ImportError:
        return None
    from rclpy.serialization import deserialize_message

    deserialize = store.deserialize_cdr
    msg_class = message_type_class(type_name)

    def read(raw: bytes) -> object:
        try:
            return deserialize(raw, type_name)
        except SerdeError:
            pass
        try:  # rclpy's reader is more lenient (e.g. trailing bytes): the slow path, never a loss
            return deserialize_message(raw, msg_class)
        except Exception as exc:  # rclpy raises RMWError (and others) on bad bytes
            raise UnreadableMessageError(f"not a CDR {type_name} ({len(raw)} bytes)") from exc

    return read


class OdometryCdrWriter:
    """The CDR bytes of ekf_node's nav_msgs/Odometry (fixed frame ids), written in place.

    rosbags serialises one template with these frame ids and a distinct sentinel in every
    float and stamp field; the writer finds the sentinels' offsets there (the layout is
    rosbags', not worked out by hand), checks that the pose and twist blocks are contiguous,
    and then writes each estimate's numbers into a copy of the template: the bytes equal
    rosbags' serialisation of :func:`~ekf_localization.ros.conversions.fill_odometry`'s message
    (``test/test_ros_conversions.py``), at a fraction of its cost.
    """

    _POSE = 3 + 4 + 36  # position, orientation, covariance
    _TWIST = 3 + 3 + 36  # linear, angular, covariance

    def __init__(self, frame_id: str, child_frame_id: str) -> None:
        from rclpy.serialization import serialize_message

        type_name = "nav_msgs/msg/Odometry"
        store = _typestore()
        msg = store.deserialize_cdr(serialize_message(message_type_class(type_name)()), type_name)
        msg.header.frame_id, msg.child_frame_id = frame_id, child_frame_id
        sentinels = np.arange(1, self._POSE + self._TWIST + 1) + 0.5
        pose, twist = sentinels[:self._POSE], sentinels[self._POSE:]
        p, t = msg.pose.pose, msg.twist.twist
        p.position.x, p.position.y, p.position.z = (float(v) for v in pose[:3])
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = (float(v) for v in pose[3:7])
        msg.pose.covariance = pose[7:].copy()
        t.linear.x, t.linear.y, t.linear.z = (float(v) for v in twist[:3])
        t.angular.x, t.angular.y, t.angular.z = (float(v) for v in twist[3:6])
        msg.twist.covariance = twist[6:].copy()
        msg.header.stamp.sec, msg.header.stamp.nanosec = 0x5EC0_1DAB, 0x0DEC_0DED
        template = bytes(store.serialize_cdr(msg, type_name))
        if template[1] != 1:  # the encapsulation says little-endian CDR
            raise ValueError("rosbags' CDR is not little-endian")
        self._buf = bytearray(template)
        self._pose = self._block(template, pose)
        self._twist = self._block(template, twist)
        stamp = struct.pack("<iI", msg.header.stamp.sec, msg.header.stamp.nanosec)
        if template.count(stamp) != 1:
            raise ValueError("the stamp of the Odometry template is not where it was expected")
        self._stamp_at = template.index(stamp)

    def _block(self, template: bytes, values) -> object:
        """A float64 view of self._buf over the contiguous run of ``values`` in ``template``."""
        first = struct.pack("<d", values[0])
        at = template.find(first)
        if at < 0 or template.count(first) != 1 or template[at:at + 8 * len(values)] != \
                np.asarray(values, dtype="<f8").tobytes():
            raise ValueError("a block of the Odometry template is not contiguous")
        return np.frombuffer(self._buf, dtype="<f8", count=len(values), offset=at)

    def write(self, est) -> bytes:
        """The CDR bytes of the estimate (fill_odometry's message)."""
        pose, pose_cov, twist, twist_cov = odometry_arrays(est)
        P = self._pose
        P[:3] = pose[:3]
        P[3:7] = rpy_to_quaternion(float(pose[3]), float(pose[4]), float(pose[5]))
        P[7:] = pose_cov.ravel()
        T = self._twist
        T[:6] = twist
        T[6:] = twist_cov.ravel()
        struct.pack_into("<iI", self._buf, self._stamp_at, *ns_to_sec_nanosec(est.stamp_ns))
        return bytes(self._buf)


def odometry_writer(frame_id: str, child_frame_id: str) -> Callable[[object], bytes] | None:
    """``write(estimate) -> CDR bytes`` of ekf_node's output (:class:`OdometryCdrWriter`); None
    when rosbags is not importable, or its template is not laid out as the writer expects
    (publish messages instead)."""
    try:
        _typestore()
        return OdometryCdrWriter(frame_id, child_frame_id).write
    except (ImportError, ValueError):
        return None
