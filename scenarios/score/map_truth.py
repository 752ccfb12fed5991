"""Map against truth (docs/files.md): how far the shared costmap is from the ground truth.

At every map read the fleet does, the shared costmap (what the units read) is compared
cell by cell with the ground-truth costmap (``fleet.ground_truth.GroundTruth``: the
world's true geometry rasterised and inflated as the server inflates):

- ``phantom_cells`` [cells]: INSCRIBED or LETHAL in the shared costmap, free in truth.
  "Free in truth": no truth cell INSCRIBED or LETHAL within ``TOLERANCE_CELLS`` (1) of
  it, the cell itself included (so truth costs 0..252 all around it).
- ``forgotten_cells`` [cells]: LETHAL in truth, below INSCRIBED in the shared costmap
  (FREE or graded; UNKNOWN 255 is not forgotten, it was never claimed free), with no
  shared LETHAL cell within ``TOLERANCE_CELLS`` of it.

  The tolerance is the rasterisation's: the truth marks a cell occupied only when its
  centre lies in the obstacle, while a LiDAR endpoint on a face lands in the cell the
  face cuts, so a map that sees perfectly may hold an obstacle's edge one cell outside
  (or inside) the truth's, and its inscribed band one cell further out. Cell for cell
  (``tolerance_cells=0``) that ring along every face would count: on ``static_shift``
  (nothing moves but the units; decay, seed 0) 1,928 phantom cells at the end, each a
  shared INSCRIBED cell one beyond the truth's inscribed band; 0 with the tolerance.
- ``unknown_share`` [1]: of the reachable floor, the share the shared costmap calls
  UNKNOWN. The reachable floor: the truth cells below INSCRIBED connected (8-connected,
  as the grid planner moves) to a unit's start cell, ``reachable_floor``; a start cell
  that is itself INSCRIBED or LETHAL in truth seeds nothing. 0.0 when nothing is
  reachable.

Moving things: people are world obstacles, so the truth rasterises them where they are
at the read and they count like any obstacle (a person the map has not caught up with
leaves forgotten cells, a person who walked away leaves phantom ones). The units are not
in the truth, and the map never sees them (``scenarios.run.fleet_filter`` drops the returns
off fleet members, and a unit cannot see the floor under itself), so the cells under
every unit's footprint at the read (centre inside the unit's radius,
``fleet.ground_truth.rasterise``'s rule) are left out of all three numbers.

``summary`` gives ``metrics.json``'s ``map_truth``: per number the mean over the reads
(each read weighs the same; reads are every ``map_read_s``, so this is the time average
sampled on the read clock) and the final value (the last read).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from fleet.ground_truth import rasterise
from fleet.shapes import Cylinder
from mapserver.core.costvalues import INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from scenarios.run.record import MapTruthSample
from scenarios.score.metric_registry import REGISTRY

KEYS = REGISTRY.parts("map_truth")
"""The three numbers, in ``metrics.json``'s order (the metric registry's)."""
MEAN_DECIMALS = 3
SHARE_DECIMALS = 6

TOLERANCE_CELLS = 1
"""[cells] how far the map's obstacle edge may lie from the truth's and still agree."""
_EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)


def measure(
    stamp: float,
    shared: np.ndarray,
    truth: np.ndarray,
    reachable: np.ndarray,
    ignore: np.ndarray | None = None,
    tolerance_cells: int = TOLERANCE_CELLS,
) -> MapTruthSample:
    """The three numbers (module docstring) at sim time ``stamp`` [s] for the shared and
    the truth costmaps (uint8 Nav2 costs, same shape), the reachable floor (bool, same
    shape) and the cells to leave out (bool, same shape; None: none), with the
    rasterisation tolerance ``tolerance_cells`` [cells] (0: cell for cell)."""
    if not (shared.shape == truth.shape == reachable.shape):
        raise ValueError(f"shapes differ: {shared.shape}, {truth.shape}, {reachable.shape}")
    keep = np.ones(shared.shape, dtype=bool) if ignore is None else ~ignore
    truth_blocks = _near(truth >= INSCRIBED, tolerance_cells)  # the truth has no UNKNOWN
    map_lethal = _near(shared == LETHAL, tolerance_cells)
    phantom = (shared >= INSCRIBED) & (shared != UNKNOWN) & ~truth_blocks
    forgotten = (truth == LETHAL) & (shared < INSCRIBED) & ~map_lethal
    floor = reachable & keep
    floor_cells = int(np.count_nonzero(floor))
    unknown = int(np.count_nonzero(floor & (shared == UNKNOWN)))
    return MapTruthSample(
        stamp,
        int(np.count_nonzero(phantom & keep)),
        int(np.count_nonzero(forgotten & keep)),
        unknown / floor_cells if floor_cells else 0.0,
    )


def _near(mask: np.ndarray, cells: int) -> np.ndarray:
    """``mask`` grown by ``cells`` in every direction (a square: 8-neighbourhood), cells
    beyond the grid's edge counted empty: ``ndimage.binary_dilation`` with a square
    structure, done as two 1-D passes of shifted ORs (a square is separable): 27 times
    faster on ``hundred_units``' 2,000 x 800 grid (``tests/benchmarks/map_truth.py``)."""
    if cells <= 0:
        return mask
    rows = mask.copy()
    for k in range(1, cells + 1):
        rows[k:] |= mask[:-k]
        rows[:-k] |= mask[k:]
    out = rows.copy()
    for k in range(1, cells + 1):
        out[:, k:] |= rows[:, :-k]
        out[:, :-k] |= rows[:, k:]
    return out


def reachable_floor(truth: np.ndarray, starts: Iterable[tuple[int, int]]) -> np.ndarray:
    """Bool mask of the truth cells below INSCRIBED 8-connected to a start cell
    ``(col, row)``; starts off the grid or on a truth cell not below INSCRIBED seed
    nothing."""
    passable = truth < INSCRIBED
    labels, _ = ndimage.label(passable, structure=_EIGHT_CONNECTED)
    height, width = truth.shape
    seeds = {
        int(labels[row, col])
        for col, row in starts
        if 0 <= col < width and 0 <= row < height and labels[row, col] > 0
    }
    return np.isin(labels, sorted(seeds)) if seeds else np.zeros(truth.shape, dtype=bool)


@dataclass(frozen=True)
class _Body:
    """A unit's footprint as ``rasterise`` reads an obstacle (it reads only ``shape``)."""

    shape: Cylinder


def footprints(geometry: GridGeometry, units: Iterable[tuple[float, float, float]]) -> np.ndarray:
    """Bool mask of the cells whose centres lie inside a unit's footprint, each unit
    ``(x, y, radius)`` [m] (``fleet.ground_truth.rasterise``'s rule)."""
    return rasterise([_Body(Cylinder(x, y, r)) for x, y, r in units], geometry)


def summary(samples: Sequence[MapTruthSample]) -> dict[str, dict[str, float | int | None]]:
    """``metrics.json``'s ``map_truth``: per key ``{mean, final}`` (module docstring);
    counts' finals are integers, means rounded to 1e-3, shares to 1e-6; all None when
    there was no read."""
    out: dict[str, dict[str, float | int | None]] = {}
    for key in KEYS:
        values = [getattr(s, key) for s in samples]
        if not values:
            out[key] = {"mean": None, "final": None}
            continue
        decimals = SHARE_DECIMALS if key == "unknown_share" else MEAN_DECIMALS
        final = values[-1]
        out[key] = {
            "mean": round(float(np.mean(values)), decimals),
            "final": round(float(final), SHARE_DECIMALS) if key == "unknown_share" else final,
        }
    return out
