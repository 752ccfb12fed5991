"""A site's map split among map servers: vertical strips with overlapping borders.

docs/scaling.md ("A site larger than one server") gives the design; this module is its
geometry, shared by the zoned client (``mapserver.client.zoned``), the runner and the
zones benchmark:

- The site grid's columns are cut into ``zones`` strips of (nearly) equal width, at cell
  boundaries. Strip ``k`` is zone ``k``'s *core*: in a stitched read of the site, its
  cells come from zone ``k``'s server.
- Zone ``k``'s server holds the core plus ``border_cells`` on each cut side (clipped to
  the site), on the site's own cells: the same resolution, its origin on a site cell
  corner, so cell ``(c, r)`` of the zone is cell ``(c + first_column, r)`` of the site.
- A scan goes to every zone whose *exact band* (the core plus ``margin_cells`` on each
  side) its LiDAR can reach: the sensor within ``reach_m`` of the band. A scan observes
  cells within its ``range_max`` of the sensor only, so every scan that can observe a cell
  of the band reaches the band's server, and a cell of the band fuses, in each zone's
  journal order, the very scans it would on one server of the whole site. With
  ``margin_cells`` covering the costmap's inflation radius (a cell's cost depends on the
  belief within that radius of it), the core's costs are those of one server's too.
- ``border_cells`` is at least the reach plus the margin, so a sensor that posts to a zone
  stands on that zone's grid (its server refuses a sensor off its map).

All lengths in metres, cells in the site's columns.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from mapserver.core.errors import FieldError
from mapserver.core.geometry import GridGeometry

MAX_ZONES = 64
"""Most zones (map server processes) a layout may have."""


@dataclass(frozen=True)
class ZoneLayout:
    """Zones of ``site`` (module docstring).

    site: the whole site's grid. cuts: the strips' first columns and the site's width,
    ``zones + 1`` increasing columns from 0. reach_m: [m] a sensor posts to a zone whose
    exact band lies within this distance of it (a LiDAR's ``range_max`` plus a cell).
    margin_cells: the exact band's width beyond the core on each side [cells].
    border_cells: each zone's grid beyond its core on each cut side [cells].
    """

    site: GridGeometry
    cuts: tuple[int, ...]
    reach_m: float
    margin_cells: int
    border_cells: int

    def __post_init__(self) -> None:
        cuts = self.cuts
        if len(cuts) < 2 or cuts[0] != 0 or cuts[-1] != self.site.width:
            raise FieldError("cuts", cuts, f"must run from 0 to the site's width {self.site.width}")
        if any(b <= a for a, b in zip(cuts, cuts[1:], strict=False)):
            raise FieldError("cuts", cuts, "must increase: every strip at least one column")
        if not (math.isfinite(self.reach_m) and self.reach_m >= 0):
            raise FieldError("reach_m", self.reach_m, "must be finite metres >= 0")
        for name in ("margin_cells", "border_cells"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise FieldError(name, value, "must be a whole number of cells >= 0")
        need = _cells_past(self.reach_m, self.site.resolution) + self.margin_cells
        if self.border_cells < need:
            raise FieldError(
                "border_cells",
                self.border_cells,
                f"must hold the reach and the margin: at least {need} cells",
            )

    @classmethod
    def strips(cls, site: GridGeometry, zones: int, range_m: float, margin_m: float) -> ZoneLayout:
        """``zones`` strips of ``site`` for LiDARs reaching ``range_m`` [m] and a costmap
        whose cells depend on the belief within ``margin_m`` [m] (the inflation radius)."""
        if isinstance(zones, bool) or not isinstance(zones, int) or not 1 <= zones <= MAX_ZONES:
            raise FieldError("zones", zones, f"must be a whole number in [1, {MAX_ZONES}]")
        if zones > site.width:
            raise FieldError("zones", zones, f"must be at most the site's {site.width} columns")
        for name, value in (("range_m", range_m), ("margin_m", margin_m)):
            if not (math.isfinite(value) and value >= 0):
                raise FieldError(name, value, "must be finite metres >= 0")
        res = site.resolution
        cuts = tuple(round(site.width * k / zones) for k in range(zones + 1))
        margin_cells = _cells_past(margin_m, res)
        reach_m = range_m + res  # a return's cell may lie up to a cell beyond its range
        border_cells = _cells_past(reach_m, res) + margin_cells
        return cls(site, cuts, reach_m, margin_cells, border_cells)

    def to_dict(self) -> dict[str, Any]:
        """The layout as plain values (``from_dict`` reads them back): what ``fleetmap
        zones`` writes to ``zones.yaml`` for a fleet's ``ZonedMapClient``."""
        return {
            "site": asdict(self.site),
            "cuts": list(self.cuts),
            "reach_m": self.reach_m,
            "margin_cells": self.margin_cells,
            "border_cells": self.border_cells,
        }

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> ZoneLayout:
        """The layout ``to_dict`` gave; ``FieldError`` names a missing or bad value."""
        if not isinstance(values, Mapping):
            raise FieldError("zones", values, "must be a mapping of the layout's values")
        names = ("site", "cuts", "reach_m", "margin_cells", "border_cells")
        missing = [n for n in names if n not in values]
        if missing:
            raise FieldError(missing[0], None, "is missing")
        site = values["site"]
        if not isinstance(site, Mapping):
            raise FieldError("site", site, "must be a mapping of the grid's values")
        cuts = values["cuts"]
        if not isinstance(cuts, list | tuple) or not all(type(c) is int for c in cuts):
            raise FieldError("cuts", cuts, "must be a list of whole columns")
        try:
            grid = GridGeometry(**site)
        except TypeError as exc:
            raise FieldError("site", dict(site), f"must hold a grid's values ({exc})") from None
        reach = values["reach_m"]
        if isinstance(reach, bool) or not isinstance(reach, int | float):
            raise FieldError("reach_m", reach, "must be metres")
        return cls(grid, tuple(cuts), float(reach), values["margin_cells"], values["border_cells"])

    @property
    def zones(self) -> int:
        """How many zones."""
        return len(self.cuts) - 1

    def core(self, k: int) -> tuple[int, int]:
        """Zone ``k``'s core: site columns ``[first, end)``."""
        return self.cuts[k], self.cuts[k + 1]

    def grid_columns(self, k: int) -> tuple[int, int]:
        """Site columns ``[first, end)`` of zone ``k``'s grid: its core and borders."""
        first, end = self.core(k)
        return max(0, first - self.border_cells), min(self.site.width, end + self.border_cells)

    def geometry(self, k: int) -> GridGeometry:
        """Zone ``k``'s grid, on the site's cells."""
        first, end = self.grid_columns(k)
        site = self.site
        return GridGeometry(
            end - first,
            site.height,
            site.resolution,
            site.origin_x + first * site.resolution,
            site.origin_y,
        )

    def posts_to(self, x: float) -> list[int]:
        """The zones a scan whose sensor stands at ``x`` [m] goes to, in order (module
        docstring): every zone whose exact band lies within ``reach_m`` of ``x``."""
        return np.flatnonzero(self.posts_to_many(np.array([x]))[0]).tolist()

    def posts_to_many(self, xs: np.ndarray) -> np.ndarray:
        """``posts_to`` for many sensors: a (len(xs), zones) bool array."""
        xs = np.asarray(xs, dtype=np.float64).reshape(-1, 1)
        lo, hi = self._bands()
        return (xs >= lo - self.reach_m) & (xs <= hi + self.reach_m)

    def home(self, x: float) -> int:
        """The zone whose core holds ``x`` [m] (clamped to the site's first and last)."""
        return int(self.homes(np.array([x]))[0])

    def homes(self, xs: np.ndarray) -> np.ndarray:
        """``home`` for many sensors' ``xs`` [m]: an int array of zones."""
        xs = np.asarray(xs, dtype=np.float64)
        cols = np.floor((xs - self.site.origin_x) / self.site.resolution)
        cols = np.clip(cols, 0, self.site.width - 1).astype(np.int64)
        return np.searchsorted(self.cuts, cols, side="right") - 1

    def stitch(self, parts: Sequence[np.ndarray]) -> np.ndarray:
        """One site array from the zones' arrays (one per zone, each of its ``geometry``'s
        shape): every core's columns from its own zone."""
        if len(parts) != self.zones:
            raise ValueError(f"need one grid per zone ({self.zones}), got {len(parts)}")
        out = np.empty(self.site.shape, dtype=parts[0].dtype)
        for k, part in enumerate(parts):
            want = self.geometry(k).shape
            if part.shape != want:
                raise ValueError(f"zone {k}'s grid must have shape {want}, got {part.shape}")
            first, end = self.core(k)
            offset = self.grid_columns(k)[0]
            out[:, first:end] = part[:, first - offset : end - offset]
        return out

    # ------------------------------------------------------------------ internals
    def _bands(self) -> tuple[np.ndarray, np.ndarray]:
        """[m] each zone's exact band: its core plus the margin, as x bounds."""
        cuts = np.asarray(self.cuts, dtype=np.float64)
        res, x0 = self.site.resolution, self.site.origin_x
        lo = x0 + (cuts[:-1] - self.margin_cells) * res
        hi = x0 + (cuts[1:] + self.margin_cells) * res
        return lo, hi


def _cells_past(length_m: float, resolution: float) -> int:
    """The whole cells that hold ``length_m`` [m] with one to spare: a span of that
    length starting anywhere in a cell ends in a cell at most this many further on, and
    short of its far edge."""
    return math.floor(length_m / resolution) + 1
