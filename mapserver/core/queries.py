"""Point and segment queries on the belief grid and the costmap (docs/http-api.md 2.4 and 2.5).

- Cells: for each world point, its state (free / occupied / unknown, or outside the map),
  occupancy probability (None when unknown, as docs/http-api.md 2.4 says, including an observed
  cell whose probability lies between the thresholds), cost, last-observed stamp and age.
- Segments: for each segment, the highest known cost of the cells it crosses, whether a
  cell on it is lethal or inscribed (``blocked``), the share of its cells that are unknown
  (cells off the map count as unknown) and the first blocked cell's centre from its start.
  Cells are those of the one traversal the fusion kernel uses for beams
  (``mapserver.core.traversal``): the segment clipped to the map, then the Bresenham line
  between its ends' cells.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from mapserver.core.belief import BeliefGrid, CellSample, CellState
from mapserver.core.costvalues import INSCRIBED, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.traversal import clipped_cells, line_next, line_start

STATE_NAMES = {CellState.FREE: "free", CellState.OCCUPIED: "occupied", CellState.UNKNOWN: "unknown"}


@dataclass(frozen=True)
class CellReport:
    """One queried point: x, y [m]; state; p_occ; cost (0..255); last_observed, age [s]."""

    x: float
    y: float
    state: str
    p_occ: float | None
    cost: int | None
    last_observed: float | None
    age: float | None


@dataclass(frozen=True)
class SegmentReport:
    """One queried segment (see the module docstring)."""

    max_cost: int | None
    blocked: bool
    unknown_fraction: float
    first_blocked: tuple[float, float] | None


@dataclass(frozen=True)
class CellSamples:
    """What cell reports need, gathered from the grids in one short step: the points
    (N, 2) [m], which are on the map, and for those (in order) the belief's sample and
    the costs."""

    points: np.ndarray
    inside: np.ndarray
    sample: CellSample
    costs: np.ndarray


def sample_cells(
    belief: BeliefGrid, costs: np.ndarray, points: Sequence[Sequence[float]], at: float
) -> CellSamples:
    """Gather ``points`` [(x, y) m] at stamp ``at`` [s] from ``belief`` and ``costs``
    (H, W) uint8: O(points) array reads, so a caller may hold a lock around it only."""
    geometry = belief.geometry
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    cols, rows, inside = geometry.points_to_cells(pts)
    flat = rows[inside] * geometry.width + cols[inside]
    return CellSamples(pts, inside, belief.sample(flat, at), costs.ravel()[flat])


CELL_FIELDS = ("x", "y", "state", "p_occ", "cost", "last_observed", "age")
_STATE_BY_CODE = np.array(
    [STATE_NAMES[CellState(code)] for code in range(3)] + ["outside"], dtype=object
)
_OUTSIDE = 3


def cell_columns(samples: CellSamples, at: float) -> dict[str, list]:
    """The reports of ``samples`` gathered at stamp ``at`` [s] as columns named
    ``CELL_FIELDS``, one value per point (None where the report has none), built with
    array operations: 100,000 points take milliseconds, not the better part of a second."""
    n, inside, sample = len(samples.points), samples.inside, samples.sample
    codes = np.full(n, _OUTSIDE, dtype=np.int64)
    codes[inside] = sample.states
    known = codes[inside] != CellState.UNKNOWN
    seen = ~np.isnan(sample.last_observed)
    return {
        "x": samples.points[:, 0].tolist(),
        "y": samples.points[:, 1].tolist(),
        "state": _STATE_BY_CODE[codes].tolist(),
        "p_occ": _scatter(n, inside, sample.p_occ.astype(np.float64), known),
        "cost": _scatter(n, inside, samples.costs.astype(np.int64), None),
        "last_observed": _scatter(n, inside, sample.last_observed, seen),
        "age": _scatter(n, inside, at - sample.last_observed, seen),
    }


def _scatter(n: int, inside: np.ndarray, values: np.ndarray, valid: np.ndarray | None) -> list:
    """A list of ``n`` with ``values`` at the ``inside`` points (where ``valid``) and
    None elsewhere."""
    out = np.full(n, None, dtype=object)
    picked = np.flatnonzero(inside)
    if valid is not None:
        picked, values = picked[valid], values[valid]
    out[picked] = values.tolist()
    return out.tolist()


def cell_reports(samples: CellSamples, at: float) -> list[CellReport]:
    """One report per point of ``samples`` gathered at stamp ``at`` [s]."""
    columns = cell_columns(samples, at)
    return [CellReport(*row) for row in zip(*(columns[f] for f in CELL_FIELDS), strict=True)]


def query_cells(
    belief: BeliefGrid, costs: np.ndarray, points: Sequence[Sequence[float]], at: float
) -> list[CellReport]:
    """Reports for ``points`` [(x, y) m] at stamp ``at`` [s] against ``costs`` (H, W) uint8."""
    return cell_reports(sample_cells(belief, costs, points, at), at)


def query_segments(
    geometry: GridGeometry, costs: np.ndarray, segments: Sequence[Sequence[float]]
) -> list[SegmentReport]:
    """Reports for ``segments`` [(x0, y0, x1, y1) m] against ``costs`` (H, W) uint8 on a
    grid of ``geometry`` (the server's costmap or a planner's local copy)."""
    g = geometry
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    with np.errstate(over="ignore", invalid="ignore"):  # a span past 1e308 m is infinite
        span = np.maximum(np.abs(seg[:, 2] - seg[:, 0]), np.abs(seg[:, 3] - seg[:, 1]))
        span /= g.resolution
        total = np.where(np.isfinite(span), np.floor(span) + 1.0, math.inf)  # on or off the map
    grid = (g.width, g.height, g.origin_x, g.origin_y, g.resolution)
    flat = np.ascontiguousarray(costs).reshape(-1)
    # Python scalars from here: a lane graph's refresh reads hundreds of segments, and
    # indexing numpy arrays element by element cost more than the kernel
    per_segment = zip(
        *(column.tolist() for column in _segments_kernel(flat, grid, seg)),
        total.tolist(),
        strict=True,
    )
    reports = []
    for on_map, max_cost, unknown, count, first, cells in per_segment:
        inside_cells = count if on_map else 0
        off_map = max(cells - inside_cells, 0.0)
        blocked = on_map and first >= 0
        known_max = max_cost if on_map else -1
        unknown_cells = (unknown if on_map else 0) + off_map
        row, col = divmod(first, g.width)
        reports.append(
            SegmentReport(
                max_cost=None if known_max < 0 else int(known_max),
                blocked=bool(blocked),
                unknown_fraction=_fraction(unknown_cells, max(cells, inside_cells)),
                first_blocked=g.cell_to_world(col, row) if blocked else None,
            )
        )
    return reports


def _fraction(part: float, whole: float) -> float:
    """part / whole in [0, 1]; a segment too long to count cells is all unknown."""
    return 1.0 if not math.isfinite(whole) else min(1.0, float(part) / float(whole))


@njit(cache=True, nogil=True)
def _segments_kernel(costs, grid, segments):
    """Per segment [m], over the cells of its part on the map (``traversal``): on the map
    at all, max known cost (-1 none), unknown count, cell count and the flat index of the
    first blocked cell (-1 none). ``costs`` is the flat row-major costmap; ``grid`` is
    (width, height [cells], origin_x, origin_y [m], resolution [m/cell])."""
    width, height, origin_x, origin_y, resolution = grid
    n = segments.shape[0]
    on_map = np.zeros(n, dtype=np.bool_)
    max_cost = np.full(n, -1, dtype=np.int64)
    unknown = np.zeros(n, dtype=np.int64)
    total = np.zeros(n, dtype=np.int64)
    first = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        x0, y0, x1, y1 = segments[i, 0], segments[i, 1], segments[i, 2], segments[i, 3]
        ok, _, _, c0, r0, c1, r1 = clipped_cells(
            x0, y0, x1, y1, origin_x, origin_y, resolution, width, height
        )
        if not ok:
            continue
        on_map[i] = True
        idx, cells, major, minor, a, b, err = line_start(c0, r0, c1, r1, width)
        total[i] = cells
        for _ in range(cells):
            v = costs[idx]
            if v == UNKNOWN:
                unknown[i] += 1
            else:
                if v > max_cost[i]:
                    max_cost[i] = v
                if v >= INSCRIBED and first[i] < 0:
                    first[i] = idx
            idx, err = line_next(idx, err, major, minor, a, b)
    return on_map, max_cost, unknown, total, first
