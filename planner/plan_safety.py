"""Unsafe plans: a plan whose footprint crosses cells that are lethal or inscribed in
ground truth (docs/files.md 3: ``stale_free_plans``, ``inscribed_plans``).

A plan is the path sent to a drive: a few straight legs (``planner.path_smoothing``)
that the unit's centre follows. Its footprint crosses a cell when a leg passes through
it (every cell a leg touches, ``line_start``). On the ground-truth costmap (inflated
as the server inflates, so INSCRIBED marks where a unit's centre puts its body on an
obstacle):

- a truly LETHAL cell on the way: the plan drives through an obstacle the map forgot
  or never saw (a *stale-free* plan);
- a truly INSCRIBED cell and no lethal one: the unit's body would touch an obstacle
  (a rack face 0.26 m from the centre line of a unit 0.3 m in radius).

The cells under the unit's body where the plan starts (centres within ``radius`` of its
first point) are left out: the unit stands there already, and a plan leaving a place
beside a rack is not what put it there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from mapserver.core.costvalues import INSCRIBED, LETHAL
from mapserver.core.geometry import GridGeometry
from planner.path_smoothing import line_more, line_start, line_step

Point = tuple[float, float]


@dataclass(frozen=True)
class PlanSafety:
    """The centres [m] of the truly lethal and truly inscribed cells a plan's legs
    cross, in the order it reaches them (both empty: a safe plan)."""

    lethal: tuple[Point, ...] = ()
    inscribed: tuple[Point, ...] = ()


def plan_safety(
    path: Sequence[Point], truth_costs: np.ndarray, geometry: GridGeometry, radius: float
) -> PlanSafety:
    """Check ``path`` [(x, y) m] on ``truth_costs`` (uint8 Nav2, the grid) for a unit of
    ``radius`` [m] (module docstring). Points off the grid are left out."""
    if not path:
        return PlanSafety()
    pts = np.asarray(path, dtype=np.float64).reshape(-1, 2)
    cols, rows, inside = geometry.points_to_cells(pts)
    cols, rows = cols[inside], rows[inside]
    seen: dict[tuple[int, int], None] = {}
    for k in range(len(cols)):
        c1, r1 = int(cols[k]), int(rows[k])
        c0, r0 = (int(cols[k - 1]), int(rows[k - 1])) if k else (c1, r1)
        for c, r in leg_cells(c0, r0, c1, r1).tolist():
            seen.setdefault((c, r), None)
    cells = np.array(list(seen), dtype=np.int64).reshape(-1, 2)
    res = geometry.resolution
    xs = geometry.origin_x + (cells[:, 0] + 0.5) * res
    ys = geometry.origin_y + (cells[:, 1] + 0.5) * res
    away = np.hypot(xs - pts[0, 0], ys - pts[0, 1]) > radius
    values = truth_costs[cells[:, 1], cells[:, 0]]

    def centres(cost) -> tuple[Point, ...]:
        keep = away & (values == cost)
        return tuple(zip(xs[keep].tolist(), ys[keep].tolist(), strict=True))

    lethal, inscribed = centres(LETHAL), centres(INSCRIBED)
    return PlanSafety(lethal, inscribed)


@njit(cache=True, nogil=True)
def leg_cells(c0, r0, c1, r1):
    """(n, 2) int64 (col, row) of every cell the segment between the centres of cells
    (c0, r0) and (c1, r1) passes through, in order (``line_start``)."""
    out = np.empty((2 * (abs(c1 - c0) + abs(r1 - r0)) + 1, 2), dtype=np.int64)
    out[0] = (c0, r0)
    n = 1
    state = line_start(c0, r0, c1, r1)
    while line_more(state):
        c, r, _, _, _, _, sc, sr = state
        state, corner = line_step(state)
        if corner:
            out[n] = (c + sc, r)
            out[n + 1] = (c, r + sr)
            n += 2
        out[n] = (state[0], state[1])
        n += 1
    return out[:n]
