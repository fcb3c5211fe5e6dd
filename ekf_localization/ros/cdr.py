"""Input messages taken as CDR bytes and read by rosbags, the bag tools' own reader; the output
written as CDR bytes.

rclpy turns each message it takes into Python objects; for a nav_msgs/Odometry that costs about
80 µs here, and at 1 kHz it is a large part of ekf_node's CPU (docs/performance.md). rosbags
reads the same bytes in about 23 µs into objects with the same fields, which
:mod:`ekf_localization.ros.conversions` reads as it reads a bag's. Bytes rosbags refuses are tried
with rclpy's own deserializer before the message is called unreadable, so nothing rclpy accepts
is lost. Without rosbags installed, :func:`cdr_reader` returns None and the node subscribes to
messages as usual.

A nav_msgs/Odometry in little-endian CDR (what rmw_fastrtps sends) is read into its measurement
record by one compiled call (:func:`measurement_reader`): the record equals
``message_to_measurement`` of rosbags' message, bit for bit; any other bytes take that path.
The output is written into a template by one compiled call (:class:`OdometryCdrWriter`).
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable

import numpy as np

from ekf_localization.core.kernels import compiled_entry, njit, quaternion_rpy, rpy_quaternion
from ekf_localization.core.measurements import Measurement, OdometryMeasurement
from ekf_localization.core.stamps import ns_to_sec_nanosec
from ekf_localization.ros.conversions import (
    MESSAGE_TYPES,
    extra_rows,
    message_to_measurement,
    message_type_class,
    odometry_into,
    output_layout,
)

_MAX_FRAME_NAMES = 64  # frame ids remembered as decoded strings, per reader


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


# --- the compiled Odometry reader ---------------------------------------------------------------

_ODOMETRY_DOUBLES = 85  # pose: position 3, orientation 4, covariance 36; twist: 3, 3, covariance 36
_ENCAPSULATION_CDR_LE = 1  # the second byte of the encapsulation header: plain CDR, little-endian


@njit(cache=True, inline="always")
def _u32(raw, at: int) -> int:
    """The little-endian uint32 at ``raw[at]``."""
    return np.int64(raw[at]) | (np.int64(raw[at + 1]) << 8) | (np.int64(raw[at + 2]) << 16) \
        | (np.int64(raw[at + 3]) << 24)


@njit(cache=True, inline="always")
def _read_header(raw, strings: int, info) -> int:
    """A little-endian CDR message that starts with a std_msgs/Header and ``strings - 1`` more
    strings: its stamp in ns into ``info[0]``, string j's bytes (no terminating NUL) at
    ``info[1 + 2j]:info[2 + 2j]``; the offset of the 8-aligned field after them, or -1 when the
    bytes are not laid out so. CDR aligns to the data after the 4-byte encapsulation header."""
    size = len(raw)
    if size < 12 or raw[0] != 0 or raw[1] != _ENCAPSULATION_CDR_LE:
        return -1
    sec = np.int64(_u32(raw, 4))
    if sec >= 0x8000_0000:  # an int32
        sec -= 0x1_0000_0000
    info[0] = sec * 1_000_000_000 + np.int64(_u32(raw, 8))
    at = 12
    for j in range(strings):
        at += (4 - (at - 4) % 4) % 4
        if at + 4 > size:
            return -1
        length = _u32(raw, at)  # with its NUL
        at += 4
        if length < 1 or at + length > size or raw[at + length - 1] != 0:
            return -1
        info[1 + 2 * j] = at
        info[2 + 2 * j] = at + length - 1
        at += length
    return at + (8 - (at - 4) % 8) % 8


@njit(cache=True)
def _read_odometry(raw, out, scratch, info) -> bool:
    """nav_msgs/Odometry bytes into ``out`` (84,): pose [x y z roll pitch yaw], its covariance
    (36), twist [vx vy vz wx wy wz], its covariance (36), as conversions.odometry_to_measurement
    reads them; the stamp and the frame ids' bytes into ``info`` (_read_header). False: not
    laid out as expected (nothing is said of why: the general reader then reads or refuses it)."""
    at = _read_header(raw, 2, info)
    if at < 0 or at + 8 * _ODOMETRY_DOUBLES > len(raw):
        return False
    b = scratch.view(np.uint8)
    for i in range(8 * _ODOMETRY_DOUBLES):
        b[i] = raw[at + i]
    out[0], out[1], out[2] = scratch[0], scratch[1], scratch[2]
    out[3], out[4], out[5] = quaternion_rpy(scratch[3], scratch[4], scratch[5], scratch[6])
    for i in range(36):
        out[6 + i] = scratch[7 + i]
    for i in range(42):  # twist and its covariance
        out[42 + i] = scratch[43 + i]
    return True


class _OdometryReader:
    """``read(raw) -> OdometryMeasurement`` in one compiled call; bytes it does not take (another
    encoding, a bad layout, frame ids that are not UTF-8) go to ``general``."""

    def __init__(self, general: Callable[[bytes], Measurement]) -> None:
        self._general = general
        self._scratch = np.zeros(_ODOMETRY_DOUBLES)
        self._info = np.zeros(5, dtype=np.int64)
        self._names: dict[bytes, str] = {}
        self._kernel = compiled_entry(_read_odometry, bytes(16), np.zeros(84), self._scratch, self._info)

    def _name(self, raw: bytes, a: int, b: int) -> str:
        key = raw[a:b]
        name = self._names.get(key)
        if name is None:
            name = key.decode()  # a UnicodeDecodeError is a ValueError: the general reader says
            if len(self._names) < _MAX_FRAME_NAMES:
                self._names[key] = name
        return name

    def __call__(self, raw: bytes) -> Measurement:
        out = np.empty(84)
        info = self._info
        if type(raw) is not bytes or not self._kernel(raw, out, self._scratch, info):
            return self._general(raw)
        try:
            frame, child = self._name(raw, info[1], info[2]), self._name(raw, info[3], info[4])
        except UnicodeDecodeError:
            return self._general(raw)
        return OdometryMeasurement(stamp_ns=int(info[0]), frame_id=frame, child_frame_id=child,
                                   pose=out[:6], pose_covariance=out[6:42].reshape(6, 6),
                                   twist=out[42:48], twist_covariance=out[48:].reshape(6, 6))


def measurement_reader(kind: str) -> Callable[[bytes], Measurement] | None:
    """``read(raw) -> measurement record`` of an input kind ("odom", "imu", ...) from CDR bytes,
    raising one of conversions.UNREADABLE_ERRORS for bytes that do not read as its type; None
    when rosbags is not importable (take messages instead). Odometry is read by one compiled call."""
    reader = cdr_reader(MESSAGE_TYPES[kind])
    if reader is None:
        return None

    def general(raw: bytes) -> Measurement:
        return message_to_measurement(kind, reader(raw))

    return _OdometryReader(general) if kind == "odom" else general


# --- the output ------------------------------------------------------------------------------


@njit(cache=True)
def _fill_odometry(pose, twist, x, P, fields, sel, extra) -> None:
    """conversions.odometry_into's numbers written into the template's pose block (43: position,
    quaternion, covariance) and twist block (42: twist, covariance)."""
    vals = np.empty(12)
    odometry_into(x, P, fields, sel, extra, vals, pose[7:], twist[6:])
    pose[0], pose[1], pose[2] = vals[0], vals[1], vals[2]
    pose[3], pose[4], pose[5], pose[6] = rpy_quaternion(vals[3], vals[4], vals[5])
    for i in range(6):
        twist[i] = vals[6 + i]


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
        fields, sel = output_layout((0, 1, 5, 6, 7, 11))
        self._fill = compiled_entry(_fill_odometry, self._pose, self._twist, np.zeros(6), np.zeros((6, 6)),
                                    fields, sel, np.zeros((0, 3)))

    def _block(self, template: bytes, values) -> object:
        """A float64 view of self._buf over the contiguous run of ``values`` in ``template``."""
        first = struct.pack("<d", values[0])
        at = template.find(first)
        if at < 0 or template.count(first) != 1 or template[at:at + 8 * len(values)] != \
                np.asarray(values, dtype="<f8").tobytes():
            raise ValueError("a block of the Odometry template is not contiguous")
        return np.frombuffer(self._buf, dtype="<f8", count=len(values), offset=at)

    def write(self, est) -> bytes:
        """The CDR bytes of the estimate (fill_odometry's message), in one compiled call."""
        fields, sel = output_layout(est.state_fields)
        x = np.ascontiguousarray(est.state, dtype=float)  # the compiled entry reads them as such
        P = np.ascontiguousarray(est.covariance, dtype=float)
        self._fill(self._pose, self._twist, x, P, fields, sel, extra_rows(est))
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
