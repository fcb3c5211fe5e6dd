"""ROS messages <-> measurement records and estimates, in plain Python and numpy.

:func:`message_to_measurement` is the one conversion of an input message: ekf_node calls it
on the messages its typed subscriptions take, and the bag tools (``tools/replay.py``) on
the messages ``rosbags`` reads from a bag. It is duck-typed on attribute names
(``msg.header.stamp.sec``, ``msg.twist.twist.linear.x``, ``msg.twist.covariance`` ...), which
both kinds of message share (covariances are array.array in one and numpy arrays in the
other). Stamps become integer nanoseconds (``core.units.stamp_to_ns``), never float
seconds. Message classes are imported only by the writers, so the readers work without ROS.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np

from ekf_localization.core.angles import quaternion_to_rpy, rpy_to_quaternion, wrap_angle, yaw_to_quaternion
from ekf_localization.core.frames import RigidTransform, TransformBuffer
from ekf_localization.core.localizer import Estimate
from ekf_localization.core.measurements import (
    ControlCommand,
    Measurement,
)
from ekf_localization.core.units import ns_to_sec_nanosec, stamp_to_ns
from ekf_localization.inputs import KINDS
from ekf_localization.inputs.kind import twist6

Message = Any  # an rclpy or a rosbags message: read by attribute names only

# Output variance of the components a planar model does not estimate (z, roll, pitch, their
# rates; vy for the differential drive): they are zero by construction.
PLANAR_FIXED_VARIANCE = 1e-9


def twist_to_control(msg: Message, stamp_ns: int) -> ControlCommand:
    """geometry_msgs/Twist (cmd_vel has no header: stamped on receipt)."""
    return ControlCommand(stamp_ns=int(stamp_ns), twist=twist6(msg))


def control_from_message(msg: Message, receive_ns: int) -> ControlCommand:
    """cmd_vel as Twist (applied at its receive time) or TwistStamped (at its header stamp)."""
    header = getattr(msg, "header", None)
    if header is not None:
        return ControlCommand(stamp_ns=stamp_to_ns(header.stamp), twist=twist6(msg.twist))
    return twist_to_control(msg, receive_ns)


MESSAGE_TYPES = {name: kind.message_type for name, kind in KINDS.items()}


# what message_to_measurement raises for a message whose fields do not read as its kind's
UNREADABLE_ERRORS = (AttributeError, TypeError, ValueError)


def message_to_measurement(kind: str, msg: Message) -> Measurement:
    """The record of a message of input kind ``kind`` (a key of ekf_localization.inputs.KINDS).

    Raises one of :data:`UNREADABLE_ERRORS` for a message whose fields do not read as that
    kind's (the caller counts it as ``unreadable_message``). Values are not checked here: a
    non-finite value, or a covariance of the wrong size (read as NaNs), is rejected by the
    Localizer with its reason."""
    return KINDS[kind].read(msg)


def message_type_class(type_name: str):
    """'nav_msgs/msg/Odometry' -> the rclpy message class (imported on demand)."""
    import importlib

    pkg, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def message_class(kind: str):
    """The rclpy message class of an input kind."""
    return message_type_class(MESSAGE_TYPES[kind])


# --- estimate -> messages --------------------------------------------------------------------


_FIXED_COVARIANCE = np.diag(np.full(12, PLANAR_FIXED_VARIANCE))  # copied, never written


@lru_cache(maxsize=16)
def _odometry_layout(state_fields: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, tuple, tuple]:
    """The state components of the 12 pose and twist fields, the fields, and their blocks (found once
    per state layout)."""
    sel = np.array([i for i, f in enumerate(state_fields) if f < 12], dtype=np.intp)
    fields = np.array([state_fields[i] for i in sel], dtype=np.intp)
    return sel, fields, np.ix_(sel, sel), np.ix_(fields, fields)


def odometry_arrays(est: Estimate) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(pose [x y z roll pitch yaw], pose 6x6 covariance, twist [vx vy vz wx wy wz], twist 6x6 covariance).

    Components the model does not estimate are 0 with variance PLANAR_FIXED_VARIANCE, except
    those the estimate carries outside its state (``est.extra``: z, roll, pitch with a tilt input).
    Pose-twist cross-covariances are dropped (nav_msgs/Odometry has no place for them).
    """
    sel, fields, block_sel, block_fields = _odometry_layout(tuple(est.state_fields))
    vals = np.zeros(12)
    cov = _FIXED_COVARIANCE.copy()
    vals[fields] = np.asarray(est.state, dtype=float)[sel]
    cov[block_fields] = np.asarray(est.covariance, dtype=float)[block_sel]
    for f, value, variance in est.extra:
        vals[int(f)] = value
        cov[int(f), int(f)] = max(variance, PLANAR_FIXED_VARIANCE)
    return vals[:6], cov[:6, :6].copy(), vals[6:], cov[6:, 6:].copy()


