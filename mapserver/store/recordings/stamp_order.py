"""Putting a recording's scans in stamp order: loggers write messages as they arrive,
and a stamp may come a little before the one written above it (the Intel log has four
such, by up to 0.9 s)."""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Iterator
from typing import Generic, TypeVar

Item = TypeVar("Item")


class StampOrder(Generic[Item]):
    """Holds items until ``window_s`` [s] of newer stamps have been pushed, then lets
    them out in stamp order (ties in push order). An item stamped before one already
    let out is dropped and counted in ``late``: a scan stream never goes back."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self.late = 0
        self._heap: list[tuple[float, int, Item]] = []
        self._tie = itertools.count()
        self._newest = float("-inf")
        self._released = float("-inf")

    def push(self, stamp: float, item: Item) -> Iterator[Item]:
        """Add ``item`` at ``stamp`` [s]; yields the items now due."""
        if stamp < self._released:
            self.late += 1
        else:
            heapq.heappush(self._heap, (stamp, next(self._tie), item))
            self._newest = max(self._newest, stamp)
        while self._heap and self._heap[0][0] <= self._newest - self.window_s:
            yield self._pop()

    def flush(self) -> Iterator[Item]:
        """The items still held, in stamp order (at the end of the recording)."""
        while self._heap:
            yield self._pop()

    def _pop(self) -> Item:
        stamp, _, item = heapq.heappop(self._heap)
        self._released = stamp
        return item
