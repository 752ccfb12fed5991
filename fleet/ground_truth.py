"""Ground truth: the world's true geometry on the map's grid, and its costmap.

Rasterisation rule: a cell is occupied when its centre lies inside or on the footprint of
an obstacle (``fleet.shapes``: a rotated box or a circle) at that time. So a cell the
shape only clips (centre outside) is free: the truth may be up to one cell thinner
along each face than the cells a LiDAR's endpoints fall in. Units are not obstacles here
(they move; they are the ones being scored).

The costmap is built as the map server builds it, with the same code: occupied cells are
LETHAL, every other cell FREE (the truth has no unknown), then
``mapserver.core.inflation.Inflator.apply`` inflates it with the server's ``InflationParams``.
So a planner run on it sees the world as the map would if it were perfect.

``GroundTruth`` follows the world's change log: after a change it re-rasterises only the
cells the changed footprints cover and re-inflates around them (the result equals a full
rebuild). Any past sim time ``at`` is answered from ``World.obstacles_at`` (one past
state is cached). ``states(start, end)`` walks the truth through a stretch of time: the
state at ``start``, then one after each world change in it, each patched from the last
as the current state is (a person walking is one change per sim step).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fleet.layout import Obstacle
from fleet.shapes import Bounds
from fleet.world import Change, World
from mapserver.core.belief import CellBox
from mapserver.core.costvalues import FREE, LETHAL
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams, Inflator
from mapserver.costmap.layered import merge_regions

MAX_INCREMENTAL_CHANGES = 64
"""More changes than this since the last look: rebuild the whole grid instead."""


def cells_of_bounds(geometry: GridGeometry, bounds: Bounds) -> CellBox:
    """The cells whose centres lie in ``bounds`` [m], clipped to the grid (maybe empty)."""
    xmin, ymin, xmax, ymax = bounds
    res = geometry.resolution
    box = CellBox(
        math.ceil((xmin - geometry.origin_x) / res - 0.5),
        math.ceil((ymin - geometry.origin_y) / res - 0.5),
        math.floor((xmax - geometry.origin_x) / res - 0.5),
        math.floor((ymax - geometry.origin_y) / res - 0.5),
    )
    return box.clip(geometry.shape)


def rasterise(
    obstacles: Iterable[Obstacle], geometry: GridGeometry, box: CellBox | None = None
) -> np.ndarray:
    """Boolean mask of the cells of ``box`` (default: the grid) whose centres lie inside an
    obstacle's footprint; shape (box.height, box.width)."""
    box = (box or CellBox(0, 0, geometry.width - 1, geometry.height - 1)).clip(geometry.shape)
    mask = np.zeros((box.height, box.width), dtype=bool)
    res = geometry.resolution
    for obstacle in obstacles:
        cells = cells_of_bounds(geometry, obstacle.shape.bounds())
        part = CellBox(
            max(cells.col0, box.col0),
            max(cells.row0, box.row0),
            min(cells.col1, box.col1),
            min(cells.row1, box.row1),
        )
        if part.empty or cells.empty:
            continue
        xs = geometry.origin_x + (np.arange(part.col0, part.col1 + 1) + 0.5) * res
        ys = geometry.origin_y + (np.arange(part.row0, part.row1 + 1) + 0.5) * res
        inside = obstacle.shape.contains(xs[None, :], ys[:, None])
        rows = slice(part.row0 - box.row0, part.row1 - box.row0 + 1)
        cols = slice(part.col0 - box.col0, part.col1 - box.col0 + 1)
        mask[rows, cols] |= inside
    return mask


@dataclass(frozen=True)
class TruthStep:
    """The truth from ``time`` [s] on: the obstacles, the occupied mask and the costmap
    (read-only), and the world ``changes`` stamped ``time`` that made it (empty for the
    first state of a walk)."""

    time: float
    obstacles: Mapping[str, Obstacle]
    mask: np.ndarray
    costs: np.ndarray
    changes: tuple[Change, ...] = ()


