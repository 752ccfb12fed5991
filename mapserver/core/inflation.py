"""Nav2-style inflation: cost falls off exponentially with distance to the nearest obstacle.

Cost of a cell at Euclidean distance ``d`` [m] (cell centre to cell centre) from the
nearest lethal cell, as Nav2's ``InflationLayer::computeCost`` (navigation2,
``nav2_costmap_2d/include/nav2_costmap_2d/inflation_layer.hpp``)::

    d == 0                          -> LETHAL (254)
    0 < d <= inscribed_radius       -> INSCRIBED (253)
    inscribed_radius < d <= radius  -> (unsigned char)((INSCRIBED - 1)
                                                       * exp(-k * (d - inscribed_radius)))
                                       = floor(252 * exp(-k * (d - r_inscribed)))
    d > radius                      -> FREE (0)

with ``k = cost_scaling_factor`` [1/m] and ``radius = inflation_radius`` [m].

Two deliberate differences from Nav2, both making the cut-offs the metric ones the
formula states:

- Nav2 propagates to ``ceil(inflation_radius / resolution)`` cells
  (``Costmap2D::cellDistance``), so when the radius is not a whole number of cells it
  inflates cells up to one cell beyond it (0.52 m at 0.05 m reaches 11 cells = 0.55 m).
  Here a cell is inflated only when ``d <= inflation_radius`` (the defaults, 0.55 m at
  0.05 m = 11 cells, give the same cells either way).
- Nav2 compares ``distance * resolution <= inscribed_radius`` in raw floating point, so a
  cell exactly on the inscribed radius (6 cells x 0.05 m = 0.30000000000000004) gets 251.
  Here both radii are compared with a tolerance of ``DISTANCE_TOLERANCE`` (1 nm), so a
  cell on a radius counts as within it.

Distances are exact Euclidean distances in cells (Nav2's wave-front propagation only
approximates them), found by a squared Euclidean distance transform restricted to the
radius ``R`` (cells), in the two separable passes of Meijster, Roerdink and Hesselink,
"A general algorithm for computing distance transforms in linear time" (2000):

1. Columns: ``g[r, c]`` = distance to the nearest lethal cell in column ``c``, capped at
   ``R + 1`` (a down sweep and an up sweep).
2. Rows: ``d2[r, c] = min over c' of (c - c')**2 + g[r, c']**2``. Instead of the lower
   envelope of parabolas (Felzenszwalb and Huttenlocher, "Distance Transforms of Sampled
   Functions", 2012) each ``c'`` with ``g <= R`` sweeps outwards and stops at the first
   ``c''`` where ``(c'' - c')**2 + g[c']**2 >= g[c'']**2``: the difference between the two
   parabolas only grows beyond ``c''``, so ``c''`` beats ``c'`` everywhere further out.
   The nearest minimiser of any cell is never stopped before reaching it, so the result
   is exact, and near straight walls each sweep stops after a step or two.

Costs then come from a table indexed by the squared integer distance ``d2`` (exact: no
square roots at run time). Capping ``g`` at ``R + 1`` only changes distances beyond the
radius, where the cost is FREE anyway. A window refresh reads the window grown by ``R``
cells, so it equals the full computation inside the window.

Unknown cells (the ``apply`` step on a master grid), as Nav2's ``updateCosts``: lethal
cells are the only sources. A cell that is UNKNOWN in the master stays UNKNOWN unless its
inflation cost is at least INSCRIBED (``inflate_unknown = False``, the default) or above
FREE (``inflate_unknown = True``); then it takes the inflation cost. Every other cell
takes ``max(master, inflation)``. So inflation never creates an UNKNOWN cell, and on known
cells the cost never increases with the distance to the nearest lethal cell. (Nav2's
``inflate_around_unknown``, which also inflates around UNKNOWN cells, is not offered.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from mapserver.core.belief import EMPTY_BOX, CellBox
from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.errors import FieldError

DISTANCE_TOLERANCE = 1e-9  # [m] slack when comparing a distance with a radius
MAX_RADIUS_CELLS = 1000  # [cells] bounds the cost table (about R**2 entries) and int16 passes


@dataclass(frozen=True)
class InflationParams:
    """Parameters of the inflation, named as Nav2's InflationLayer parameters.

    inflation_radius: [m] cells farther than this from every obstacle are not inflated
        (Nav2 default 0.55).
    cost_scaling_factor: [1/m] exponential decay rate ``k`` of the cost beyond the
        inscribed radius (Nav2 default 10.0).
    inscribed_radius: [m] radius of the largest circle inside the unit's footprint; a unit
        centred closer than this to an obstacle touches it. Nav2 derives it from the
        footprint; here the default 0.3 m is the drive units' footprint radius.
    inflate_unknown: when True an UNKNOWN cell near an obstacle takes any inflated cost;
        when False (Nav2 default) only INSCRIBED cost overrides UNKNOWN.
    """

    inflation_radius: float = 0.55
    cost_scaling_factor: float = 10.0
    inscribed_radius: float = 0.3
    inflate_unknown: bool = False

    def __post_init__(self) -> None:
        for name in ("inflation_radius", "cost_scaling_factor", "inscribed_radius"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise FieldError(name, value, "must be a number")
            if not math.isfinite(value):
                raise FieldError(name, value, "must be finite")
        if self.inscribed_radius < 0:
            raise FieldError("inscribed_radius", self.inscribed_radius, "must be >= 0 m")
        if self.inflation_radius < self.inscribed_radius:
            raise FieldError(
                "inflation_radius",
                self.inflation_radius,
                f"must be >= inscribed_radius ({self.inscribed_radius!r} m)",
            )
        if not self.cost_scaling_factor > 0:
            raise FieldError(
                "cost_scaling_factor", self.cost_scaling_factor, "must be > 0 per metre"
            )
        if not isinstance(self.inflate_unknown, bool | np.bool_):
            raise FieldError("inflate_unknown", self.inflate_unknown, "must be a boolean")


def inflation_cost(distance: float, params: InflationParams) -> int:
    """Cost (0..254) of a cell ``distance`` [m] from the nearest lethal cell (module doc)."""
    if distance < 0 or not math.isfinite(distance):
        raise FieldError("distance", distance, "must be a finite number of metres >= 0")
    if distance == 0:
        return int(LETHAL)
    if distance <= params.inscribed_radius + DISTANCE_TOLERANCE:
        return int(INSCRIBED)
    if distance > params.inflation_radius + DISTANCE_TOLERANCE:
        return int(FREE)
    factor = math.exp(-params.cost_scaling_factor * (distance - params.inscribed_radius))
    return int((int(INSCRIBED) - 1) * factor)  # truncation, as Nav2's unsigned char cast


def merge_inflation(
    master: np.ndarray, inflation: np.ndarray, inflate_unknown: bool = False
) -> np.ndarray:
    """Combine master costs with inflation costs as Nav2's ``updateCosts`` (module doc).

    master, inflation: uint8 arrays of one shape. Returns a new uint8 array.
    """
    if master.shape != inflation.shape:
        raise ValueError(
            f"inflation shape {inflation.shape} must equal master shape {master.shape}"
        )
    merged = np.maximum(master, inflation)
    lowest_override = 1 if inflate_unknown else int(INSCRIBED)
    take = (master == UNKNOWN) & (inflation >= lowest_override)
    merged[take] = inflation[take]
    return merged


class Inflator:
    """Inflation for one ``InflationParams`` at one resolution, its cost table precomputed.

    params: the inflation parameters.
    resolution: [m/cell] of the grids it inflates.

    Attributes:
    cost_by_sq_distance: uint8 table, index ``s = dx*dx + dy*dy`` [cells^2] -> cost, for
        every ``s`` with ``sqrt(s) * resolution <= inflation_radius``; longer distances cost 0.
    radius_cells: [cells] ``R = isqrt(len(cost_by_sq_distance) - 1)``, the largest integer
        offset along one axis that can still be inflated.
    """

    def __init__(self, params: InflationParams, resolution: float) -> None:
        if isinstance(resolution, bool) or not (
            isinstance(resolution, int | float) and math.isfinite(resolution) and resolution > 0
        ):
            raise FieldError("resolution", resolution, "must be a positive number of metres")
        self.params = params
        self.resolution = float(resolution)
        max_sq = _max_sq_distance(params.inflation_radius, self.resolution)
        r = math.isqrt(max_sq)
        if r > MAX_RADIUS_CELLS:
            raise ValueError(
                f"inflation_radius {params.inflation_radius!r} m at resolution {resolution!r} m "
                f"spans {r} cells, more than {MAX_RADIUS_CELLS}"
            )
        self.radius_cells = r
        table = [inflation_cost(math.sqrt(s) * self.resolution, params) for s in range(max_sq + 1)]
        self.cost_by_sq_distance = np.array(table, dtype=np.uint8)
        self.cost_by_sq_distance.setflags(write=False)

    def affected_box(self, changed: CellBox, shape: tuple[int, int]) -> CellBox:
        """Cells whose inflation may change when lethal cells change inside ``changed``.

        ``changed`` grown by ``radius_cells`` and clipped to a (height, width) ``shape``.
        """
        if changed.empty:
            return EMPTY_BOX
        r = self.radius_cells
        return CellBox(changed.col0 - r, changed.row0 - r, changed.col1 + r, changed.row1 + r).clip(
            shape
        )

    def inflate(self, lethal: np.ndarray) -> np.ndarray:
        """Inflation costs (uint8, same shape) for a boolean (H, W) mask of lethal cells."""
        lethal = _as_lethal_mask(lethal)
        out = np.empty(lethal.shape, dtype=np.uint8)
        _inflate_kernel(lethal, out, 0, 0, self.radius_cells, self.cost_by_sq_distance)
        return out

    def inflate_window(self, lethal: np.ndarray, out_costs: np.ndarray, box: CellBox) -> None:
        """Recompute ``out_costs[box]`` exactly as ``inflate(lethal)[box]``; nothing else.

        lethal: boolean (H, W) mask of lethal cells, the whole grid.
        out_costs: uint8 (H, W) inflation costs, written only inside ``box``.
        box: the cells to refresh (inclusive; clipped to the grid).
        Only lethal cells within ``radius_cells`` of ``box`` are read.
        """
        lethal = _as_lethal_mask(lethal)
        if out_costs.shape != lethal.shape or out_costs.dtype != np.uint8:
            raise ValueError(
                f"out_costs must be uint8 of shape {lethal.shape}, "
                f"got {out_costs.dtype} {out_costs.shape}"
            )
        target = box.clip(lethal.shape)
        if not target.empty:
            out_costs[target.slices] = self._inflate_box(lethal, target)

    def apply(self, master: np.ndarray, box: CellBox | None = None) -> None:
        """Inflate a master costmap in place inside ``box`` (default: the whole grid).

        master: uint8 (H, W) costs from the layers below (FREE/LETHAL/UNKNOWN, graded
        allowed). Its LETHAL cells within ``radius_cells`` of ``box`` are the sources; cells
        in ``box`` become ``merge_inflation(master, inflation, inflate_unknown)``. Applying
        it again with the same sources changes nothing.
        """
        if master.ndim != 2 or master.dtype != np.uint8:
            raise ValueError(f"master must be a 2-D uint8 array, got {master.dtype} {master.shape}")
        full = CellBox(0, 0, master.shape[1] - 1, master.shape[0] - 1)
        target = (box or full).clip(master.shape)
        if target.empty:
            return
        window = self.affected_box(target, master.shape)
        inflation = self._inflate_box(master[window.slices] == LETHAL, target, window)
        master[target.slices] = merge_inflation(
            master[target.slices], inflation, self.params.inflate_unknown
        )

    def _inflate_box(
        self, lethal: np.ndarray, target: CellBox, window: CellBox | None = None
    ) -> np.ndarray:
        """Inflation costs for ``target`` (a new array) from lethal cells near it.

        ``lethal`` is the whole grid, or (when ``window`` is given) already the
        ``affected_box(target)`` window of it.
        """
        if window is None:
            window = self.affected_box(target, lethal.shape)
            lethal = lethal[window.slices]
        out = np.empty((target.height, target.width), dtype=np.uint8)
        _inflate_kernel(
            np.ascontiguousarray(lethal),
            out,
            target.row0 - window.row0,
            target.col0 - window.col0,
            self.radius_cells,
            self.cost_by_sq_distance,
        )
        return out


def _max_sq_distance(radius: float, resolution: float) -> int:
    """Largest squared cell distance ``s`` with ``sqrt(s) * resolution <= radius`` (+ tolerance)."""
    limit = radius + DISTANCE_TOLERANCE
    s = math.floor((limit / resolution) ** 2)
    while math.sqrt(s + 1) * resolution <= limit:
        s += 1
    while s > 0 and math.sqrt(s) * resolution > limit:
        s -= 1
    return s


def _as_lethal_mask(lethal: np.ndarray) -> np.ndarray:
    """Check and return a C-contiguous boolean 2-D mask."""
    arr = np.asarray(lethal)
    if arr.ndim != 2 or arr.dtype != np.bool_:
        raise ValueError(f"lethal must be a 2-D boolean array, got {arr.dtype} {arr.shape}")
    return np.ascontiguousarray(arr)


@njit(cache=True, nogil=True)
def _inflate_kernel(lethal, out, row_off, col_off, radius, cost_by_sq_distance):
    """Fill ``out`` with inflation costs from the lethal cells of the window ``lethal``.

    lethal: (h, w) bool window. out: (bh, bw) uint8 target box, whose cell (0, 0) is
    window cell (row_off, col_off); the window extends ``radius`` [cells] beyond the box
    where the grid allows. The two passes are described in the module docstring.
    """
    h, w = lethal.shape
    bh, bw = out.shape
    far = radius + 1
    r2max = cost_by_sq_distance.shape[0] - 1
    # pass 1: vertical distance to the nearest lethal cell in the column, capped at `far`
    g = np.empty((h, w), dtype=np.int16)
    for c in range(w):
        g[0, c] = 0 if lethal[0, c] else far
    for row in range(1, h):
        for c in range(w):
            g[row, c] = 0 if lethal[row, c] else min(g[row - 1, c] + 1, far)
    for row in range(h - 2, -1, -1):
        for c in range(w):
            g[row, c] = min(g[row, c], g[row + 1, c] + 1)
    # pass 2: per target row, squared distance by pruned sweeps, then the cost table
    d2 = np.empty(bw, dtype=np.int32)
    for br in range(bh):
        grow = g[br + row_off]
        for bc in range(bw):
            own = np.int32(grow[bc + col_off])
            d2[bc] = own * own
        for src in range(w):
            gs = np.int32(grow[src])
            if gs > radius:
                continue
            gs2 = gs * gs
            for step in (1, -1):
                c = src + step
                dx = 1
                while dx <= radius and 0 <= c < w:
                    v = dx * dx + gs2
                    gc = np.int32(grow[c])
                    if v >= gc * gc:
                        break
                    bc = c - col_off
                    if 0 <= bc < bw and v < d2[bc]:
                        d2[bc] = v
                    c += step
                    dx += 1
        orow = out[br]
        for bc in range(bw):
            v = d2[bc]
            orow[bc] = cost_by_sq_distance[v] if v <= r2max else 0
