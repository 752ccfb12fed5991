"""Landmark (ALT) lower bounds for grid A*, cached per costmap content.

For a landmark cell L with exact costs d(L, v) [m] from L to every cell v (one Dijkstra
over the planner's own directed graph), the triangle inequality d(L, goal) <= d(L, n) +
d(n, goal) gives the lower bound

    d(n, goal) >= d(L, goal) - d(L, n)

(Goldberg and Harrelson 2005, "Computing the shortest path: A* search meets graph
theory", the ALT method). A maximum of such bounds is admissible, and consistent: for an
edge n -> m of cost c, d(L, m) <= d(L, n) + c. Where L reaches neither cell, or not the
goal, the bound is -inf (no information).

The tables are float64 [m] (8 B per cell and landmark), summed by the same search as
the plans; each bound is lowered by ``margin`` = 2**-40 x the largest finite distance,
above the rounding of those sums, so it stays below the exact cost and consistency holds
up to that margin (the search reopens a node that a later, cheaper path reaches, and its
stop rule keeps the cost the optimum).

Landmarks are chosen by the farthest rule: the first is the passable cell nearest the
grid's first cell (row 0, col 0), each next one the reachable cell whose least distance
from the landmarks chosen so far is greatest (ties: the lowest index). The tables are
built on the first plan over a costmap and reused while the costmap's content and the
``allow_unknown`` flag stay the same: any changed cell rebuilds them (a content
comparison, not a version number, so no caller can forget to invalidate).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mapserver.core.errors import FieldError

MARGIN_SCALE = 2.0**-40  # x the largest distance: above the rounding of its sums


class LandmarkHeuristic:
    """ALT tables of ``count`` landmarks over padded grids of ``cells`` cells.

    ``tables(...)`` returns (distances float64 (count, cells) [m], margin [m]), built
    with the given single-source function or taken from the cache."""

    def __init__(self, count: int, cells: int) -> None:
        if count < 0:
            raise FieldError("landmarks", count, "must be >= 0")
        self.count = count
        self._distances = np.full((count, cells), np.inf)
        self._margin = 0.0
        self._key_costs: np.ndarray | None = None
        self._key_unknown: bool | None = None
        self.builds = 0  # how many times the tables were (re)built

    def tables(
        self,
        padded: np.ndarray,
        allow_unknown: bool,
        weights: np.ndarray,
        distances_from: Callable[[int], np.ndarray],
    ) -> tuple[np.ndarray, float]:
        """The landmark tables for the padded costmap ``padded`` (uint8, flat).

        weights: the weight per cost value (inf: impassable); distances_from(cell) ->
        float64 costs [m] from that padded cell to every padded cell (inf: unreachable)."""
        if (
            self._key_costs is not None
            and self._key_unknown == allow_unknown
            and np.array_equal(self._key_costs, padded)
        ):
            return self._distances, self._margin
        self._build(np.isfinite(weights[padded]), distances_from)
        self._key_costs = padded.copy()
        self._key_unknown = allow_unknown
        self.builds += 1
        return self._distances, self._margin

    def _build(self, passable: np.ndarray, distances_from: Callable[[int], np.ndarray]) -> None:
        """Choose the landmarks by the farthest rule and fill their tables."""
        self._distances[:] = np.inf
        candidates = np.flatnonzero(passable)
        if self.count == 0 or candidates.size == 0:
            self._margin = 0.0
            return
        nearest = np.full(passable.shape, np.inf)  # least distance from the chosen ones
        source = int(candidates[0])
        largest = 0.0
        for k in range(self.count):
            d = distances_from(source)
            self._distances[k] = d
            finite = np.isfinite(d)
            if finite.any():
                largest = max(largest, float(d[finite].max()))
            nearest = np.minimum(nearest, d)
            spread = np.where(np.isfinite(nearest), nearest, -1.0)
            source = int(np.argmax(spread))
        self._margin = largest * MARGIN_SCALE
