"""Costmap layers with Nav2's two-phase interface.

Every layer answers two questions, in the configured order (as Nav2's
``costmap_2d::Layer``): ``update_bounds`` grows the region that must be recomputed, and
``update_costs`` writes its costs into the master grid inside that region only. Layers
never see each other; ``LayeredCostmap`` (``mapserver.costmap.layered``) drives them.

- ``StaticLayer``: a map file (walls, racks that never move), written over the region.
- ``ObstacleLayer``: the belief grid by its thresholds, combined as Nav2's
  ``updateWithMaxWithoutUnknownOverwrite``: an UNKNOWN obstacle cell never overwrites a
  known master cell, a known one overwrites an UNKNOWN master cell, otherwise the max
  (``obstacle_kernel``).
  Under the ``decay`` policy it reports, per tile, when its costs next change.
- ``InflationLayer``: Nav2's inflation of LETHAL cells (``mapserver.core.inflation``).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from mapserver.core.belief import BeliefGrid, CellBox
from mapserver.core.costvalues import FREE, LETHAL, UNKNOWN
from mapserver.core.fusion_kernel import FADE_CACHE_SIZE
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams, Inflator
from mapserver.core.obstacle_kernel import classify_window
from mapserver.store.mapfiles import RosMap


class Layer(Protocol):
    """One costmap layer (two phases, as Nav2)."""

    name: str

    def update_bounds(self, stamp: float, box: CellBox) -> CellBox:
        """Phase 1: the region to recompute, grown from ``box`` as this layer needs."""
        ...

    def due_regions(self, stamp: float) -> list[CellBox]:
        """Regions whose costs change by time alone by ``stamp`` [s] (none for most)."""
        ...

    def update_costs(self, master: np.ndarray, box: CellBox, stamp: float) -> None:
        """Phase 2: write this layer's costs into ``master`` (uint8) inside ``box`` only."""
        ...

    def fresh(self) -> Layer:
        """The same layer with none of its incremental state (for from-scratch builds)."""
        ...

    def reset(self) -> None:
        """Forget incremental state (the sources it reads were replaced)."""
        ...


class StaticLayer:
    """Costs from a ROS map: occupancy >= ``lethal_threshold`` is LETHAL, -1 UNKNOWN,
    anything else FREE (Nav2's static layer with ``trinary_costmap: true``).
    """

    name = "static"

    def __init__(self, ros_map: RosMap, lethal_threshold: int = 100) -> None:
        if not 0 < lethal_threshold <= 100:
            raise ValueError(f"lethal_threshold must be in 1..100, got {lethal_threshold!r}")
        occ = ros_map.occupancy
        costs = np.full(occ.shape, FREE, dtype=np.uint8)
        costs[occ < 0] = UNKNOWN
        costs[occ >= lethal_threshold] = LETHAL
        self.geometry = ros_map.geometry
        self.costs = costs

    def update_bounds(self, stamp: float, box: CellBox) -> CellBox:
        return box

    def due_regions(self, stamp: float) -> list[CellBox]:
        return []

    def update_costs(self, master: np.ndarray, box: CellBox, stamp: float) -> None:
        master[box.slices] = self.costs[box.slices]

    def fresh(self) -> StaticLayer:
        return self

    def reset(self) -> None:
        return None


