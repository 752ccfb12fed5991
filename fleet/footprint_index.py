"""The world's bodies as planar footprints in a uniform grid: what the ``grid`` LiDAR
caster casts against (``fleet.casters``), kept in step with the PyBullet world.

Two tables of footprints (``fleet.planar_cast``), each with its own cell lists on one
grid: the obstacles (boxes; cylinders as ``PRISM_SIDES``-gon prisms, yaw 0, as
``fleet.world`` builds them) and the units (prisms turned with the unit's yaw). Every
change writes its table row at once (a few floats, no numba); a table's cell lists are
rebuilt, in numba, at the first cast after it changed. Units move every step and
obstacles seldom, so a step rebuilds only the units' lists (measured by
``tests/benchmarks/sim.py``: 7.5 us for 100 units, against milliseconds of casting a
step, so cells are not updated body by body).

The grid covers the floor and a ``MARGIN_CELLS`` border with square cells of ``cell``
[m]; a body that leaves it (a unit parked off the floor) is tested by every ray.
"""

from __future__ import annotations

import math

import numpy as np

from fleet.planar_cast import (
    BOX,
    COS,
    CX,
    CY,
    GEOM_COLUMNS,
    HALF_A,
    HALF_B,
    KIND,
    PRISM,
    SIN,
    Z_HIGH,
    Z_LOW,
    build_cells,
    cast_fans,
)
from fleet.shapes import PRISM_SIDES, Box, Shape

DEFAULT_CELL_M = 2.0
"""[m] grid cell side (``tests/benchmarks/sim.py --cells`` compares others)."""
MARGIN_CELLS = 1
"""Cells of border around the floor in the grid."""
MAX_CELLS = 1 << 22
"""Most cells in a grid: a larger floor gets larger cells."""


class _Table:
    """Footprints by key: rows of a ``GEOM_COLUMNS`` float64 array, and their cell lists."""

    def __init__(self) -> None:
        self.geom = np.zeros((16, GEOM_COLUMNS))
        self.keys: list[str] = []
        self.slot: dict[str, int] = {}
        self.cells: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def row(self, key: str, new: bool = True) -> np.ndarray:
        """Key's row (a new one when the key is new and ``new``, else KeyError); its cell
        lists are stale after."""
        self.cells = None
        slot = self.slot.get(key)
        if slot is None:
            if not new:
                raise KeyError(f"no body {key!r} in the footprint index")
            slot = len(self.keys)
            if slot == self.geom.shape[0]:
                self.geom = np.concatenate([self.geom, np.zeros_like(self.geom)])
            self.keys.append(key)
            self.slot[key] = slot
        return self.geom[slot]

    def remove(self, key: str) -> None:
        """Drop key's row (the last row takes its slot)."""
        self.cells = None
        slot = self.slot.pop(key)
        last = len(self.keys) - 1
        if slot != last:
            self.geom[slot] = self.geom[last]
            self.keys[slot] = self.keys[last]
            self.slot[self.keys[slot]] = slot
        self.keys.pop()

    def tables(self, grid: np.ndarray, shape: np.ndarray) -> tuple[np.ndarray, ...]:
        """(geom, starts, items, outside) for ``planar_cast.cast_ray``."""
        n = len(self.keys)
        if self.cells is None:
            x0, y0, cell = grid
            self.cells = build_cells(self.geom, n, x0, y0, cell, int(shape[0]), int(shape[1]))
        return (self.geom[:n], *self.cells)


