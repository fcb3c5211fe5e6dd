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
from collections.abc import Callable


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

    from ekf_localization.ros.conversions import message_type_class

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


def cdr_writer(type_name: str) -> tuple[object, Callable[[object], bytes]] | None:
    """(a default message of ``type_name`` as rosbags builds it, ``write(msg) -> CDR bytes``) for a
    publisher that reuses one message and publishes its bytes (rclpy's conversion of an Odometry
    costs about twice rosbags'); None when rosbags is not importable (publish messages instead)."""
    try:
        store = _typestore()
    except ImportError:
        return None
    from rclpy.serialization import serialize_message

    from ekf_localization.ros.conversions import message_type_class

    message = store.deserialize_cdr(serialize_message(message_type_class(type_name)()), type_name)
    serialize = store.serialize_cdr
    return message, lambda msg: bytes(serialize(msg, type_name))  # rclpy publishes bytes, not a memoryview
