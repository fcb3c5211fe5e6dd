"""A bounded map that forgets the least recently used key (no ROS imports).

Per-frame bookkeeping (which (input, frame) pairs need no transform, which missing transforms
were already warned about) is keyed by names that come from messages: 1000 distinct frame ids
must not make 1000 entries. :class:`Lru` keeps ``cap`` of them and counts what it forgot
(ekf_node's /diagnostics: ``frame_cache_*``).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable
from typing import Any


class Lru:
    """``get`` / ``put`` on at most ``cap`` keys; the least recently used goes first."""

    def __init__(self, cap: int) -> None:
        self.cap = cap
        self.evictions = 0
        self._items: OrderedDict[Hashable, Any] = OrderedDict()

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._items

    def get(self, key: Hashable, default: Any = None) -> Any:
        """The value of ``key`` (now the most recently used), or ``default``."""
        items = self._items
        if key not in items:
            return default
        items.move_to_end(key)
        return items[key]

    def put(self, key: Hashable, value: Any) -> None:
        """Set ``key``; beyond ``cap`` keys the least recently used is forgotten (counted)."""
        items = self._items
        items[key] = value
        items.move_to_end(key)
        if len(items) > self.cap:
            items.popitem(last=False)
            self.evictions += 1
