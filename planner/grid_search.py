"""Grid A* and Dijkstra over a Nav2 costmap (numba, flat arrays, a binary heap).

The grid is 8-connected. Moving onto a cell costs its step length [m] (the resolution,
times sqrt(2) diagonally) times the cell's weight, NavFn's rule (navfn.cpp ``setCostmap``:
``COST_NEUTRAL + COST_FACTOR * cost`` with 50 and 0.8) divided by the neutral cost so that
a free cell weighs 1:

    weight(c) = 1 + 0.016 * c   for graded costs c in 0..252 (a 252 cell weighs 5.03)

LETHAL (254) and INSCRIBED (253) cells are never entered. UNKNOWN (255) cells are entered
only with ``allow_unknown``, at the weight of the highest graded cost (as NavFn maps
unknown to ``COST_OBS - 1``). A diagonal move may not cut the corner of an impassable
cell. The A* heuristic is the octile distance [m] (admissible: no weight is below 1), so
A* and Dijkstra find paths of the same cost (Hart, Nilsson, Raphael 1968).

Buffers the size of the grid are allocated once per ``GridPlanner`` and only the nodes a
search touched are reset, so a search costs what it expands.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from mapserver.core.costvalues import LETHAL, MAX_GRADED, UNKNOWN
from mapserver.core.errors import FleetmapError
from mapserver.core.geometry import GridGeometry

NEUTRAL_COST = 50.0  # NavFn COST_NEUTRAL
COST_FACTOR = 0.8  # NavFn COST_FACTOR
SQRT2 = math.sqrt(2.0)
ALGORITHMS = ("astar", "dijkstra")


def cell_weights(allow_unknown: bool) -> np.ndarray:
    """Weight per cost value (float64[256]); inf where the cell may not be entered."""
    weights = np.full(256, np.inf)
    graded = np.arange(int(MAX_GRADED) + 1)
    weights[graded] = (NEUTRAL_COST + COST_FACTOR * graded) / NEUTRAL_COST
    if allow_unknown:
        weights[UNKNOWN] = weights[MAX_GRADED]
    return weights


@dataclass(frozen=True)
class PlanResult:
    """found; path of (x, y) cell centres [m] from start to goal; length [m] along it;
    cost (sum of step length x weight) [m]; min_clearance [m] from the path's cells to the
    nearest LETHAL cell, exact up to ``clearance_cap`` (reported as the cap beyond it, and
    as None without a path); nodes expanded; planning time [ms]."""

    found: bool
    path: list[tuple[float, float]]
    length: float
    cost: float
    min_clearance: float | None
    expanded: int
    planning_ms: float


class PlanRequestError(FleetmapError, ValueError):
    """A planning request that cannot be served: names the field and value."""

    def __init__(self, field: str, value: object, reason: str) -> None:
        self.field = field
        super().__init__(f"{field}: {reason}, got {value!r}")


class GridPlanner:
    """Plans on costmaps of one geometry, reusing its search buffers between plans.

    clearance_cap: [m] clearance is computed exactly up to this distance.
    """

    def __init__(self, geometry: GridGeometry, clearance_cap: float = 2.0) -> None:
        self.geometry = geometry
        self.clearance_cap = clearance_cap
        n = geometry.size
        self._g = np.full(n, np.inf)
        self._parent = np.full(n, -1, dtype=np.int32)
        self._closed = np.zeros(n, dtype=np.uint8)
        self._touched = np.empty(n, dtype=np.int32)
        self._keys = np.empty(n, dtype=np.float64)
        self._heap = np.empty(n, dtype=np.int32)
        self._pos = np.full(n, -1, dtype=np.int32)

    def plan(
        self,
        costs: np.ndarray,
        start: tuple[float, float],
        goal: tuple[float, float],
        algorithm: str = "astar",
        allow_unknown: bool = True,
    ) -> PlanResult:
        """Plan from ``start`` to ``goal`` [m] on ``costs`` (uint8, (height, width))."""
        if algorithm not in ALGORITHMS:
            raise PlanRequestError(
                "algorithm", algorithm, f"must be one of {', '.join(ALGORITHMS)}"
            )
        g = self.geometry
        if costs.shape != g.shape:
            raise PlanRequestError("costs", costs.shape, f"must have shape {g.shape}")
        cells = []
        for name, point in (("start", start), ("goal", goal)):
            if not g.contains_point(*point):
                xmin, ymin, xmax, ymax = g.bounds
                raise PlanRequestError(
                    name, list(point), f"must be on the map [{xmin}, {xmax}) x [{ymin}, {ymax})"
                )
            col, row = g.world_to_cell(*point)
            cells.append(row * g.width + col)
        t0 = time.perf_counter()
        weights = cell_weights(allow_unknown)
        flat = np.ascontiguousarray(costs).ravel()
        found, cost, expanded, touched = _search(
            flat, g.width, g.height, cells[0], cells[1], weights, g.resolution,
            algorithm == "astar", self._g, self._parent, self._closed, self._touched,
            self._keys, self._heap, self._pos,
        )  # fmt: skip
        path_cells = (
            _trace_path(self._parent, cells[0], cells[1]) if found else np.empty(0, np.int64)
        )
        _reset(self._g, self._parent, self._closed, self._pos, self._touched, touched)
        planning_ms = (time.perf_counter() - t0) * 1e3
        if not found:
            return PlanResult(False, [], 0.0, 0.0, None, int(expanded), planning_ms)
        rows, cols = np.divmod(path_cells, g.width)
        xs = g.origin_x + (cols + 0.5) * g.resolution
        ys = g.origin_y + (rows + 0.5) * g.resolution
        steps = np.hypot(np.diff(xs), np.diff(ys))
        cap_cells = self.clearance_cap / g.resolution
        clearance = _min_clearance(flat, g.width, g.height, path_cells, cap_cells) * g.resolution
        return PlanResult(
            found=True,
            path=list(zip(xs.tolist(), ys.tolist(), strict=True)),
            length=float(steps.sum()),
            cost=float(cost),
            min_clearance=float(clearance),
            expanded=int(expanded),
            planning_ms=planning_ms,
        )


@njit(cache=True, nogil=True, inline="always")
def _sift_up(keys, heap, pos, i):
    """Move heap slot i up to its place (indexed min-heap: heap[slot] = node, pos[node] =
    slot, keys[node] = priority)."""
    node = heap[i]
    key = keys[node]
    while i > 0:
        parent = (i - 1) >> 1
        other = heap[parent]
        if keys[other] <= key:
            break
        heap[i] = other
        pos[other] = i
        i = parent
    heap[i] = node
    pos[node] = i


@njit(cache=True, nogil=True, inline="always")
def _pop(keys, heap, pos, size):
    """Remove and return the node of smallest key from a heap of ``size`` (> 0)."""
    top = heap[0]
    pos[top] = -1
    size -= 1
    if size == 0:
        return top
    node = heap[size]
    key = keys[node]
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and keys[heap[child + 1]] < keys[heap[child]]:
            child += 1
        if keys[heap[child]] >= key:
            break
        heap[i] = heap[child]
        pos[heap[i]] = i
        i = child
    heap[i] = node
    pos[node] = i
    return top


@njit(cache=True, nogil=True, inline="always")
def _octile(r1, c1, r2, c2, resolution):
    """Octile distance [m] between cells (r1, c1) and (r2, c2)."""
    dr = abs(r1 - r2)
    dc = abs(c1 - c2)
    lo = min(dr, dc)
    return resolution * (max(dr, dc) - lo + SQRT2 * lo)


@njit(cache=True, nogil=True)
def _search(costs, width, height, start, goal, weights, resolution, astar,
            g, parent, closed, touched, keys, heap, pos):  # fmt: skip
    """A* (astar) or Dijkstra from start to goal with an indexed heap (decrease-key);
    returns (found, cost, expanded, touched count). ``keys`` holds f per node."""
    n_touched = 0
    if weights[costs[start]] == np.inf or weights[costs[goal]] == np.inf:
        return False, 0.0, 0, n_touched
    goal_r, goal_c = divmod(goal, width)
    start_r, start_c = divmod(start, width)
    hscale = 1.0 if astar else 0.0
    g[start] = 0.0
    keys[start] = hscale * _octile(start_r, start_c, goal_r, goal_c, resolution)
    touched[0] = start
    n_touched = 1
    heap[0] = start
    pos[start] = 0
    size = 1
    expanded = 0
    diag = resolution * SQRT2
    while size > 0:
        node = _pop(keys, heap, pos, size)
        size -= 1
        closed[node] = 1
        expanded += 1
        if node == goal:
            return True, g[node], expanded, n_touched
        row, col = divmod(node, width)
        base = g[node]
        for dr in range(-1, 2):
            r = row + dr
            if r < 0 or r >= height:
                continue
            for dc in range(-1, 2):
                if dr == 0 and dc == 0:
                    continue
                c = col + dc
                if c < 0 or c >= width:
                    continue
                nb = node + dr * width + dc
                if closed[nb]:
                    continue
                w = weights[costs[nb]]
                if w == np.inf:
                    continue
                if dr != 0 and dc != 0:
                    # no cutting the corner of an impassable cell
                    if weights[costs[node + dc]] == np.inf:
                        continue
                    if weights[costs[node + dr * width]] == np.inf:
                        continue
                    step = diag
                else:
                    step = resolution
                candidate = base + step * w
                old = g[nb]
                if candidate < old:
                    g[nb] = candidate
                    parent[nb] = node
                    keys[nb] = candidate + hscale * _octile(r, c, goal_r, goal_c, resolution)
                    if old == np.inf:  # first reached: a new heap entry
                        touched[n_touched] = nb
                        n_touched += 1
                        heap[size] = nb
                        size += 1
                        _sift_up(keys, heap, pos, size - 1)
                    else:  # already in the heap: decrease its key
                        _sift_up(keys, heap, pos, pos[nb])
    return False, 0.0, expanded, n_touched


@njit(cache=True, nogil=True)
def _trace_path(parent, start, goal):
    """Cells from start to goal following parents back from the goal."""
    count = 1
    node = goal
    while node != start:
        node = parent[node]
        count += 1
    path = np.empty(count, dtype=np.int64)
    node = goal
    for i in range(count - 1, -1, -1):
        path[i] = node
        node = parent[node]
    return path


@njit(cache=True, nogil=True)
def _reset(g, parent, closed, pos, touched, n):
    """Undo a search on the nodes it touched."""
    for i in range(n):
        node = touched[i]
        g[node] = np.inf
        parent[node] = -1
        closed[node] = 0
        pos[node] = -1


@njit(cache=True, nogil=True)
def _min_clearance(costs, width, height, path, cap):
    """Smallest distance [cells] from a path cell's centre to a LETHAL cell's centre,
    searched within the best found so far (starting at ``cap``); ``cap`` if none nearer."""
    best = cap
    for k in range(path.shape[0]):
        row, col = divmod(path[k], width)
        reach = int(math.ceil(best))
        for r in range(max(0, row - reach), min(height, row + reach + 1)):
            dr = r - row
            for c in range(max(0, col - reach), min(width, col + reach + 1)):
                if costs[r * width + c] == LETHAL:
                    dc = c - col
                    d = math.sqrt(dr * dr + dc * dc)
                    if d < best:
                        best = d
        if best == 0.0:
            break
    return best