def estimate_to_odometry(est: Estimate, frame_id: str, child_frame_id: str, msg=None):
    """nav_msgs/Odometry: pose in ``frame_id``, twist in ``child_frame_id`` (REP-105), 6x6 covariances.

    ``msg``: an Odometry to fill instead of a new one (a publisher reuses one: rclpy's
    ``publish`` serialises the message before it returns); its covariance arrays are written in
    place."""
    pose, pose_cov, twist, twist_cov = odometry_arrays(est)
    if msg is None:
        from nav_msgs.msg import Odometry

        msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(est.stamp_ns)
    msg.header.frame_id = frame_id
    msg.child_frame_id = child_frame_id
    p = msg.pose.pose
    x, y, z, roll, pitch, yaw = pose.tolist()
    p.position.x, p.position.y, p.position.z = x, y, z
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = rpy_to_quaternion(roll, pitch, yaw)
    msg.pose.covariance[:] = pose_cov.ravel()
    t = msg.twist.twist
    t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z = twist.tolist()
    msg.twist.covariance[:] = twist_cov.ravel()
    return msg


def planar_pose(est: Estimate) -> tuple[float, float, float]:
    """(x, y, yaw) of an estimate."""
    f = {fld: i for i, fld in enumerate(est.state_fields)}
    return float(est.state[f[0]]), float(est.state[f[1]]), float(est.state[f[5]])


def map_to_odom(map_base: tuple[float, float, float],
                odom_base: tuple[float, float, float]) -> tuple[float, float, float]:
    """Planar map->odom = (map->base_link) ∘ (odom->base_link)⁻¹, each as (x, y, yaw)."""
    mx, my, myaw = map_base
    ox, oy, oyaw = odom_base
    yaw = myaw - oyaw
    c, s = math.cos(yaw), math.sin(yaw)
    return mx - (c * ox - s * oy), my - (s * ox + c * oy), wrap_angle(yaw)


def transform_stamped(stamp_ns: int, parent: str, child: str, xyyaw: tuple[float, float, float], tf=None):
    """geometry_msgs/TransformStamped of a planar transform (``tf``: one to fill instead of a new one)."""
    if tf is None:
        from geometry_msgs.msg import TransformStamped

        tf = TransformStamped()
    tf.header.stamp.sec, tf.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    tf.header.frame_id = parent
    tf.child_frame_id = child
    tf.transform.translation.x, tf.transform.translation.y = float(xyyaw[0]), float(xyyaw[1])
    qx, qy, qz, qw = yaw_to_quaternion(float(xyyaw[2]))
    r = tf.transform.rotation
    r.x, r.y, r.z, r.w = qx, qy, qz, qw
    return tf


def transform_to_planar(tf_msg: Message) -> tuple[float, float, float]:
    """(x, y, yaw) of a geometry_msgs/TransformStamped."""
    t = tf_msg.transform.translation
    q = tf_msg.transform.rotation
    return float(t.x), float(t.y), quaternion_to_rpy(q.x, q.y, q.z, q.w)[2]


def transforms_in_message(msg: Message) -> list[tuple[str, str, RigidTransform, int]]:
    """(parent, child, T_parent,child, stamp ns) of each transform in a tf2_msgs/TFMessage."""
    out = []
    for tf in msg.transforms:
        t, q = tf.transform.translation, tf.transform.rotation
        out.append((str(tf.header.frame_id), str(tf.child_frame_id),
                    RigidTransform.from_quaternion((t.x, t.y, t.z), (q.x, q.y, q.z, q.w)),
                    stamp_to_ns(tf.header.stamp)))
    return out


def feed_transforms(buffer: TransformBuffer, msg: Message, static: bool) -> int:
    """Add a TFMessage (from /tf, or /tf_static when ``static``) to ``buffer``; returns the count."""
    items = transforms_in_message(msg)
    for parent, child, T, stamp in items:
        if static:
            buffer.set_static(parent, child, T)
        else:
            buffer.add(parent, child, T, stamp)
    return len(items)


def planar_transform(T: RigidTransform) -> tuple[float, float, float]:
    """(x, y, yaw) of a core RigidTransform."""
    return float(T.translation[0]), float(T.translation[1]), math.atan2(T.rotation[1, 0], T.rotation[0, 0])