class GroundTruth:
    """The true occupancy and costmap of ``world`` on ``geometry``, inflated with
    ``inflation`` (the map server's ``InflationParams``)."""

    def __init__(self, world: World, geometry: GridGeometry, inflation: InflationParams) -> None:
        self.world = world
        self.geometry = geometry
        self.inflator = Inflator(inflation, geometry.resolution)
        self._revision = -1  # the world revision _mask and _costs show
        self._mask = np.zeros(geometry.shape, dtype=bool)
        self._costs = np.full(geometry.shape, FREE, dtype=np.uint8)
        self._past: tuple[int, np.ndarray, np.ndarray] | None = None

    def occupied(self, at: float | None = None) -> np.ndarray:
        """Boolean (height, width) mask of truly occupied cells at sim time ``at`` [s]
        (default: now); a read-only snapshot that later changes leave alone."""
        return self._state(at)[0]

    def costmap(self, at: float | None = None) -> np.ndarray:
        """uint8 (height, width) Nav2 costs of the truth at sim time ``at`` [s] (default:
        now): LETHAL on occupied cells, inflated around them, FREE elsewhere; a read-only
        snapshot."""
        return self._state(at)[1]

    def is_occupied(self, points: np.ndarray, at: float | None = None) -> np.ndarray:
        """For each (x, y) [m] of ``points`` (n, 2): is its cell truly occupied at ``at``
        (default: now)? False off the grid."""
        cols, rows, inside = self.geometry.points_to_cells(np.asarray(points, dtype=np.float64))
        out = np.zeros(inside.shape, dtype=bool)
        out[inside] = self.occupied(at)[rows[inside], cols[inside]]
        return out

    def states(self, start: float, end: float) -> Iterator[TruthStep]:
        """The truth at ``start`` [s], then after each world change stamped in (start,
        end), one state per change time, in time order (module docstring)."""
        obstacles = self.world.obstacles_at(start)
        mask, costs = self._state(start)
        yield TruthStep(start, dict(obstacles), mask, costs)
        changes = self.world.changes_since(self.world.revision_at(start)) or []
        pending = [c for c in changes if start < c.time < end]
        while pending:
            now = [c for c in pending if c.time == pending[0].time]
            pending = pending[len(now) :]
            for change in now:
                if change.after is None:
                    obstacles.pop(change.id, None)
                else:
                    obstacles[change.id] = change.after
            mask, costs = self._patch(mask, costs, now, obstacles.values())
            yield TruthStep(now[0].time, dict(obstacles), *self._read_only(mask, costs), tuple(now))

    # ------------------------------------------------------------------ internals
    def _state(self, at: float | None) -> tuple[np.ndarray, np.ndarray]:
        if at is None or self.world.revision_at(at) == self.world.revision:
            self._catch_up()
            return self._read_only(self._mask, self._costs)
        revision = self.world.revision_at(at)
        if self._past is None or self._past[0] != revision:
            mask = rasterise(self.world.obstacles_at(at).values(), self.geometry)
            self._past = (revision, mask, self._inflate(mask))
        return self._read_only(self._past[1], self._past[2])

    @staticmethod
    def _read_only(mask: np.ndarray, costs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mask_view, costs_view = mask.view(), costs.view()
        mask_view.flags.writeable = False
        costs_view.flags.writeable = False
        return mask_view, costs_view

    def _inflate(self, mask: np.ndarray) -> np.ndarray:
        costs = np.where(mask, LETHAL, FREE).astype(np.uint8)
        self.inflator.apply(costs)
        return costs

    def _catch_up(self) -> None:
        """Bring the current mask and costs to the world's revision."""
        if self._revision == self.world.revision:
            return
        changes = self.world.changes_since(self._revision) if self._revision >= 0 else None
        if changes is None or len(changes) > MAX_INCREMENTAL_CHANGES:
            self._mask = rasterise(self.world.obstacles.values(), self.geometry)
            self._costs = self._inflate(self._mask)
        else:
            self._mask, self._costs = self._patch(
                self._mask, self._costs, changes, self.world.obstacles.values()
            )
        self._revision = self.world.revision

    def _patch(
        self,
        mask: np.ndarray,
        costs: np.ndarray,
        changes: Sequence[Change],
        obstacles: Iterable[Obstacle],
    ) -> tuple[np.ndarray, np.ndarray]:
        """``mask`` and ``costs`` after ``changes``, ``obstacles`` being the obstacles
        after them: copies (arrays handed out before stay as they were), re-rasterised
        where the changed footprints lie and re-inflated around them."""
        mask, costs = mask.copy(), costs.copy()
        touched = [
            cells_of_bounds(self.geometry, obstacle.shape.bounds())
            for change in changes
            for obstacle in (change.before, change.after)
            if obstacle is not None
        ]
        regions = merge_regions(touched)
        obstacles = list(obstacles)
        for region in regions:
            mask[region.slices] = rasterise(obstacles, self.geometry, region)
        for region in regions:
            window = self.inflator.affected_box(region, self.geometry.shape)
            costs[window.slices] = np.where(mask[window.slices], LETHAL, FREE)
            self.inflator.apply(costs, window)
        return mask, costs
