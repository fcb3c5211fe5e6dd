"""Input messages taken as CDR bytes and read into measurement records; the output written as
CDR bytes.

rclpy turns each message it takes into Python objects; for a nav_msgs/Odometry that costs about
80 µs here, and at 1 kHz it is a large part of ekf_node's CPU (docs/performance.md). Instead,
a message of every input kind but JointState, in little-endian CDR (what rmw_fastrtps sends),
is read into its record by one compiled call (:func:`measurement_reader`): the record equals
``message_to_measurement`` of rclpy's and of rosbags' message, bit for bit. Any other bytes
(another encoding, a bad layout) are read by rclpy's deserializer, so the node takes exactly
what a typed subscription would. JointState is read by rosbags (:func:`cdr_reader`), whose
objects :mod:`ekf_localization.ros.conversions` reads as it reads a bag's; bytes rosbags
refuses are tried with rclpy's deserializer before the message is called unreadable.

The output is written into a template (rclpy's serialisation of one message, its alignment
padding zeroed) by one compiled call (:class:`OdometryCdrWriter`), and so is each broadcast
transform (:class:`PlanarTransformCdrWriter`). None of these loads rosbags, whose type store
takes a fifth of a second to load: ekf_node starts without it unless an input is JointState.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from ekf_localization.core.angles import yaw_to_quaternion
from ekf_localization.core.kernels import compiled_entry, njit, quaternion_rpy, rpy_quaternion
from ekf_localization.core.measurements import (
    ImuMeasurement,
    Measurement,
    OdometryMeasurement,
    PoseMeasurement,
    TwistMeasurement,
)
from ekf_localization.core.stamps import ns_to_sec_nanosec
from ekf_localization.ros.conversions import (
    MESSAGE_TYPES,
    extra_rows,
    message_to_measurement,
    message_type_class,
    odometry_into,
    output_layout,
    transform_stamped,
)

_MAX_FRAME_NAMES = 64  # frame ids remembered as decoded strings, per reader


class UnreadableMessageError(ValueError):
    """Bytes that neither rosbags nor rclpy can read as the subscribed type."""


@functools.cache
def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def cdr_reader(type_name: str) -> Callable[[bytes], object] | None:
    """``read(raw) -> message`` for CDR bytes of ``type_name`` ("nav_msgs/msg/Odometry") by rosbags,
    then rclpy's deserializer for bytes rosbags refuses, raising :class:`UnreadableMessageError`
    when neither reads them; None when rosbags is not importable (:func:`rclpy_reader`)."""
    try:
        from rosbags.serde import SerdeError

        store = _typestore()
        store.get_msgdef(type_name)
    except ImportError:
        return None
    deserialize = store.deserialize_cdr
    lenient = rclpy_reader(type_name)

    def read(raw: bytes) -> object:
        try:
            return deserialize(raw, type_name)
        except SerdeError:  # rclpy's reader is more lenient (e.g. trailing bytes): never a loss
            return lenient(raw)

    return read


def rclpy_reader(type_name: str) -> Callable[[bytes], object]:
    """``read(raw) -> message`` by rclpy's deserializer, raising :class:`UnreadableMessageError`."""
    from rclpy.serialization import deserialize_message

    msg_class = message_type_class(type_name)

    def read(raw: bytes) -> object:
        try:
            return deserialize_message(raw, msg_class)
        except Exception as exc:  # rclpy raises RMWError (and others) on bad bytes
            raise UnreadableMessageError(f"not a CDR {type_name} ({len(raw)} bytes)") from exc

    return read


# --- the compiled readers ----------------------------------------------------------------------

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
def _read_message(raw, strings: int, quaternion: int, out, scratch, info) -> bool:
    """A message of a header, ``strings - 1`` more strings and ``len(scratch)`` float64s (every
    input kind but JointState) into ``out``: the float64s in order, the quaternion that starts
    at float ``quaternion`` (-1: none) as roll, pitch, yaw (conversions reads it so); the stamp
    and the strings' bytes into ``info`` (_read_header). False: not laid out as expected (nothing
    is said of why: the general reader then reads or refuses it)."""
    at = _read_header(raw, strings, info)
    n = len(scratch)
    if at < 0 or at + 8 * n > len(raw):
        return False
    b = scratch.view(np.uint8)
    for i in range(8 * n):
        b[i] = raw[at + i]
    i = 0
    j = 0
    while i < n:
        if i == quaternion:
            out[j], out[j + 1], out[j + 2] = quaternion_rpy(scratch[i], scratch[i + 1], scratch[i + 2],
                                                            scratch[i + 3])
            i += 4
            j += 3
        else:
            out[j] = scratch[i]
            i += 1
            j += 1
    return True


def _odometry(stamp: int, frame: str, child: str | None, out: np.ndarray) -> OdometryMeasurement:
    return OdometryMeasurement(stamp_ns=stamp, frame_id=frame, child_frame_id=child,
                               pose=out[:6], pose_covariance=out[6:42].reshape(6, 6),
                               twist=out[42:48], twist_covariance=out[48:].reshape(6, 6))


