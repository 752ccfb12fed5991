"""Grid geometry: size, resolution and origin, and conversions between world and cells.

Conventions (docs/contract.md): one fixed ``map`` frame, x right, y up, metres. Grids are
row-major and row 0 is the row at the origin's y (the bottom row, as in ROS
``nav_msgs/OccupancyGrid``): ``index = row * width + col``. The origin is the world
position of the outer corner of cell (0, 0); the map is axis-aligned (origin yaw 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mapserver.core.errors import FieldError, FleetmapError


class OutsideMapError(FleetmapError, ValueError):
    """A world point lies outside the grid; carries the point for the error message."""

    def __init__(self, x: float, y: float, geometry: GridGeometry) -> None:
        self.x, self.y = x, y
        xmin, ymin, xmax, ymax = geometry.bounds
        super().__init__(f"point ({x}, {y}) is outside the map [{xmin}, {xmax}) x [{ymin}, {ymax})")


@dataclass(frozen=True)
class GridGeometry:
    """The shape and placement of a grid.

    width, height: [cells], both >= 1.
    resolution: [m/cell], > 0.
    origin_x, origin_y: [m] world position of the outer corner of cell (0, 0).
    """

    width: int
    height: int
    resolution: float
    origin_x: float = 0.0
    origin_y: float = 0.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise FieldError(name, value, "must be a positive number of cells")
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise FieldError("resolution", self.resolution, "must be positive metres")
        for name in ("origin_x", "origin_y"):
            if not math.isfinite(getattr(self, name)):
                raise FieldError(name, getattr(self, name), "must be finite")

    def describe(self) -> str:
        """The grid in words: ``120 x 80 cells of 0.1 m (12 x 8 m) from (0, 0)``."""
        return (
            f"{self.width} x {self.height} cells of {self.resolution:g} m "
            f"({self.width * self.resolution:g} x {self.height * self.resolution:g} m) "
            f"from ({self.origin_x:g}, {self.origin_y:g})"
        )

    def differing_fields(self, other: GridGeometry) -> dict[str, float]:
        """This grid's fields whose value ``other`` does not share, by name."""
        names = ("width", "height", "resolution", "origin_x", "origin_y")
        return {n: getattr(self, n) for n in names if getattr(self, n) != getattr(other, n)}

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) = (height, width), the numpy shape of a grid array."""
        return (self.height, self.width)

    @property
    def size(self) -> int:
        """Number of cells."""
        return self.width * self.height

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) [m]; points on the max edges are outside."""
        return (
            self.origin_x,
            self.origin_y,
            self.origin_x + self.width * self.resolution,
            self.origin_y + self.height * self.resolution,
        )

    def world_to_cell(self, x: float, y: float) -> tuple[int, int]:
        """(col, row) of the cell holding world point (x, y) [m]; may lie outside the grid."""
        return (
            math.floor((x - self.origin_x) / self.resolution),
            math.floor((y - self.origin_y) / self.resolution),
        )

    def contains_cell(self, col: int, row: int) -> bool:
        """True when (col, row) is a cell of this grid."""
        return 0 <= col < self.width and 0 <= row < self.height

    def contains_point(self, x: float, y: float) -> bool:
        """True when world point (x, y) [m] lies on the grid (NaN is never on it)."""
        xmin, ymin, xmax, ymax = self.bounds
        return xmin <= x < xmax and ymin <= y < ymax  # False for NaN; no overflow for 1e308

    def world_to_cell_checked(self, x: float, y: float) -> tuple[int, int]:
        """(col, row) of world point (x, y) [m]; raises OutsideMapError off the grid."""
        if not self.contains_point(x, y):
            raise OutsideMapError(x, y, self)
        return self.world_to_cell(x, y)

    def cell_to_world(self, col: int, row: int) -> tuple[float, float]:
        """World position [m] of the centre of cell (col, row)."""
        return (
            self.origin_x + (col + 0.5) * self.resolution,
            self.origin_y + (row + 0.5) * self.resolution,
        )

    def points_to_cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised world -> cell for an (n, 2) array of points [m].

        Returns (cols, rows, inside): int64 cell coordinates and a boolean mask of the
        points that lie on the grid; points off it (or not finite) get cells -1.
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        xmin, ymin, xmax, ymax = self.bounds
        with np.errstate(invalid="ignore"):
            inside = (
                (pts[:, 0] >= xmin) & (pts[:, 0] < xmax) & (pts[:, 1] >= ymin) & (pts[:, 1] < ymax)
            )
        cols = np.full(len(pts), -1, dtype=np.int64)
        rows = np.full(len(pts), -1, dtype=np.int64)
        cols[inside] = np.floor((pts[inside, 0] - self.origin_x) / self.resolution)
        rows[inside] = np.floor((pts[inside, 1] - self.origin_y) / self.resolution)
        # A point a rounding error below the far edge still belongs to the last cell.
        np.minimum(cols, self.width - 1, out=cols)
        np.minimum(rows, self.height - 1, out=rows)
        return cols, rows, inside

    def index(self, col: int, row: int) -> int:
        """Flat row-major index of cell (col, row)."""
        return row * self.width + col