class ObstacleLayer:
    """Costs from the belief grid at a stamp: LETHAL (occupied), FREE, UNKNOWN.

    tile: [cells] side of the squares for which the next decay-driven change is tracked.
    """

    name = "obstacle"

    def __init__(self, belief: BeliefGrid, tile: int = 32) -> None:
        if tile < 1:
            raise ValueError(f"tile must be a positive number of cells, got {tile!r}")
        self.belief = belief
        self.tile = tile
        g = belief.geometry
        self._tiles_shape = (math.ceil(g.height / tile), math.ceil(g.width / tile))
        self.next_change = np.full(self._tiles_shape, math.inf)  # [s] per tile
        self._fade_cache = np.empty((FADE_CACHE_SIZE, 3), dtype=np.float64)

    def aligned(self, box: CellBox) -> CellBox:
        """``box`` grown to whole tiles (clipped to the grid)."""
        t = self.tile
        grown = CellBox(
            box.col0 // t * t,
            box.row0 // t * t,
            (box.col1 // t + 1) * t - 1,
            (box.row1 // t + 1) * t - 1,
        )
        return grown.clip(self.belief.geometry.shape)

    def update_bounds(self, stamp: float, box: CellBox) -> CellBox:
        return box if box.empty else self.aligned(box)

    def due_regions(self, stamp: float) -> list[CellBox]:
        """Tile rows' runs of tiles whose next decay-driven change is at or before stamp."""
        if not self.belief.fades:
            return []
        due = self.next_change <= stamp
        regions: list[CellBox] = []
        t = self.tile
        for trow in np.flatnonzero(due.any(axis=1)):
            cols = np.flatnonzero(due[trow])
            starts = np.flatnonzero(np.diff(cols, prepend=-2) != 1)
            ends = np.append(starts[1:], len(cols)) - 1
            for s, e in zip(starts, ends, strict=True):
                box = CellBox(cols[s] * t, trow * t, (cols[e] + 1) * t - 1, (trow + 1) * t - 1)
                regions.append(box.clip(self.belief.geometry.shape))
        return regions

    def update_costs(self, master: np.ndarray, box: CellBox, stamp: float) -> None:
        self.merge_costs(master[box.slices], stamp, box)

    def fresh(self) -> ObstacleLayer:
        return ObstacleLayer(self.belief, self.tile)

    def reset(self) -> None:
        self.next_change.fill(math.inf)

    def merge_costs(self, window: np.ndarray, stamp: float, box: CellBox) -> None:
        """Merge obstacle costs of ``box`` at ``stamp`` [s] into the master ``window``
        (MaxWithoutUnknownOverwrite) and refresh the decay schedule.

        Tiles wholly inside ``box`` get their next change recomputed; tiles it covers in
        part can only be lowered to crossings they already hold (their other cells were
        not read), so every phase-1 region, being tile-aligned, is fully rescheduled.
        """
        b = self.belief
        m, d = b.sensor_model, b.decay
        t = self.tile
        g = b.geometry
        rows = slice(-(-box.row0 // t), (box.row1 + 1) // t if box.row1 + 1 < g.height else None)
        cols = slice(-(-box.col0 // t), (box.col1 + 1) // t if box.col1 + 1 < g.width else None)
        self.next_change[rows, cols] = math.inf
        classify_window(
            b.raw_log_odds().ravel(),
            b.last_observed().ravel(),
            b.geometry.width,
            box.col0,
            box.row0,
            box.col1,
            box.row1,
            float(stamp),
            b.fades,
            m.l0,
            m.l_occupied,
            m.l_free,
            b.occupied_half_life,
            d.half_life_free,
            window,
            self.tile,
            self.next_change,
            self._fade_cache,
            b.history(),
            b.fades_selectively,
        )


class InflationLayer:
    """Nav2 inflation of the master grid's LETHAL cells (``mapserver.core.inflation``)."""

    name = "inflation"

    def __init__(self, params: InflationParams, geometry: GridGeometry) -> None:
        self.params = params
        self.geometry = geometry
        self.inflator = Inflator(params, geometry.resolution)

    def update_bounds(self, stamp: float, box: CellBox) -> CellBox:
        return box if box.empty else self.inflator.affected_box(box, self.geometry.shape)

    def due_regions(self, stamp: float) -> list[CellBox]:
        return []

    def update_costs(self, master: np.ndarray, box: CellBox, stamp: float) -> None:
        self.inflator.apply(master, box)

    def fresh(self) -> InflationLayer:
        return self

    def reset(self) -> None:
        return None
