"""The costmap kept up to the belief beside the fusion thread, over a mirror of the belief.

The fusion thread writes the live belief under the map lock. Composing and inflating
the costmap from it under that lock (tens of milliseconds once a fleet's scans cover
the floor) held up every scan queued behind it, and so did copying the whole belief
for a snapshot or a read at another stamp. So the costmap is built from a mirror: a
second ``BeliefGrid`` brought up to the live one by copying only the boxes fused since
its last refresh (``BeliefGrid.copy_cells_from``: a copy of those cells, under the map
lock), then composed and inflated under the follower's own lock while fusion goes on.

- ``fused(boxes, version)`` (the fusion thread, holding the map lock) records what the
  live belief changed and wakes the follower's thread (``map-costmap``), which refreshes
  the costmap beside fusion ``refresh_s`` [s] after its last refresh (by a reader or
  itself), so it lags the belief by about that at most when nobody reads.
- ``costmap_current()`` brings mirror and costmap up to every scan fused so far and
  holds them for the caller (so a read sees every acknowledged scan);
  ``mirror_current()`` brings only the mirror up (a snapshot, a belief read): the boxes
  it copied wait for the costmap's next refresh.

The mirror costs one more belief's memory (12 B a cell, 13 under ``dual``).

Lock order: the follower's lock, then the map lock; the map lock's holders never take
the follower's (``fused`` takes no lock).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

from mapserver.core.belief import BeliefGrid, CellBox
from mapserver.costmap.layered import LayeredCostmap, merge_regions
from mapserver.costmap.layers import Layer

MAX_DIRTY_BOXES = 256  # fused boxes kept apart for the costmap; beyond, merged


class CostmapFollower:
    """The costmap and the mirror it is built from, following a live belief.

    live: the belief the fusion thread writes (read only under ``map_lock``).
    mirror: a grid of the same geometry and policy, holding the live one's state now.
    layers: a function giving the costmap's layers over a belief (the mirror).
    map_lock: the lock under which ``live`` changes.
    refresh_s: [s] how long the costmap may lag the live belief while nobody reads it;
        0: the caller refreshes after each group itself (``costmap_current``).
    history: the costmap's patch history (versions). version: the live belief's now.
    """

    def __init__(
        self,
        live: BeliefGrid,
        mirror: BeliefGrid,
        layers: Callable[[BeliefGrid], Sequence[Layer]],
        map_lock: threading.Lock,
        refresh_s: float,
        history: int,
        version: int,
    ) -> None:
        mirror.copy_state_from(live)
        mirror.scans_fused = live.scans_fused
        self.belief = mirror
        """The mirror, at ``version`` (read it inside ``costmap_current``/``mirror_current``)."""
        self.version = version
        self.costmap = LayeredCostmap(
            live.geometry, layers(mirror), history=history, stamp=mirror.stamp, version=version
        )
        self._live = live
        self._map_lock = map_lock
        self._lock = threading.Lock()
        self._refresh_s = refresh_s
        self._dirty: list[CellBox] = []  # fused into live, not yet copied (map lock)
        self._live_version = version  # (map lock)
        self._pending: list[CellBox] = []  # copied into the mirror, not yet in the costmap
        self._refreshed = time.monotonic()  # [s] when the costmap last caught up
        self._changed = threading.Event()  # fused() since the thread last looked
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._refresh_loop, name="map-costmap", daemon=True)
        if refresh_s > 0:
            self._thread.start()

    def fused(self, boxes: Sequence[CellBox], version: int) -> None:
        """The live belief fused scans changing ``boxes`` and is now at ``version`` (the
        caller holds the map lock), and wakes the refresh thread."""
        self._dirty += boxes
        self._live_version = version
        if len(self._dirty) > MAX_DIRTY_BOXES:
            self._dirty = merge_regions(self._dirty)
        self._changed.set()

    @contextmanager
    def costmap_current(self) -> Iterator[CostmapFollower]:
        """Hold the follower with mirror and costmap at every scan fused so far."""
        with self._lock:
            self._catch_up_mirror()
            if self.costmap.version != self.version or self._pending:
                self.costmap.update(self.belief.stamp, self._pending, version=self.version)
                self._pending = []
            self._refreshed = time.monotonic()
            yield self

    def refresh(self) -> None:
        """Bring mirror and costmap up to every scan fused so far, now."""
        with self.costmap_current():
            pass

    @contextmanager
    def mirror_current(self) -> Iterator[CostmapFollower]:
        """Hold the follower with the mirror (not the costmap) at every scan fused so far."""
        with self._lock:
            self._catch_up_mirror()
            yield self

    def close(self) -> None:
        """Stop the refresh thread."""
        self._closing.set()
        self._changed.set()
        if self._thread.is_alive():
            self._thread.join()

    def _catch_up_mirror(self) -> None:
        """Copy what the live belief fused since into the mirror (follower lock held)."""
        with self._map_lock:
            boxes = merge_regions(self._dirty)
            self._dirty = []
            version = self._live_version
            if boxes or version != self.version:
                self.belief.copy_cells_from(self._live, boxes)
        self.version = version
        self._pending = merge_regions(self._pending + boxes)

    def _refresh_loop(self) -> None:
        """Thread ``map-costmap``: after each change, refresh the costmap ``refresh_s``
        after its last refresh (a read in between may have done it: then nothing is left).
        ``close`` sets ``_closing`` before ``_changed``, so checking it at every turn stops
        the loop even when the close lands between a wake-up and ``_changed.clear()``."""
        while not self._closing.is_set():
            self._changed.wait()
            wait = self._refreshed + self._refresh_s - time.monotonic()
            if self._closing.wait(max(wait, 0.0)):
                return
            self._changed.clear()
            self.refresh()
