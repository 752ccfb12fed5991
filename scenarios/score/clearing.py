"""Time to clear (docs/files.md): from an object's removal until the shared costmap no
longer holds a lethal cell where the object was."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fleet.ground_truth import cells_of_bounds
from mapserver.core.costvalues import LETHAL
from mapserver.core.geometry import GridGeometry


@dataclass
class ClearWatch:
    """One removal: the object's old footprint cells, when it left, when it cleared."""

    object_id: str
    removed_at: float
    cells: tuple[slice, slice]
    cleared_at: float | None = None


@dataclass
class ClearingTracker:
    """Watches every removal until the costmap shows its footprint free of LETHAL cells."""

    geometry: GridGeometry
    watches: list[ClearWatch] = field(default_factory=list)

    def removed(self, object_id: str, bounds: tuple[float, float, float, float], at: float) -> None:
        """``object_id`` left the box ``bounds`` (xmin, ymin, xmax, ymax) [m] at ``at`` [s]."""
        box = cells_of_bounds(self.geometry, bounds)
        if not box.empty:
            self.watches.append(ClearWatch(object_id, at, box.slices))

    def observe(self, costs: np.ndarray, stamp: float) -> None:
        """Check the open watches against the costmap read at ``stamp`` [s]."""
        for watch in self.watches:
            if watch.cleared_at is None and not np.any(costs[watch.cells] == LETHAL):
                watch.cleared_at = stamp

    def times(self) -> list[float | None]:
        """Seconds to clear per removal, in removal order (None: never cleared)."""
        return [None if w.cleared_at is None else w.cleared_at - w.removed_at for w in self.watches]
