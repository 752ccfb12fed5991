"""What makes a blocking cell block: the LETHAL cells that inflate it to INSCRIBED.

A lane or a path is blocked where its line crosses a cell of cost INSCRIBED (253) or
LETHAL (254) (``mapserver.core.queries``). A LETHAL cell holds occupancy evidence of its
own; an INSCRIBED one is free or unknown in the map and blocks only because a LETHAL
cell lies within the inscribed radius of it (Nav2's inflation,
``mapserver.core.inflation``: ``0 < d <= inscribed_radius`` gives INSCRIBED). A freeze's
explanation names those LETHAL cells, since their evidence (what marked them, when) is
what held the unit; the blocking cell's own says only that it is free.
"""

from __future__ import annotations

import math

import numpy as np

from mapserver.core.costvalues import INSCRIBED, LETHAL
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import DISTANCE_TOLERANCE

Point = tuple[float, float]

MAX_SOURCES = 3
"""The nearest LETHAL cells named per INSCRIBED cell (one is what inscribes it; a few
show whether it is one stray cell or a face)."""


def inscribing_cells(
    costs: np.ndarray,
    geometry: GridGeometry,
    point: Point,
    inscribed_radius: float,
    limit: int = MAX_SOURCES,
) -> tuple[Point, ...]:
    """Centres [m] of the LETHAL cells within ``inscribed_radius`` [m] of the cell at
    ``point`` [m] in ``costs`` (uint8 Nav2 costs, (height, width) of ``geometry``),
    nearest first (ties in row-major order), at most ``limit``. Empty when that cell is
    off the map or its cost is not INSCRIBED (a LETHAL cell blocks by itself)."""
    col, row = geometry.world_to_cell(*point)
    if not geometry.contains_cell(col, row) or costs[row, col] != INSCRIBED:
        return ()
    reach = int(math.ceil(inscribed_radius / geometry.resolution))
    r0, r1 = max(0, row - reach), min(geometry.height, row + reach + 1)
    c0, c1 = max(0, col - reach), min(geometry.width, col + reach + 1)
    rows, cols = np.nonzero(costs[r0:r1, c0:c1] == LETHAL)
    if rows.size == 0:
        return ()
    distance = np.hypot(rows + r0 - row, cols + c0 - col) * geometry.resolution
    near = distance <= inscribed_radius + DISTANCE_TOLERANCE  # as the inflation compares
    order = np.argsort(distance[near], kind="stable")[:limit]
    return tuple(
        geometry.cell_to_world(int(c), int(r))
        for r, c in zip(rows[near][order] + r0, cols[near][order] + c0, strict=True)
    )
