"""TF over DDS: read ``/tf`` and ``/tf_static`` into a core TransformBuffer, publish ``/tf``.

Speaks tf2's wire protocol directly: ``tf2_msgs/msg/TFMessage`` on ``/tf`` (reliable,
depth 100) and ``/tf_static`` (reliable, transient local, depth 100), the QoS of tf2_ros's
TransformListener and broadcasters. So the same code runs against a real tf2 stack (the
system's tf2_msgs) and in the venv (tf2_msgs built by scripts/setup_env.sh), and
``bag_replay`` feeds the same buffer from a bag. Without any tf2_msgs the node logs one
line and works without TF (inputs must then be in the filter's frames or covered by the
``static_transforms`` parameter).
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from ekf_localization.core.frames import TransformBuffer
from ekf_localization.ros.conversions import (
    Message,
    feed_transforms,
    transform_stamped,
    transforms_in_message,
)

TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
TF_STATIC_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)


def tf_message_class() -> type | None:
    """tf2_msgs.msg.TFMessage, or None when no tf2_msgs is installed."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


class TfListener:
    """Feeds ``buffer`` from /tf and /tf_static (what tf2_ros.TransformListener subscribes)."""

    def __init__(self, node: Node, buffer: TransformBuffer,
                 callback_wrapper: Callable[[str, Callable], Callable] = lambda _name, fn: fn,
                 static_filter: Callable[[list], list] | None = None) -> None:
        """``static_filter``: given /tf_static's (parent, child, T, stamp) items, the ones to feed."""
        msg_type = tf_message_class()
        if msg_type is None:
            raise ImportError("tf2_msgs")
        self.buffer = buffer
        self.received = 0
        self._static_filter = static_filter
        self._subs = [
            node.create_subscription(msg_type, TF_TOPIC, callback_wrapper("tf", self._on_tf), TF_QOS),
            node.create_subscription(msg_type, TF_STATIC_TOPIC,
                                     callback_wrapper("tf_static", self._on_tf_static), TF_STATIC_QOS),
        ]

    def _on_tf(self, msg: Message) -> None:
        self.received += feed_transforms(self.buffer, msg, static=False)

    def _on_tf_static(self, msg: Message) -> None:
        if self._static_filter is None:
            self.received += feed_transforms(self.buffer, msg, static=True)
            return
        for parent, child, T, _stamp in self._static_filter(transforms_in_message(msg)):
            self.buffer.set_static(parent, child, T)
            self.received += 1


class TfBroadcaster:
    """Publishes planar transforms on /tf (tf2_ros.TransformBroadcaster's topic and QoS)."""

    def __init__(self, node: Node) -> None:
        self._type = tf_message_class()
        if self._type is None:
            raise ImportError("tf2_msgs")
        self._pub = node.create_publisher(self._type, TF_TOPIC, TF_QOS)
        self._msg = self._type(transforms=[transform_stamped(0, "", "", (0.0, 0.0, 0.0))])  # refilled

    def send_planar(self, stamp_ns: int, parent: str, child: str, xyyaw: tuple[float, float, float]) -> None:
        """Publish ``transform_stamped(stamp_ns, parent, child, xyyaw)`` in a TFMessage, when
        anyone listens (/tf is volatile: a later listener gets later messages only). One message
        is refilled each time: rclpy's ``publish`` serialises it before it returns."""
        if self._pub.get_subscription_count() == 0:
            return
        transform_stamped(stamp_ns, parent, child, xyyaw, self._msg.transforms[0])
        self._pub.publish(self._msg)
