"""ekf_node's fusion log: what it fed its Localizer, in order, with its own clock.

The replay of a recorded bag (tools/replay.py) reproduces the published /odometry/filtered
only if it feeds the filter the same messages, in the same order, with the same clock, and
asks for the estimate at the same moments. The recorder cannot know these: it receives every
topic on its own, a little earlier or later than ekf_node, and each node has its own /clock.
So ekf_node says what it did: after each /odometry/filtered it publishes, on
``ekf_node/fusion_log`` (``std_msgs/Int64MultiArray``), one row per call it made on the
Localizer since the previous one:

    [receive_ns, stamp_ns, source]   receive_ns: the node's clock (-1: no clock yet)

``source`` is :data:`OUTPUT` for the estimate it published (stamp_ns: the output's stamp; the
last row), :data:`RESET` for the reset service, and otherwise :func:`source_code` of the input
name (``odom0``, ``cmd_vel``, ``set_pose``, ...): the CRC-32 of the name, so a replay with other
inputs than the node's still reads every row. ``stamp_ns`` is the message's header stamp (the
key the replay finds the recorded message by). ROS-free apart from :func:`to_message`.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable

import numpy as np

TOPIC = "fusion_log"  # private: ~/fusion_log
ROW = 3  # receive_ns, stamp_ns, source
OUTPUT = -1
RESET = -2
NO_CLOCK = -1
LABELS = ("events", "receive_ns stamp_ns source")


def source_code(name: str) -> int:
    """The log's code of input ``name`` (non-negative; OUTPUT and RESET are negative)."""
    return zlib.crc32(name.encode())


def decode_names(names: Iterable[str]) -> dict[int, str]:
    """code -> name for ``names``; raises ValueError if two names share a code."""
    out: dict[int, str] = {}
    for name in names:
        code = source_code(name)
        if out.get(code, name) != name:
            raise ValueError(f"fusion log: inputs '{out[code]}' and '{name}' share the code {code}")
        out[code] = name
    return out


def rows_of(msg) -> np.ndarray:
    """(k, 3) int64 rows of a log message (an rclpy or a rosbags Int64MultiArray)."""
    data = np.asarray(msg.data, dtype=np.int64)
    if data.size % ROW:
        raise ValueError(f"fusion log: {data.size} values is not a whole number of rows of {ROW}")
    return data.reshape(-1, ROW)


def to_message(rows: list[int]):
    """A std_msgs/Int64MultiArray of the flat row list ``rows``."""
    from std_msgs.msg import Int64MultiArray, MultiArrayDimension

    msg = Int64MultiArray()
    n = len(rows) // ROW
    msg.layout.dim = [MultiArrayDimension(label=LABELS[0], size=n, stride=n * ROW),
                      MultiArrayDimension(label=LABELS[1], size=ROW, stride=ROW)]
    msg.data = rows
    return msg
