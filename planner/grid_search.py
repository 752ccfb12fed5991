"""Grid A* and Dijkstra over a Nav2 costmap (numba, flat arrays, a bucket queue).

The grid is 8-connected. Moving onto a cell costs its step length [m] (the resolution,
times sqrt(2) diagonally) times the cell's weight, NavFn's rule (navfn.cpp ``setCostmap``:
``COST_NEUTRAL + COST_FACTOR * cost`` with 50 and 0.8) divided by the neutral cost so that
a free cell weighs 1:

    weight(c) = 1 + 0.016 * c   for graded costs c in 0..252 (a 252 cell weighs 5.03)

LETHAL (254) and INSCRIBED (253) cells are never entered. UNKNOWN (255) cells are entered
only with ``allow_unknown``, at the weight of the highest graded cost (as NavFn maps
unknown to ``COST_OBS - 1``). A diagonal move may not cut the corner of an impassable
cell. The A* heuristic is the octile distance [m] (consistent: no weight is below 1), so
A* and Dijkstra find paths of the same cost (Hart, Nilsson, Raphael 1968).

The open list is a bucket queue over f (Dial 1969; Dinitz 1978): bucket b holds the
nodes of f in [b, b + 1) x ``BUCKET_WIDTH`` cells, each a LIFO list, in a circular array
as wide as the largest step can raise f. A node is expanded when its bucket comes up, so
a node of the same bucket may still lower its g afterwards: it is then reopened (label
correcting), and the search ends only when the lowest bucket left starts at or above the
goal's g, i.e. every node still open has f >= that cost. The path cost is therefore the
optimum, as with an exact priority queue, up to floating-point rounding: on an expanded
node, gains below ``REOPEN_TOLERANCE`` cells (the same cost summed in another order) do
not reopen it. ``expanded`` counts distinct nodes expanded.

With ``landmarks`` (``planner.landmarks``) the heuristic is also raised by ALT bounds,
admissible and consistent up to their margin. Once the goal has a cost, a node whose f
is within ``REOPEN_TOLERANCE`` plus that margin of it is neither queued nor expanded: it
cannot lead to a cheaper path, and with a heuristic exact along shortest paths this
stops the search expanding every cell of every equal-cost path.

Buffers the size of the grid are allocated once per ``GridPlanner`` and only the nodes a
search touched are reset, so a search costs what it expands. A node is two arrays: its g
[m] (float64, 8 B: the array the neighbour scans read) and one byte of state and parent
direction. A queue entry carries the g its node had when queued: the entry is stale once
that g has fallen (every push lowers it), so no bucket tag is kept per node.

Speed (numba): the search loop never rebinds an array (an entry pool that runs out makes
the search return, and it is run again with twice the room), and the eight moves are
written out rather than a helper called per move: either makes numba count references
to the arrays atomically in the loop, which cost more than half of the search's time.
Without landmarks the kernel gets ``None`` for their tables, so their loop is compiled
out. Every array index in the loop is cast to ``np.uint64`` (the same bits: indices here
are never negative), so numba leaves out its wrap-around of negative indices at each
access (1.23x corner to corner on the benchmark map, the same path and nodes).
Bidirectional search was weighed on the 2000 x 2000 benchmark map and not taken:
counted from the exact distances from both ends, front-to-end bidirectional A* that meets
in the middle (MM: Holte, Felner, Sharon, Sturtevant 2016) would expand 2.1 million nodes
and the average-potential rule (Ikeda et al. 1994; Goldberg, Harrelson 2005) 1.9 to 2.1
million, where this A* expands 1.68 million: the octile bound is weak there.
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
from planner.landmarks import LandmarkHeuristic

NEUTRAL_COST = 50.0  # NavFn COST_NEUTRAL
COST_FACTOR = 0.8  # NavFn COST_FACTOR
SQRT2 = math.sqrt(2.0)
_ROW_STEPS = (0, 0, 1, -1, 1, 1, -1, -1)  # the 8 moves: E, W, S, N, then the diagonals
_COL_STEPS = (1, -1, 0, 0, 1, -1, 1, -1)
ALGORITHMS = ("astar", "dijkstra")
# A node's byte of ``info``: state | move << 2. state 0 never expanded, 1 expanded at its
# g, 2 expanded before and improved since; move (0..7) the step that reached it, from its
# parent, in the order of _ROW_STEPS / _COL_STEPS.
BUCKET_WIDTH = 1.0 / 8  # [cells] of f per bucket of the queue
REOPEN_TOLERANCE = 1e-9  # [cells]: smaller gains on an expanded node are rounding


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
    landmarks: how many ALT landmarks raise the A* heuristic (``planner.landmarks``); 0,
    the default, is the octile distance alone. Their tables (8 B per cell each) are built
    by one Dijkstra per landmark on the first A* plan over a costmap and reused while its
    content stays the same: worth it when many plans share one costmap, a loss when the
    costmap changes between plans, unless the plans give ``bounds`` (``plan``).
    """

    def __init__(
        self, geometry: GridGeometry, clearance_cap: float = 2.0, landmarks: int = 0
    ) -> None:
        self.geometry = geometry
        self.clearance_cap = clearance_cap
        self._wp = geometry.width + 2  # a border of LETHAL cells spares the bounds checks
        n = self._wp * (geometry.height + 2)
        self.landmarks = LandmarkHeuristic(landmarks, n)
        self._padded = np.full((geometry.height + 2, self._wp), LETHAL, dtype=np.uint8)
        self._padded_bounds = self._padded.copy()
        self.bounded_plans = 0  # A* plans whose landmarks came from ``bounds``
        self._g = np.full(n, np.inf)  # [m] from the start; inf: not reached
        self._info = np.zeros(n, dtype=np.uint8)  # state | move << 2 (see _ROW_STEPS)
        self._touched = np.empty(n, dtype=np.int32)
        self._grow_entries(1 << 16)

    def plan(
        self,
        costs: np.ndarray,
        start: tuple[float, float],
        goal: tuple[float, float],
        algorithm: str = "astar",
        allow_unknown: bool = True,
        bounds: np.ndarray | None = None,
    ) -> PlanResult:
        """Plan from ``start`` to ``goal`` [m] on ``costs`` (uint8, (height, width)).

        bounds: a costmap of the same shape no dearer than ``costs`` anywhere (each
        cell's weight at most its weight in ``costs``, so impassable only where ``costs``
        is), e.g. the static map's costs with unknown as free and inflated; the landmark
        tables are then built on it and kept while it stays the same, however ``costs``
        changes above it (Nav2 Smac caches its obstacle heuristic likewise). It is
        checked on every plan: where it is not below ``costs`` the plan uses no landmarks
        (the octile heuristic, as exact). Without ``bounds`` the tables follow ``costs``.
        """
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
            cells.append((row + 1) * self._wp + col + 1)
        t0 = time.perf_counter()
        weights = cell_weights(allow_unknown)
        flat = np.ascontiguousarray(costs).ravel()
        self._padded[1:-1, 1:-1] = costs
        padded = self._padded.ravel()
        lm, lm_goal, margin = None, np.empty(0), 0.0
        base = padded if bounds is None else self._lower_bounds(bounds, padded, weights)
        if algorithm == "astar" and self.landmarks.count and base is not None:
            lm, margin = self.landmarks.tables(
                base, allow_unknown, weights,
                lambda source: self._distances_from(base, source, weights),
            )  # fmt: skip
            self.bounded_plans += bounds is not None
            at_goal = lm[:, cells[1]].astype(np.float64)
            lm_goal = np.where(np.isfinite(at_goal), at_goal, -np.inf)
        found, cost, expanded, touched = self._run(
            padded, cells[0], cells[1], weights, float(algorithm == "astar"), lm, lm_goal, margin
        )
        if found:
            path = _trace_path(self._info, self._wp, cells[0], cells[1])
            rows, cols = np.divmod(path, self._wp)
            path_cells = (rows - 1) * g.width + cols - 1
        _reset(self._g, self._info, self._touched, touched)
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

    def _lower_bounds(self, bounds, padded, weights) -> np.ndarray | None:
        """``bounds`` padded like the costs, or None where a cell weighs more in it than
        in ``padded`` (it would not bound the costs from below)."""
        if bounds.shape != self.geometry.shape:
            raise PlanRequestError("bounds", bounds.shape, f"must have shape {self.geometry.shape}")
        self._padded_bounds[1:-1, 1:-1] = bounds
        flat = self._padded_bounds.ravel()
        return flat if _weighs_no_more(flat, padded, weights) else None

    def _run(self, padded, start, goal, weights, hscale, lm, lm_goal, margin):
        """One ``_search`` on the padded grid; returns (found, cost, expanded, touched),
        the nodes left set for the caller to read and reset."""
        g = self.geometry
        top = np.max(weights[np.isfinite(weights)])
        # f stays below the grid's size x the dearest step: at most 2**28 buckets
        width = max(g.resolution * BUCKET_WIDTH, g.size * SQRT2 * g.resolution * top / 2**28)
        span = 1 << int(math.ceil(SQRT2 * g.resolution * (top + 1.0) / width) + 2).bit_length()
        heads = np.empty(span, np.int32)
        while True:
            found, cost, expanded, touched = _search(
                padded, self._wp, start, goal, weights, g.resolution, hscale, width, self._g,
                self._info, self._touched, heads, self._entry_node, self._entry_g,
                self._entry_next, lm, lm_goal, margin,
            )  # fmt: skip
            if found >= 0:
                return bool(found), cost, expanded, touched
            _reset(self._g, self._info, self._touched, touched)  # out of entries: again
            self._grow_entries(2 * self._entry_node.shape[0])

    def _grow_entries(self, capacity: int) -> None:
        """Room for ``capacity`` queue entries (node, g [m], next), kept between plans."""
        self._entry_node = np.empty(capacity, dtype=np.int32)
        self._entry_g = np.empty(capacity)
        self._entry_next = np.empty(capacity, dtype=np.int32)

    def _distances_from(self, padded, source, weights) -> np.ndarray:
        """Dijkstra's costs [m] from padded cell ``source`` to every padded cell (inf
        where unreachable)."""
        touched = self._run(padded, source, -1, weights, 0.0, None, np.empty(0), 0.0)[3]
        distances = self._g.copy()
        _reset(self._g, self._info, self._touched, touched)
        return distances