class FootprintIndex:
    """The footprints of a floor ``[0, width] x [0, height]`` [m] in a grid of ``cell`` [m]."""

    def __init__(self, width: float, height: float, cell: float = DEFAULT_CELL_M) -> None:
        if not (math.isfinite(cell) and cell > 0):
            raise ValueError(f"cell must be a positive number of metres, got {cell!r}")
        cell = max(cell, math.sqrt(width * height / MAX_CELLS))
        self.cell = cell
        margin = MARGIN_CELLS * cell
        self.grid = np.array([-margin, -margin, cell])  # x0, y0, cell [m]
        border = 2 * MARGIN_CELLS
        self.shape = np.array([math.ceil(width / cell) + border, math.ceil(height / cell) + border])
        self._obstacles = _Table()
        self._units = _Table()

    # ------------------------------------------------------------------ bodies
    def put_obstacle(self, key: str, shape: Shape, z_high: float) -> None:
        """Obstacle ``key``: footprint ``shape`` from the floor to ``z_high`` [m] (new or moved)."""
        row = self._obstacles.row(key)
        if isinstance(shape, Box):
            row[[CX, CY, COS, SIN, HALF_A, HALF_B, KIND]] = (
                shape.x, shape.y, math.cos(shape.yaw), math.sin(shape.yaw),
                shape.size_x / 2, shape.size_y / 2, BOX,
            )  # fmt: skip
        else:
            _prism(row, shape.x, shape.y, 0.0, shape.radius)
        row[Z_LOW], row[Z_HIGH] = 0.0, z_high

    def remove_obstacle(self, key: str) -> None:
        """Obstacle ``key`` is gone."""
        self._obstacles.remove(key)

    def put_unit(self, key: str, radius: float, z_low: float, z_high: float) -> None:
        """Unit ``key``: a prism of ``radius`` [m] from ``z_low`` to ``z_high`` [m]; place it
        with ``move_unit``."""
        row = self._units.row(key)
        _prism(row, 0.0, 0.0, 0.0, radius)
        row[Z_LOW], row[Z_HIGH] = z_low, z_high

    def move_unit(self, key: str, x: float, y: float, yaw: float) -> None:
        """Unit ``key``'s body to (x, y) [m], turned to yaw [rad]."""
        row = self._units.row(key, new=False)
        row[CX], row[CY], row[COS], row[SIN] = x, y, math.cos(yaw), math.sin(yaw)

    # ------------------------------------------------------------------ rays
    def cast_fans(
        self,
        poses: np.ndarray,
        beam_cos: np.ndarray,
        beam_sin: np.ndarray,
        height: float,
        start: float,
        stop: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Fans of planar beams at ``height`` [m] from sensors at ``poses`` ((m, 3): x, y
        [m], heading [rad]); beam i leaves at angle ``atan2(beam_sin[i], beam_cos[i])``
        from the heading, over distances [start, stop) [m].

        Returns (ranges, hits), each (m, beams): the distance [m] from the sensor to the
        first surface (inf: none before ``stop``), and what it belongs to (an index for
        ``object_id``; -1: nothing).
        """
        poses = np.ascontiguousarray(poses, dtype=np.float64).reshape(-1, 3)
        ranges = np.empty((poses.shape[0], beam_cos.size))
        hits = np.empty((poses.shape[0], beam_cos.size), dtype=np.int64)
        obstacles = self._obstacles.tables(self.grid, self.shape)
        units = self._units.tables(self.grid, self.shape)
        cast_fans(
            poses, beam_cos, beam_sin, float(height), float(start), float(stop),
            self.grid, self.shape, obstacles, units, ranges, hits,
        )  # fmt: skip
        return ranges, hits

    def object_id(self, hit: int) -> str | None:
        """The obstacle or unit id of a ``cast_fans`` hit index (None for -1)."""
        if hit < 0:
            return None
        n = len(self._obstacles.keys)
        return self._obstacles.keys[hit] if hit < n else self._units.keys[hit - n]

    def rebuild_cells(self, obstacles: bool = True, units: bool = True) -> None:
        """Rebuild the obstacles' and/or the units' cell lists now (a cast rebuilds stale
        ones itself; this is for measuring it)."""
        for table, rebuild in ((self._obstacles, obstacles), (self._units, units)):
            if rebuild:
                table.cells = None
                table.tables(self.grid, self.shape)


def _prism(row: np.ndarray, x: float, y: float, yaw: float, radius: float) -> None:
    row[[CX, CY, COS, SIN, HALF_A, HALF_B, KIND]] = (
        x, y, math.cos(yaw), math.sin(yaw), radius, radius * math.cos(math.pi / PRISM_SIDES), PRISM,
    )  # fmt: skip