def _pose(stamp: int, frame: str, child: str | None, out: np.ndarray) -> PoseMeasurement:
    return PoseMeasurement(stamp_ns=stamp, frame_id=frame, pose=out[:6], covariance=out[6:].reshape(6, 6))


def _twist(stamp: int, frame: str, child: str | None, out: np.ndarray) -> TwistMeasurement:
    return TwistMeasurement(stamp_ns=stamp, frame_id=frame, twist=out[:6], covariance=out[6:].reshape(6, 6))


def _imu(stamp: int, frame: str, child: str | None, out: np.ndarray) -> ImuMeasurement:
    return ImuMeasurement(stamp_ns=stamp, frame_id=frame,
                          orientation=out[:3], orientation_covariance=out[3:12].reshape(3, 3),
                          angular_velocity=out[12:15], angular_velocity_covariance=out[15:24].reshape(3, 3),
                          linear_acceleration=out[24:27],
                          linear_acceleration_covariance=out[27:].reshape(3, 3))


class _Layout(NamedTuple):
    """How a kind's CDR bytes become its record: the strings (the header's frame id first), the
    float64s after them, where the quaternion starts among those (-1: none), the record."""

    strings: int
    doubles: int
    quaternion: int
    record: Callable[[int, str, str | None, np.ndarray], Measurement]


_LAYOUTS = {  # conversions' readers of each kind, field by field
    "odom": _Layout(2, 85, 3, _odometry),  # position, orientation, covariance 36; twist 6, covariance 36
    "pose": _Layout(1, 43, 3, _pose),  # position, orientation, covariance 36
    "twist": _Layout(1, 42, -1, _twist),  # twist 6, covariance 36
    "imu": _Layout(1, 37, 0, _imu),  # orientation 4, covariance 9; angular velocity 3, 9; acceleration 3, 9
}


class _CompiledReader:
    """``read(raw) -> record`` of one input kind in one compiled call; bytes it does not take
    (another encoding, a bad layout, frame ids that are not UTF-8) go to ``general``."""

    def __init__(self, layout: _Layout, general: Callable[[bytes], Measurement]) -> None:
        self._general = general
        self._strings, self._quaternion, self._record = layout.strings, layout.quaternion, layout.record
        self._size = layout.doubles - (1 if layout.quaternion >= 0 else 0)
        self._scratch = np.zeros(layout.doubles)
        self._info = np.zeros(1 + 2 * layout.strings, dtype=np.int64)
        self._names: dict[bytes, str] = {}
        self._kernel = compiled_entry(_read_message, bytes(16), 1, 1, np.zeros(self._size), self._scratch,
                                      self._info)

    def _name(self, raw: bytes, a: int, b: int) -> str:
        key = raw[a:b]
        name = self._names.get(key)
        if name is None:
            name = key.decode()  # a UnicodeDecodeError is a ValueError: the general reader says
            if len(self._names) < _MAX_FRAME_NAMES:
                self._names[key] = name
        return name

    def __call__(self, raw: bytes) -> Measurement:
        out = np.empty(self._size)
        info = self._info
        if type(raw) is not bytes or not self._kernel(raw, self._strings, self._quaternion, out,
                                                      self._scratch, info):
            return self._general(raw)
        try:
            frame = self._name(raw, info[1], info[2])
            child = self._name(raw, info[3], info[4]) if self._strings == 2 else None
        except UnicodeDecodeError:
            return self._general(raw)
        return self._record(int(info[0]), frame, child, out)


def measurement_reader(kind: str) -> Callable[[bytes], Measurement] | None:
    """``read(raw) -> measurement record`` of an input kind ("odom", "imu", ...) from CDR bytes,
    raising one of conversions.UNREADABLE_ERRORS for bytes that do not read as its type. Every
    kind but "joint" is read by one compiled call, and bytes it does not take by rclpy's reader
    (what a typed subscription would read) + message_to_measurement; "joint" by rosbags (rclpy
    for what rosbags refuses) + message_to_measurement. None: "joint" without rosbags (take
    messages instead)."""
    type_name = MESSAGE_TYPES[kind]
    layout = _LAYOUTS.get(kind)
    reader = rclpy_reader(type_name) if layout is not None else cdr_reader(type_name)
    if reader is None:
        return None

    def general(raw: bytes) -> Measurement:
        return message_to_measurement(kind, reader(raw))

    return general if layout is None else _CompiledReader(layout, general)


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


