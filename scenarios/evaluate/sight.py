"""What a recording's scans saw, independent of any map: returns, floor, sight lines.

For each scan, over the beams that returned (REP 117: a range in [range_min, range_max]):

- its *returns* land in endpoint cells, counted per cell over the whole recording
  (``hit_count``; a return whose endpoint is off the grid is counted in
  ``returns_total`` only);
- the *floor* the recording saw is every cell a returning beam crossed or hit, traced as
  the fusion kernel traces beams (``mapserver.core.traversal``: the Bresenham line
  between the cells of the beam's ends clipped to the grid, the endpoint cell hit, not
  crossed);
- the cells it *sees through* are the crossed cells more than ``margin`` cells
  (Chebyshev distance, in cells) from the endpoint cell of the beam that crosses them,
  and not hit by any return of the same scan: space the scan shows empty now, well
  before a return (so range noise, a beam grazing the corner of a wall's cell and the
  wall's own thickness are not read as "seen through").

No-return beams count for nothing here: a beam that reads nothing may have been dropped
(a black or shiny surface, a glancing angle), so it proves neither a surface nor the
empty space before one. Every map under test is measured against the same sight.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.core.traversal import clipped_cells, line_next, line_start

MARK_THROUGH = 1
MARK_HIT = 2


@njit(cache=True, nogil=True)
def _endpoint_cell(x, y, origin_x, origin_y, inv_res, width, height):
    """Flat index of the cell holding point (x, y) [m], -1 off the grid (as the fusion
    kernel's endpoint test: the grid's far edges excluded)."""
    if not (x >= origin_x and y >= origin_y):
        return -1
    c = int(math.floor((x - origin_x) * inv_res))
    r = int(math.floor((y - origin_y) * inv_res))
    if c >= width or r >= height:
        return -1
    return r * width + c


@njit(cache=True, nogil=True)
def observe_scan(
    width, height, origin_x, origin_y, resolution,
    x, y, yaw, angle_min, angle_increment, range_min, range_max, ranges, margin,
    marks, hit_count, floor, hits, through,
):  # fmt: skip
    """Count one scan's returns into ``hit_count`` (int32 per cell), mark its floor in
    ``floor`` (bool per cell) and write the flat indices of the cells it sees through
    (see the module) into ``through``; returns (returns, cells seen through).

    Grid: ``width`` x ``height`` cells of ``resolution`` [m] from ``origin`` [m]. Scan:
    sensor pose [m, m, rad], beam angles [rad], range limits and ``ranges`` [m]; margin
    [cells]. Scratch, owned by the caller: ``marks`` (uint8 per cell, zero, left zero),
    ``hits`` (int64, one per beam) and ``through`` (int64, large enough for every cell
    the returns cross: ``SightKeeper`` sizes it).
    """
    inv_res = 1.0 / resolution
    returns = 0
    n_hits = 0
    for i in range(ranges.shape[0]):
        r = ranges[i]
        if not (r >= range_min and r <= range_max):
            continue
        returns += 1
        a = yaw + angle_min + i * angle_increment
        idx = _endpoint_cell(
            x + r * math.cos(a), y + r * math.sin(a), origin_x, origin_y, inv_res, width, height
        )
        if idx >= 0:
            hit_count[idx] += 1
            floor[idx] = True
            if marks[idx] != MARK_HIT:
                marks[idx] = MARK_HIT
                hits[n_hits] = idx
                n_hits += 1
    n = 0
    for i in range(ranges.shape[0]):
        r = ranges[i]
        if not (r >= range_min and r <= range_max):
            continue
        a = yaw + angle_min + i * angle_increment
        ex = x + r * math.cos(a)
        ey = y + r * math.sin(a)
        if not (math.isfinite(ex) and math.isfinite(ey)):
            continue
        ok, t0, t1, c0, r0, c1, r1 = clipped_cells(
            x, y, ex, ey, origin_x, origin_y, resolution, width, height
        )
        if not ok:
            continue
        end_col = math.floor((ex - origin_x) * inv_res)  # unclamped: may lie off the grid
        end_row = math.floor((ey - origin_y) * inv_res)
        idx, cells, major, minor, da, db, err = line_start(c0, r0, c1, r1, width)
        count = cells - 1 if t1 >= 1.0 else cells  # the endpoint's cell is hit, not crossed
        for _ in range(count):
            floor[idx] = True
            if marks[idx] == 0:
                row = idx // width
                col = idx - row * width
                if max(abs(col - end_col), abs(row - end_row)) > margin:
                    marks[idx] = MARK_THROUGH
                    through[n] = idx
                    n += 1
            idx, err = line_next(idx, err, major, minor, da, db)
    for k in range(n):
        marks[through[k]] = 0
    for k in range(n_hits):
        marks[hits[k]] = 0
    return returns, n


class SightKeeper:
    """The sight of a recording's scans on ``geometry``, scan after scan.

    ``observe(scan)`` adds the scan's returns to ``hit_count`` and ``returns_total`` and
    its floor to ``floor``, and returns the cells it sees through (flat indices, each
    once). ``margin`` [cells]: how far from a return's endpoint cell a crossed cell must
    be to count as seen through (Chebyshev distance greater than it; default 2).
    """

    def __init__(self, geometry: GridGeometry, margin: int = 2) -> None:
        if isinstance(margin, bool) or not isinstance(margin, int) or margin < 0:
            raise ValueError(f"the ghost margin must be whole cells >= 0, got {margin!r}")
        self.geometry = geometry
        self.margin = margin
        self.hit_count = np.zeros(geometry.size, dtype=np.int32)
        self.floor = np.zeros(geometry.size, dtype=bool)
        self.returns_total = 0
        self._marks = np.zeros(geometry.size, dtype=np.uint8)
        self._hits = np.empty(0, dtype=np.int64)
        self._through = np.empty(0, dtype=np.int64)

    def observe(self, scan: Scan) -> np.ndarray:
        """Add one scan (see the class); returns the cells it sees through (int64)."""
        g = self.geometry
        beams = scan.beam_count
        if self._hits.size < beams:
            self._hits = np.empty(beams, dtype=np.int64)
            # Each beam's line crosses at most max(width, height) + 1 cells.
            bound = min(g.size, beams * (max(g.width, g.height) + 1))
            self._through = np.empty(bound, dtype=np.int64)
        returns, n = observe_scan(
            int(g.width), int(g.height), float(g.origin_x), float(g.origin_y),
            float(g.resolution), float(scan.pose.x), float(scan.pose.y), float(scan.pose.yaw),
            float(scan.angle_min), float(scan.angle_increment), float(scan.range_min),
            float(scan.range_max), scan.ranges, int(self.margin),
            self._marks, self.hit_count, self.floor, self._hits, self._through,
        )  # fmt: skip
        self.returns_total += returns
        return self._through[:n].copy()

    def ghost_candidates(self, through: np.ndarray) -> np.ndarray:
        """The cells of ``through`` that some return of the recording so far has hit:
        the only cells a map can hold occupied for a reason (a never-hit cell held
        occupied is not a trail but an artefact, and is not counted)."""
        return through[self.hit_count[through] > 0]
