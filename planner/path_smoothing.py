"""Line-of-sight shortcuts of a grid path: the few straight legs a drive can follow.

An 8-connected A* path is a staircase of cell centres with a turn of 45 or 90 degrees
every few cells; driven as is, a unit would slow or stop at each. ``smooth_path`` keeps
the path's first and last points and, greedily from the start, replaces each stretch by
the straight line to the farthest later path point it can see (the "string pulling" of
post-smoothed A*: Botea, Mueller and Schaeffer, *Near Optimal Hierarchical
Path-Finding*, J. Game Development 1, 2004; Daniel, Nash, Koenig and Felner, *Theta\\**,
JAIR 39, 2010, section 2).

A line may replace a stretch only if it is as safe as the stretch: no cell it passes
through (every cell it touches, so it never slips between two diagonal neighbours) is
lethal or inscribed, and none costs more than the costliest cell of the stretch it
replaces (unknown counts as the highest cost). So the smoothed path never enters an inscribed
cell, never crosses unknown space the plan avoided, and keeps at least the clearance of
the plan.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from mapserver.core.costvalues import INSCRIBED, LETHAL
from mapserver.core.geometry import GridGeometry

Point = tuple[float, float]

LOOK_PAST = 12
"""[path points] how far past the first point it cannot see the search keeps looking
(a staircase hides a point now and then that a longer line sees again)."""

_BLOCKED = 1 << 16  # above every cost: a line through a lethal or inscribed cell


def smooth_path(path: Sequence[Point], costs: np.ndarray, geometry: GridGeometry) -> list[Point]:
    """The shortcut ``path`` [(x, y) m, cell centres as ``GridPlanner`` returns them] on
    ``costs`` (H, W uint8); its first and last points are kept (module docstring)."""
    if len(path) <= 2:
        return [tuple(p) for p in path]
    pts = np.asarray(path, dtype=np.float64)
    cols, rows, _ = geometry.points_to_cells(pts)  # the planner's cells: all on the grid
    keep = _shortcut(np.ascontiguousarray(costs), cols, rows)
    return [(float(pts[i, 0]), float(pts[i, 1])) for i in keep]


@njit(cache=True, nogil=True)
def _cost(v):
    return _BLOCKED if v == LETHAL or v == INSCRIBED else np.int64(v)


@njit(cache=True, nogil=True, inline="always")
def line_start(c0, r0, c1, r1):
    """The supercover of the segment between the centres of cells (c0, r0) and (c1, r1):
    every cell it passes through, both cells beside a corner it crosses, by Amanatides
    and Woo's traversal (*A Fast Voxel Traversal Algorithm*, Eurographics 1987) in exact
    integer arithmetic. Returns the walk's state, at cell (c0, r0); ``line_step`` moves
    it on while ``line_more``."""
    return (c0, r0, 0, 0, abs(c1 - c0), abs(r1 - r0), 1 if c1 > c0 else -1,
            1 if r1 > r0 else -1)  # fmt: skip


@njit(cache=True, nogil=True, inline="always")
def line_more(state):
    """Does the walk have a cell after its current one?"""
    _, _, kc, kr, dc, dr, _, _ = state
    return kc < dc or kr < dr


@njit(cache=True, nogil=True, inline="always")
def line_step(state):
    """(the state at the next cell, corner): corner True when the segment went through
    a corner on the way, so that both side cells, (c + sc, r) and (c, r + sr) of the
    old cell (c, r), touch it too."""
    c, r, kc, kr, dc, dr, sc, sr = state
    # next boundary along the segment at t = (2k + 1) / (2 d): compare across axes
    col_t = (2 * kc + 1) * dr if kc < dc else -1
    row_t = (2 * kr + 1) * dc if kr < dr else -1
    if row_t < 0 or (0 <= col_t < row_t):
        return (c + sc, r, kc + 1, kr, dc, dr, sc, sr), False
    if col_t < 0 or row_t < col_t:
        return (c, r + sr, kc, kr + 1, dc, dr, sc, sr), False
    return (c + sc, r + sr, kc + 1, kr + 1, dc, dr, sc, sr), True


@njit(cache=True, nogil=True)
def _line_cost(costs, c0, r0, c1, r1):
    """The highest cost of every cell the segment between the centres of (c0, r0) and
    (c1, r1) passes through (``line_start``)."""
    state = line_start(c0, r0, c1, r1)
    worst = _cost(costs[r0, c0])
    while line_more(state):
        c, r, _, _, _, _, sc, sr = state
        state, corner = line_step(state)
        if corner:
            worst = max(worst, _cost(costs[r, c + sc]), _cost(costs[r + sr, c]))
        worst = max(worst, _cost(costs[state[1], state[0]]))
    return worst


@njit(cache=True, nogil=True)
def _shortcut(costs, cols, rows):
    """Indices of the path points kept (module docstring)."""
    n = cols.shape[0]
    keep = [0]
    i = 0
    while i < n - 1:
        best = i + 1
        stretch = max(_cost(costs[rows[i], cols[i]]), _cost(costs[rows[i + 1], cols[i + 1]]))
        j = i + 2
        while j < n and j - best <= LOOK_PAST:
            stretch = max(stretch, _cost(costs[rows[j], cols[j]]))
            if stretch < _BLOCKED and _line_cost(costs, cols[i], rows[i], cols[j], rows[j]) <= (
                stretch
            ):
                best = j
            j += 1
        keep.append(best)
        i = best
    return keep
