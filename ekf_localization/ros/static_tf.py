"""ekf_node's ``static_transforms`` on /tf_static, and other publishers of the same frames.

The parameter's transforms are published once at start as tf2_ros's StaticTransformBroadcaster
does (one TFMessage, reliable, transient local, depth 100), so every node on the robot (a
tag_localizer, rviz) sees the same mount ekf_node fuses with. When another node publishes one of
those child frames on /tf_static with a different value, ekf_node keeps its parameter's (the
transform buffer pins them: the filter's result depends on its own parameters, and a bag
replayed with a new params file uses the new value, not the one recorded) and reports the
conflict once, in the log and on /diagnostics: tf2 listeners elsewhere keep whichever of the
two they received last, so it has to be fixed where the frame is defined.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.node import Node

from ekf_localization.core.angles import matrix_to_rpy, rpy_to_quaternion
from ekf_localization.core.frames import RigidTransform
from ekf_localization.core.units import ns_to_sec_nanosec
from ekf_localization.ros.tf_io import TF_STATIC_QOS, TF_STATIC_TOPIC

SAME_TOLERANCE = 1e-6  # m, and rad through the rotation matrix: a value within it is the same transform

Entry = tuple[str, str, tuple[float, ...]]  # (parent, child, (x, y, z, yaw, pitch, roll))
Item = tuple[str, str, RigidTransform, int]  # conversions.transforms_in_message's (parent, child, T, stamp)


def _text(xyz_ypr: tuple[float, ...] | np.ndarray) -> str:
    return " ".join(f"{float(v) + 0.0:.6g}" for v in xyz_ypr)  # + 0.0: -0 prints as 0


def _xyz_ypr(T: RigidTransform) -> tuple[float, ...]:
    roll, pitch, yaw = matrix_to_rpy(T.rotation)
    return (*(float(v) for v in T.translation), float(yaw), float(pitch), float(roll))


def static_message(msg_type: type, entries: tuple[Entry, ...], stamp_ns: int):
    """One ``msg_type`` (tf2_msgs/TFMessage) holding every entry, each stamped ``stamp_ns``."""
    from geometry_msgs.msg import TransformStamped

    out = []
    for parent, child, (x, y, z, yaw, pitch, roll) in entries:
        tf = TransformStamped()
        tf.header.stamp.sec, tf.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
        tf.header.frame_id, tf.child_frame_id = parent, child
        t, r = tf.transform.translation, tf.transform.rotation
        t.x, t.y, t.z = float(x), float(y), float(z)
        r.x, r.y, r.z, r.w = rpy_to_quaternion(roll, pitch, yaw)
        out.append(tf)
    return msg_type(transforms=out)


class StaticTransforms:
    """Publishes ``entries`` on /tf_static (nothing when empty) and filters what /tf_static brings.

    :meth:`filter` is the TfListener's hook: it keeps a transform for an entry's child out of
    the buffer (the entry is pinned there) and reports one that differs from the entry (another
    node's; ekf_node's own echo and identical copies do not) through ``warn`` once per child."""

    def __init__(self, node: Node, msg_type: type, entries: tuple[Entry, ...], stamp_ns: int,
                 warn: Callable[[str], None]) -> None:
        self._entries = {child: (parent, RigidTransform.from_xyz_ypr(*v), v) for parent, child, v in entries}
        self._warn = warn
        self.conflicts: dict[str, str] = {}  # child -> the message reported
        self._pub = None
        if entries:  # kept: a transient-local message lives as long as its publisher
            self._pub = node.create_publisher(msg_type, TF_STATIC_TOPIC, TF_STATIC_QOS)
            self._pub.publish(static_message(msg_type, entries, stamp_ns))

    def filter(self, items: list[Item]) -> list[Item]:
        """The /tf_static transforms to feed the buffer (those of frames without an entry)."""
        out = []
        for parent, child, T, stamp in items:
            own = self._entries.get(child.strip().lstrip("/"))
            if own is None:
                out.append((parent, child, T, stamp))
                continue
            own_parent, own_T, own_values = own
            same_parent = parent.strip().lstrip("/") == own_parent
            if same_parent and np.allclose(T.translation, own_T.translation, rtol=0.0, atol=SAME_TOLERANCE) \
                    and np.allclose(T.rotation, own_T.rotation, rtol=0.0, atol=SAME_TOLERANCE):
                continue
            key = child.strip().lstrip("/")
            if key not in self.conflicts:
                self.conflicts[key] = text = (
                    f"/tf_static from another node has {parent} -> {child} = {_text(_xyz_ypr(T))} "
                    f"(x y z yaw pitch roll), static_transforms has {own_parent} -> {key} = "
                    f"{_text(own_values)}: ekf_node uses its static_transforms; other nodes keep "
                    "whichever they received last: put one value where the frame is defined")
                self._warn(text)
        return out

    def status(self, name: str) -> list[DiagnosticStatus]:
        """``<name>: static_transforms``: OK, or WARN naming each conflict ([] without entries)."""
        if not self._entries:
            return []
        st = DiagnosticStatus(name=f"{name}: static_transforms", hardware_id=name)
        st.values = [KeyValue(key="published", value=str(len(self._entries)))]
        if self.conflicts:
            st.level = DiagnosticStatus.WARN
            st.message = "; ".join(self.conflicts.values())
            st.values += [KeyValue(key=f"conflict {child}", value=text)
                          for child, text in self.conflicts.items()]
        else:
            st.level, st.message = DiagnosticStatus.OK, f"{len(self._entries)} published on /tf_static"
        return [st]
