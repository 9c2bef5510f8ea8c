"""Results remembered by the content they were computed from: an explicit, bounded object.

A calibration worker sees the same images and recordings again and again (every live job has
the poses of the one before, plus one); keyed by the files' SHA-256 (session files never change
once written), the work on each file is done once. The owner (the worker, a test, a script)
creates the memo and hands it to the calibration; nothing is remembered between calibrations
that were not given the same memo.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class LruMemo(Generic[K, V]):
    """A thread-safe map of at most `max_items` entries; the least recently used is dropped."""

    def __init__(self, max_items: int) -> None:
        if max_items < 1:
            raise ValueError(f"a memo holds at least 1 item, not {max_items}")
        self.max_items = max_items
        self._items: OrderedDict[K, V] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: K) -> V | None:
        """The value remembered for `key` (now the most recently used), or None."""
        with self._lock:
            value = self._items.get(key)
            if value is not None:
                self._items.move_to_end(key)
            return value

    def put(self, key: K, value: V) -> None:
        """Remember `value` for `key`, dropping the least recently used beyond the bound."""
        with self._lock:
            self._items[key] = value
            self._items.move_to_end(key)
            while len(self._items) > self.max_items:
                self._items.popitem(last=False)

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)
