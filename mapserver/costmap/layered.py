"""The layered costmap: layers combined in order, incremental, versioned, with patches.

``LayeredCostmap.update(stamp, changed)`` recomputes only what changed: the boxes the
caller reports (a scan's fused box) plus the regions whose costs change by time alone
(decay crossing a threshold, reported by the layers). For each region it runs Nav2's two
phases: every layer grows the bounds (``update_bounds``), the master is reset to UNKNOWN
inside them, and every layer writes its costs there (``update_costs``).

The result at stamp t equals a from-scratch build at t (``build_costs``) while the work
stays proportional to what changed. Every update that changes a cell bumps ``version``
and records the changed cells' bounding box; ``patches_since(v)`` returns the current
costs in each box changed after version v, or ``None`` once that history is gone (the
caller then sends the full costmap). History is bounded to ``history`` entries.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np

from mapserver.core.belief import EMPTY_BOX, CellBox
from mapserver.core.costvalues import UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.patch import Patch
from mapserver.costmap.layers import Layer


def changed_box(old: np.ndarray, new: np.ndarray, region: CellBox) -> CellBox:
    """Bounding box (grid coordinates) of the cells where old != new inside ``region``."""
    diff = old != new
    rows = np.flatnonzero(diff.any(axis=1))
    if rows.size == 0:
        return EMPTY_BOX
    cols = np.flatnonzero(diff.any(axis=0))
    return CellBox(
        region.col0 + int(cols[0]),
        region.row0 + int(rows[0]),
        region.col0 + int(cols[-1]),
        region.row0 + int(rows[-1]),
    )


def merge_regions(boxes: Sequence[CellBox]) -> list[CellBox]:
    """Non-empty boxes with overlapping ones merged (so no cell is recomputed twice)."""
    pending = [b for b in boxes if not b.empty]
    merged: list[CellBox] = []
    while pending:
        current = pending.pop()
        grew = True
        while grew:
            grew = False
            for i in range(len(pending) - 1, -1, -1):
                if _overlap(current, pending[i]):
                    current = current.union(pending.pop(i))
                    grew = True
        merged.append(current)
    return merged


def _overlap(a: CellBox, b: CellBox) -> bool:
    return a.col0 <= b.col1 and b.col0 <= a.col1 and a.row0 <= b.row1 and b.row0 <= a.row1


class LayeredCostmap:
    """Layers combined in order into one uint8 costmap, kept current incrementally.

    geometry: the grid. layers: in the order they are applied (e.g. static, obstacle,
    inflation). history: how many changed boxes are kept for patches.
    The costmap starts built at ``stamp`` (default -inf: only static information) as
    ``version`` (default 0). By default every update that changes a cell bumps the
    version by one; a caller that numbers versions itself (the map server: one per scan)
    passes ``version`` to ``update``.
    """

    def __init__(
        self,
        geometry: GridGeometry,
        layers: Sequence[Layer],
        history: int = 256,
        stamp: float = float("-inf"),
        version: int = 0,
    ) -> None:
        if history < 1:
            raise ValueError(f"history must be at least 1 version, got {history!r}")
        self.geometry = geometry
        self.layers = list(layers)
        self.costs = np.full(geometry.shape, UNKNOWN, dtype=np.uint8)
        self.version = version
        self.stamp = stamp
        self._history: deque[tuple[int, CellBox]] = deque(maxlen=history)
        self._floor = version  # patches exist since any version >= this
        self._full = CellBox(0, 0, geometry.width - 1, geometry.height - 1)
        self.update(stamp, [self._full], version=version)

    @property
    def oldest_patch_version(self) -> int:
        """Patches are available since this version (inclusive)."""
        return self._floor

    def update(
        self, stamp: float, changed: Sequence[CellBox] = (), version: int | None = None
    ) -> CellBox:
        """Bring the costmap to ``stamp`` [s] (never backwards) after ``changed`` boxes.

        Returns the bounding box of the cells whose cost changed (empty if none). The
        costmap is then at ``version`` (>= the current one) if given, else at the next
        version if any cell changed.
        """
        if version is not None and version < self.version:
            raise ValueError(f"version must not go backwards from {self.version}, got {version}")
        stamp = max(stamp, self.stamp)
        regions = list(changed)
        for layer in self.layers:
            regions.extend(layer.due_regions(stamp))
        touched = EMPTY_BOX
        for region in merge_regions([r.clip(self.geometry.shape) for r in regions]):
            bounds = region
            for layer in self.layers:
                bounds = layer.update_bounds(stamp, bounds)
            before = self.costs[bounds.slices].copy()
            self._compose(self.costs, bounds, stamp)
            touched = touched.union(changed_box(before, self.costs[bounds.slices], bounds))
        self.stamp = stamp
        if version is None:
            version = self.version + (0 if touched.empty else 1)
        self.version = version
        if not touched.empty:
            if len(self._history) == self._history.maxlen:
                self._floor = self._history[0][0]  # clients at that version need only later
            self._history.append((version, touched))
        return touched

    def _compose(self, master: np.ndarray, bounds: CellBox, stamp: float) -> None:
        master[bounds.slices] = UNKNOWN
        for layer in self.layers:
            layer.update_costs(master, bounds, stamp)

    def patches_since(self, version: int) -> list[Patch] | None:
        """Patches that bring a copy at ``version`` to the current one; None if unknown."""
        if version == self.version:
            return []
        if version > self.version or version < self.oldest_patch_version:
            return None
        boxes = [box for v, box in self._history if v > version]
        return [
            Patch(b.col0, b.row0, b.width, b.height, self.costs[b.slices].copy())
            for b in merge_regions(boxes)
        ]

    def build_costs(self, stamp: float) -> np.ndarray:
        """A from-scratch costmap at ``stamp`` [s]: fresh layers, nothing cached is used."""
        fresh = [layer.fresh() for layer in self.layers]
        return LayeredCostmap(self.geometry, fresh, history=1, stamp=stamp).costs

    def rebuild(self, stamp: float, version: int) -> None:
        """Recompute everything at ``stamp`` as ``version`` (after loading a snapshot);
        patch history starts afresh."""
        for layer in self.layers:
            layer.reset()
        self._history.clear()
        self.stamp = float("-inf")
        self.version = version
        self._floor = version
        self.update(stamp, [self._full], version=version)