@njit(cache=True, nogil=True, inline="always")
def _octile(r1, c1, r2, c2, resolution):
    """Octile distance [m] between cells (r1, c1) and (r2, c2)."""
    dr = abs(r1 - r2)
    dc = abs(c1 - c2)
    lo = min(dr, dc)
    return resolution * (max(dr, dc) - lo + SQRT2 * lo)


@njit(cache=True, nogil=True, inline="always")
def _heuristic(r, c, node, goal_r, goal_c, resolution, hscale, lm, lm_goal, margin):
    """Lower bound [m] on the cost from cell (r, c) (padded index ``node``) to the goal:
    hscale x octile, raised by the landmark bounds ``lm_goal[k] - lm[k, node] - margin``
    (``landmarks.LandmarkHeuristic``; none when ``lm`` is None or has no rows: a None
    ``lm`` compiles the loop out)."""
    h = hscale * _octile(r, c, goal_r, goal_c, resolution)
    if lm is not None:
        for k in range(lm.shape[0]):
            bound = lm_goal[k] - lm[k, node] - margin
            if bound > h:
                h = bound
    return h


@njit(cache=True, nogil=True)
def _search(costs, wp, start, goal, weights, resolution, hscale, width, g, info,
            touched, heads, entry_node, entry_g, entry_next, lm, lm_goal, margin):  # fmt: skip
    """A* (f = g + h, h from ``_heuristic``; hscale 0 and no landmarks is Dijkstra) from
    start to goal over a bucket queue; returns (found: 1 or 0, or -1 when the entries ran
    out, cost [m], expanded, touched count). A goal of -1 searches every reachable cell
    (Dijkstra's distances stay in ``g``).

    ``costs`` is the padded grid (``wp`` columns, a LETHAL border). Bucket ``b`` holds
    the entries of f in [b, b + 1) x ``width``, a LIFO list each, kept in the circular
    ``heads`` (a power of two slots); an entry whose g is no longer its node's is stale.
    The entry arrays are never replaced here (see the module on numba)."""
    n_touched = 0
    if weights[costs[np.uint64(start)]] == np.inf or (
        goal >= 0 and weights[costs[np.uint64(goal)]] == np.inf
    ):
        return 0, 0.0, 0, n_touched
    goal_r, goal_c = divmod(goal, wp)
    start_r, start_c = divmod(start, wp)
    inv = 1.0 / width
    mask = heads.shape[0] - 1  # a power of two
    tolerance = REOPEN_TOLERANCE * resolution
    slack = tolerance + margin  # f within this of the goal's cost is a tie, not a gain
    bound = np.inf  # the goal's cost - slack: f at or above it cannot beat the goal
    diag = resolution * SQRT2
    heads[:] = -1
    capacity = entry_node.shape[0]
    free = -1  # recycled entries
    g[np.uint64(start)] = 0.0
    h0 = _heuristic(
        start_r, start_c, start, goal_r, goal_c, resolution, hscale, lm, lm_goal, margin
    )
    cur = np.int64(h0 * inv)
    touched[0] = start
    n_touched = 1
    entry_node[0] = start
    entry_g[0] = 0.0
    entry_next[0] = -1
    heads[np.uint64(cur & mask)] = 0
    top = 1  # entries ever used
    size = 1
    expanded = 0
    slot = cur & mask
    while size > 0:
        while heads[np.uint64(slot)] == -1:
            cur += 1
            slot = (slot + 1) & mask
        if goal >= 0 and cur * width >= g[np.uint64(goal)]:
            break  # every entry left has f >= the goal's cost
        e = heads[np.uint64(slot)]
        heads[np.uint64(slot)] = entry_next[np.uint64(e)]
        entry_next[np.uint64(e)] = free
        free = e
        size -= 1
        node = entry_node[np.uint64(e)]
        base = g[np.uint64(node)]
        if base != entry_g[np.uint64(e)]:
            continue  # stale: its node's g fell since
        row, col = divmod(node, wp)
        if node != goal and bound < np.inf:
            h = _heuristic(row, col, node, goal_r, goal_c, resolution, hscale, lm, lm_goal, margin)
            if base + h >= bound:
                continue  # no path through it beats the goal's cost (ties: see the module)
        state = info[np.uint64(node)]
        if state & 3 == 0:
            expanded += 1
        info[np.uint64(node)] = (state & ~3) | 1
        if node == goal:
            continue
        if top + 8 > capacity:
            return -1, 0.0, expanded, n_touched  # the caller grows the entries, runs again
        w_east = weights[costs[np.uint64(node + 1)]]
        w_west = weights[costs[np.uint64(node - 1)]]
        w_south = weights[costs[np.uint64(node + wp)]]
        w_north = weights[costs[np.uint64(node - wp)]]
        # E, W, S (then SE, SW), N (then NE, NW): a diagonal needs both cells beside it
        if w_east != np.inf:
            candidate = base + resolution * w_east
            nb = node + 1
            old = g[np.uint64(nb)]
            while candidate < old:  # one pass: ``break`` leaves the move
                h = _heuristic(
                    row, col + 1, nb, goal_r, goal_c, resolution, hscale, lm, lm_goal, margin
                )
                if candidate + h >= bound:
                    break  # cannot beat the goal's cost (ties: see the module)
                state = 0
                if old == np.inf:
                    touched[np.uint64(n_touched)] = nb
                    n_touched += 1
                else:
                    state = info[np.uint64(nb)] & 3
                    if state == 1:
                        if candidate > old - tolerance:
                            break  # the same cost summed in another order: no reopening
                        state = 2
                g[np.uint64(nb)] = candidate
                info[np.uint64(nb)] = state | 0
                if nb == goal:
                    bound = candidate - slack
                b = max(cur, np.int64((candidate + h) * inv))  # b < cur: rounding only
                if free != -1:
                    e = free
                    free = entry_next[np.uint64(e)]
                else:
                    e = top
                    top += 1
                entry_node[np.uint64(e)] = nb
                entry_g[np.uint64(e)] = candidate
                entry_next[np.uint64(e)] = heads[np.uint64(b & mask)]
                heads[np.uint64(b & mask)] = e
                size += 1
                break
        if w_west != np.inf:
            candidate = base + resolution * w_west
            nb = node - 1
            old = g[np.uint64(nb)]
            while candidate < old:  # one pass: ``break`` leaves the move
                h = _heuristic(
                    row, col - 1, nb, goal_r, goal_c, resolution, hscale, lm, lm_goal, margin
                )
                if candidate + h >= bound:
                    break  # cannot beat the goal's cost (ties: see the module)
                state = 0
                if old == np.inf:
                    touched[np.uint64(n_touched)] = nb
                    n_touched += 1
                else:
                    state = info[np.uint64(nb)] & 3
                    if state == 1:
                        if candidate > old - tolerance:
                            break  # the same cost summed in another order: no reopening
                        state = 2
                g[np.uint64(nb)] = candidate
                info[np.uint64(nb)] = state | 4
                if nb == goal:
                    bound = candidate - slack
                b = max(cur, np.int64((candidate + h) * inv))  # b < cur: rounding only
                if free != -1:
                    e = free
                    free = entry_next[np.uint64(e)]
                else:
                    e = top
                    top += 1
                entry_node[np.uint64(e)] = nb
                entry_g[np.uint64(e)] = candidate
                entry_next[np.uint64(e)] = heads[np.uint64(b & mask)]
                heads[np.uint64(b & mask)] = e
                size += 1
                break
        if w_south != np.inf:
            candidate = base + resolution * w_south
            nb = node + wp
            old = g[np.uint64(nb)]
            while candidate < old:  # one pass: ``break`` leaves the move
                h = _heuristic(
                    row + 1, col, nb, goal_r, goal_c, resolution, hscale, lm, lm_goal, margin
                )
                if candidate + h >= bound:
                    break  # cannot beat the goal's cost (ties: see the module)
                state = 0
                if old == np.inf:
                    touched[np.uint64(n_touched)] = nb
                    n_touched += 1
                else:
                    state = info[np.uint64(nb)] & 3
                    if state == 1:
                        if candidate > old - tolerance:
                            break  # the same cost summed in another order: no reopening
                        state = 2
                g[np.uint64(nb)] = candidate
                info[np.uint64(nb)] = state | 8
                if nb == goal:
                    bound = candidate - slack
                b = max(cur, np.int64((candidate + h) * inv))  # b < cur: rounding only
                if free != -1:
                    e = free
                    free = entry_next[np.uint64(e)]
                else:
                    e = top
                    top += 1
                entry_node[np.uint64(e)] = nb
                entry_g[np.uint64(e)] = candidate
                entry_next[np.uint64(e)] = heads[np.uint64(b & mask)]
                heads[np.uint64(b & mask)] = e
                size += 1
                break
            if w_east != np.inf:
                w = weights[costs[np.uint64(node + wp + 1)]]
                if w != np.inf:
                    candidate = base + diag * w
                    nb = node + wp + 1
                    old = g[np.uint64(nb)]
                    while candidate < old:  # one pass: ``break`` leaves the move
                        h = _heuristic(
                            row + 1,
                            col + 1,
                            nb,
                            goal_r,
                            goal_c,
                            resolution,
                            hscale,
                            lm,
                            lm_goal,
                            margin,
                        )
                        if candidate + h >= bound:
                            break  # cannot beat the goal's cost (ties: see the module)
                        state = 0
                        if old == np.inf:
                            touched[np.uint64(n_touched)] = nb
                            n_touched += 1
                        else:
                            state = info[np.uint64(nb)] & 3
                            if state == 1:
                                if candidate > old - tolerance:
                                    break  # the same cost summed in another order: no reopening
                                state = 2
                        g[np.uint64(nb)] = candidate
                        info[np.uint64(nb)] = state | 16
                        if nb == goal:
                            bound = candidate - slack
                        b = max(cur, np.int64((candidate + h) * inv))  # b < cur: rounding only
                        if free != -1:
                            e = free
                            free = entry_next[np.uint64(e)]
                        else:
                            e = top
                            top += 1
                        entry_node[np.uint64(e)] = nb
                        entry_g[np.uint64(e)] = candidate
                        entry_next[np.uint64(e)] = heads[np.uint64(b & mask)]
                        heads[np.uint64(b & mask)] = e
                        size += 1
                        break
            if w_west != np.inf:
                w = weights[costs[np.uint64(node + wp - 1)]]
                if w != np.inf:
                    candidate = base + diag * w
                    nb = node + wp - 1
                    old = g[np.uint64(nb)]
                    while candidate < old:  # one pass: ``break`` leaves the move
                        h = _heuristic(
                            row + 1,
                            col - 1,
                            nb,
                            goal_r,
                            goal_c,
                            resolution,
                            hscale,
                            lm,
                            lm_goal,
                            margin,
                        )
                        if candidate + h >= bound:
                            break  # cannot beat the goal's cost (ties: see the module)
                        state = 0
                        if old == np.inf:
                            touched[np.uint64(n_touched)] = nb
                            n_touched += 1
                        else:
                            state = info[np.uint64(nb)] & 3
                            if state == 1:
                                if candidate > old - tolerance:
                                    break  # the same cost summed in another order: no reopening
                                state = 2
                        g[np.uint64(nb)] = candidate
                        info[np.uint64(nb)] = state | 20
                        if nb == goal:
                            bound = candidate - slack
                        b = max(cur, np.int64((candidate + h) * inv))  # b < cur: rounding only
                        if free != -1:
                            e = free
                            free = entry_next[np.uint64(e)]
                        else:
                            e = top
                            top += 1
                        entry_node[np.uint64(e)] = nb
                        entry_g[np.uint64(e)] = candidate
                        entry_next[np.uint64(e)] = heads[np.uint64(b & mask)]
                        heads[np.uint64(b & mask)] = e
                        size += 1
                        break
        if w_north != np.inf:
            candidate = base + resolution * w_north
            nb = node - wp
            old = g[np.uint64(nb)]
            while candidate < old:  # one pass: ``break`` leaves the move
                h = _heuristic(
                    row - 1, col, nb, goal_r, goal_c, resolution, hscale, lm, lm_goal, margin
                )
                if candidate + h >= bound:
                    break  # cannot beat the goal's cost (ties: see the module)
                state = 0
                if old == np.inf:
                    touched[np.uint64(n_touched)] = nb
                    n_touched += 1
                else:
                    state = info[np.uint64(nb)] & 3
                    if state == 1:
                        if candidate > old - tolerance:
                            break  # the same cost summed in another order: no reopening
                        state = 2
                g[np.uint64(nb)] = candidate
                info[np.uint64(nb)] = state | 12
                if nb == goal:
                    bound = candidate - slack
                b = max(cur, np.int64((candidate + h) * inv))  # b < cur: rounding only
                if free != -1:
                    e = free
                    free = entry_next[np.uint64(e)]
                else:
                    e = top
                    top += 1
                entry_node[np.uint64(e)] = nb
                entry_g[np.uint64(e)] = candidate
                entry_next[np.uint64(e)] = heads[np.uint64(b & mask)]
                heads[np.uint64(b & mask)] = e
                size += 1
                break
            if w_east != np.inf:
                w = weights[costs[np.uint64(node - wp + 1)]]
                if w != np.inf:
                    candidate = base + diag * w
                    nb = node - wp + 1
                    old = g[np.uint64(nb)]
                    while candidate < old:  # one pass: ``break`` leaves the move
                        h = _heuristic(
                            row - 1,
                            col + 1,
                            nb,
                            goal_r,
                            goal_c,
                            resolution,
                            hscale,
                            lm,
                            lm_goal,
                            margin,
                        )
                        if candidate + h >= bound:
                            break  # cannot beat the goal's cost (ties: see the module)
                        state = 0
                        if old == np.inf:
                            touched[np.uint64(n_touched)] = nb
                            n_touched += 1
                        else:
                            state = info[np.uint64(nb)] & 3
                            if state == 1:
                                if candidate > old - tolerance:
                                    break  # the same cost summed in another order: no reopening
                                state = 2
                        g[np.uint64(nb)] = candidate
                        info[np.uint64(nb)] = state | 24
                        if nb == goal:
                            bound = candidate - slack
                        b = max(cur, np.int64((candidate + h) * inv))  # b < cur: rounding only
                        if free != -1:
                            e = free
                            free = entry_next[np.uint64(e)]
                        else:
                            e = top
                            top += 1
                        entry_node[np.uint64(e)] = nb
                        entry_g[np.uint64(e)] = candidate
                        entry_next[np.uint64(e)] = heads[np.uint64(b & mask)]
                        heads[np.uint64(b & mask)] = e
                        size += 1
                        break
            if w_west != np.inf:
                w = weights[costs[np.uint64(node - wp - 1)]]
                if w != np.inf:
                    candidate = base + diag * w
                    nb = node - wp - 1
                    old = g[np.uint64(nb)]
                    while candidate < old:  # one pass: ``break`` leaves the move
                        h = _heuristic(
                            row - 1,
                            col - 1,
                            nb,
                            goal_r,
                            goal_c,
                            resolution,
                            hscale,
                            lm,
                            lm_goal,
                            margin,
                        )
                        if candidate + h >= bound:
                            break  # cannot beat the goal's cost (ties: see the module)
                        state = 0
                        if old == np.inf:
                            touched[np.uint64(n_touched)] = nb
                            n_touched += 1
                        else:
                            state = info[np.uint64(nb)] & 3
                            if state == 1:
                                if candidate > old - tolerance:
                                    break  # the same cost summed in another order: no reopening
                                state = 2
                        g[np.uint64(nb)] = candidate
                        info[np.uint64(nb)] = state | 28
                        if nb == goal:
                            bound = candidate - slack
                        b = max(cur, np.int64((candidate + h) * inv))  # b < cur: rounding only
                        if free != -1:
                            e = free
                            free = entry_next[np.uint64(e)]
                        else:
                            e = top
                            top += 1
                        entry_node[np.uint64(e)] = nb
                        entry_g[np.uint64(e)] = candidate
                        entry_next[np.uint64(e)] = heads[np.uint64(b & mask)]
                        heads[np.uint64(b & mask)] = e
                        size += 1
                        break
    if goal < 0:
        return 0, 0.0, expanded, n_touched
    cost = g[np.uint64(goal)]
    found = cost < np.inf
    return int(found), cost if found else 0.0, expanded, n_touched


@njit(cache=True, nogil=True)
def _trace_path(info, wp, start, goal):
    """Cells from start to goal, stepping back from the goal by each cell's move."""
    back = np.empty(8, dtype=np.int64)  # padded index of a cell - its parent's
    for k in range(8):
        back[k] = _ROW_STEPS[k] * wp + _COL_STEPS[k]
    count = 1
    node = goal
    while node != start:
        node -= back[info[node] >> 2]
        count += 1
    path = np.empty(count, dtype=np.int64)
    node = goal
    for i in range(count - 1, -1, -1):
        path[i] = node
        node -= back[info[node] >> 2]
    return path


@njit(cache=True, nogil=True)
def _weighs_no_more(lower, costs, weights):
    """Whether every cell weighs no more in ``lower`` than in ``costs`` (inf <= inf)."""
    for i in range(lower.size):
        if weights[lower[i]] > weights[costs[i]]:
            return False
    return True


@njit(cache=True, nogil=True)
def _reset(g, info, touched, n):
    """Undo a search on the nodes it touched."""
    for i in range(n):
        node = touched[i]
        g[node] = np.inf
        info[node] = 0


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