class _Template:
    """A message as rclpy serialises it, with a distinct sentinel in each field to be written
    later: where those fields are (the layout is rmw's, not worked out by hand).

    The message must end in a header's stamp, ``strings`` strings (the header's frame id first)
    and float64s. rclpy leaves the alignment padding before a string's length and before the
    float64s unset (whatever its buffer held); here it is zeroed, as rosbags writes it."""

    STAMP = (0x5EC0_1DAB, 0x0DEC_0DED)  # the header stamp's sentinel (sec, nanosec)

    def __init__(self, msg, what: str, strings: int) -> None:
        from rclpy.serialization import serialize_message

        self.what = what
        raw = bytearray(serialize_message(msg))
        if raw[1] != _ENCAPSULATION_CDR_LE:
            raise ValueError(f"rclpy's CDR of {what} is not little-endian")
        self.bytes = raw
        self.stamp_at = self.offset(struct.pack("<iI", *self.STAMP))
        at = self.stamp_at + 8
        for _ in range(strings):  # CDR aligns to the data after the 4-byte encapsulation header
            pad = (4 - (at - 4) % 4) % 4
            raw[at:at + pad] = bytes(pad)
            at += pad
            at += 4 + int.from_bytes(raw[at:at + 4], "little")
        pad = (8 - (at - 4) % 8) % 8
        raw[at:at + pad] = bytes(pad)
        self.bytes = bytes(raw)
        self.buf = bytearray(raw)

    def offset(self, packed: bytes) -> int:
        """Where ``packed`` (a field's sentinel bytes, or a run of them) is: once, or ValueError."""
        at = self.bytes.find(packed)
        if at < 0 or self.bytes.count(packed) != 1:
            raise ValueError(f"a field of the {self.what} template is not where it was expected")
        return at

    def block(self, values) -> np.ndarray:
        """A float64 view of ``buf`` over the contiguous run of sentinel ``values``."""
        at = self.offset(np.asarray(values, dtype="<f8").tobytes())
        return np.frombuffer(self.buf, dtype="<f8", count=len(values), offset=at)


class OdometryCdrWriter:
    """The CDR bytes of ekf_node's nav_msgs/Odometry (fixed frame ids), written in place.

    rclpy serialises one template with these frame ids and a distinct sentinel in every float
    and stamp field (:class:`_Template`); the writer checks that the pose and twist blocks are
    contiguous there, and then writes each estimate's numbers into a copy of the template: the
    bytes equal both rclpy's and rosbags' serialisation of
    :func:`~ekf_localization.ros.conversions.fill_odometry`'s message
    (``test/test_ros_conversions.py``), at a fraction of their cost.
    """

    _POSE = 3 + 4 + 36  # position, orientation, covariance
    _TWIST = 3 + 3 + 36  # linear, angular, covariance

    def __init__(self, frame_id: str, child_frame_id: str) -> None:
        msg = message_type_class("nav_msgs/msg/Odometry")()
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
        msg.header.stamp.sec, msg.header.stamp.nanosec = _Template.STAMP
        template = _Template(msg, "Odometry", strings=2)
        self._buf, self._stamp_at = template.buf, template.stamp_at
        self._pose = template.block(pose)
        self._twist = template.block(twist)
        fields, sel = output_layout((0, 1, 5, 6, 7, 11))
        self._fill = compiled_entry(_fill_odometry, self._pose, self._twist, np.zeros(6), np.zeros((6, 6)),
                                    fields, sel, np.zeros((0, 3)))

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
    when its template is not laid out as the writer expects (publish messages instead)."""
    try:
        return OdometryCdrWriter(frame_id, child_frame_id).write
    except ValueError:
        return None


class PlanarTransformCdrWriter:
    """The CDR bytes of a tf2_msgs/TFMessage holding one planar transform ``parent`` -> ``child``
    (conversions.transform_stamped's message), written in place as :class:`OdometryCdrWriter`
    writes: byte for byte rosbags' serialisation, and what rclpy reads back as that message
    (``test/test_tf_messages.py``)."""

    _FIELDS = struct.Struct("<7d")  # translation x y z, rotation x y z w

    def __init__(self, message_type, parent: str, child: str) -> None:
        sentinels = np.arange(1, 8) + 0.5
        tf = transform_stamped(0, parent, child, (0.0, 0.0, 0.0))
        tf.header.stamp.sec, tf.header.stamp.nanosec = _Template.STAMP
        t, r = tf.transform.translation, tf.transform.rotation
        t.x, t.y, t.z, r.x, r.y, r.z, r.w = (float(v) for v in sentinels)
        template = _Template(message_type(transforms=[tf]), "TFMessage", strings=2)
        self._buf, self._stamp_at = template.buf, template.stamp_at
        self._at = template.offset(np.asarray(sentinels, dtype="<f8").tobytes())

    def write(self, stamp_ns: int, xyyaw: tuple[float, float, float]) -> bytes:
        """The bytes of ``transform_stamped(stamp_ns, parent, child, xyyaw)`` in a TFMessage."""
        qx, qy, qz, qw = yaw_to_quaternion(float(xyyaw[2]))
        self._FIELDS.pack_into(self._buf, self._at, float(xyyaw[0]), float(xyyaw[1]), 0.0, qx, qy, qz, qw)
        struct.pack_into("<iI", self._buf, self._stamp_at, *ns_to_sec_nanosec(stamp_ns))
        return bytes(self._buf)
