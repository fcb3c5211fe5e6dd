"""The same message delivered twice is fused once (no ROS imports).

A DDS redelivery, a bag recorded from two bridges, a driver that republishes its last
message: the copy has the same stamp and content as one already taken, and fusing it again
would count its information twice (an overconfident covariance). :class:`RecentMessages`
remembers, per input, the (stamp, content digest) of its last ``depth`` messages: bounded
memory and one set lookup per message.
"""

from __future__ import annotations

import dataclasses
from collections import deque

import numpy as np

DUPLICATE_DEPTH = 16  # messages remembered per input


_FIELDS: dict[type, tuple[str, ...]] = {}  # a record class's field names, found once


def content_digest(message: object) -> int:
    """A digest of a record's fields (arrays by their bytes); equal records give equal digests."""
    names = _FIELDS.get(type(message))
    if names is None and dataclasses.is_dataclass(message):
        names = _FIELDS[type(message)] = tuple(f.name for f in dataclasses.fields(message))
    if names is not None:
        values = [getattr(message, name) for name in names]
    else:
        values = list(vars(message).values()) if hasattr(message, "__dict__") else [message]
    return hash(tuple([v.tobytes() if isinstance(v, np.ndarray) else v if type(v) in _EXACT else repr(v)
                       for v in values]))


_EXACT = (int, str)  # hashed as they are: equal values give equal hashes (a float's nan would not)


class RecentMessages:
    """Per source, the (stamp, digest) of its last ``depth`` messages."""

    def __init__(self, depth: int = DUPLICATE_DEPTH) -> None:
        self._depth = depth
        # per source: its last keys in arrival order, and the same keys as a set (looked up)
        self._seen: dict[str, tuple[deque[tuple[int, int]], set[tuple[int, int]]]] = {}

    def is_duplicate(self, source: str, stamp_ns: int, digest: int) -> bool:
        """True when ``source`` gave this (stamp, digest) among its last messages; otherwise it
        is remembered and False."""
        seen = self._seen.get(source)
        if seen is None:
            seen = self._seen[source] = (deque(), set())
        order, keys = seen
        key = (int(stamp_ns), digest)
        if key in keys:
            return True
        if order and len(order) >= self._depth:
            keys.discard(order.popleft())
        order.append(key)
        keys.add(key)
        return False

    def clear(self) -> None:
        """Forget them (a filter reset: a bag played again is not a duplicate)."""
        self._seen.clear()
