"""Inflation benchmark: fleetmap's exact windowed inflation against a scipy full rebuild.

Run: ``python tests/benchmarks/inflation.py [--repeats N] [--window CELLS] [--seed S] [--json]``

The grid is a 100 m x 100 m warehouse at 0.05 m (2000 x 2000 cells): outer walls, rows
of 1.2 m x 9.6 m racks separated by 3 m aisles and 3.5 m cross-aisles, and a few
0.4 m totes dropped in the aisles (seeded). Inflation uses the Nav2 defaults
(``inflation_radius`` 0.55 m = 11 cells, ``cost_scaling_factor`` 10 /m) and a 0.3 m
inscribed radius, on one core, after a warm-up call has compiled (or loaded) the numba
kernel.

Printed, each the best of ``--repeats`` runs [ms]:
- full: ``Inflator.inflate`` over the whole grid;
- scipy: ``scipy.ndimage.distance_transform_edt`` of the whole grid plus the same
  cost-table lookup (the plain full rebuild), and how many times slower it is;
- window: ``Inflator.inflate_window`` over a ``--window`` square box (400 x 400 cells by
  default, about what one 1080-beam scan among racks touches) after a tote inside it
  moved, read from the box grown by the radius.
Both full results and the window refresh are checked to be identical to the scipy
result. ``--json`` prints the figures as one JSON object on the last line. Tests assert
behaviour; this script only measures.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import numpy as np
from scipy import ndimage

from mapserver.core.belief import CellBox
from mapserver.core.inflation import InflationParams, Inflator

RESOLUTION = 0.05  # [m/cell]
SIDE = 2000  # [cells] = 100 m
RACK_DEPTH, RACK_LENGTH = 24, 192  # [cells] = 1.2 m x 9.6 m
AISLE, CROSS_AISLE = 60, 70  # [cells] = 3.0 m, 3.5 m
WALL = 4  # [cells] = 0.2 m
TOTE = 8  # [cells] = 0.4 m


def warehouse(seed: int) -> np.ndarray:
    """(SIDE, SIDE) boolean mask of lethal cells: walls, rack rows, totes in aisles."""
    lethal = np.zeros((SIDE, SIDE), dtype=bool)
    lethal[:WALL, :] = lethal[-WALL:, :] = lethal[:, :WALL] = lethal[:, -WALL:] = True
    margin = 100  # [cells] free band inside the walls
    for col in range(margin, SIDE - margin - RACK_DEPTH, RACK_DEPTH + AISLE):
        for row in range(margin, SIDE - margin - RACK_LENGTH, RACK_LENGTH + CROSS_AISLE):
            lethal[row : row + RACK_LENGTH, col : col + RACK_DEPTH] = True
    rng = np.random.default_rng(seed)
    for _ in range(200):
        row, col = rng.integers(margin, SIDE - margin - TOTE, size=2)
        if not lethal[row - 2 : row + TOTE + 2, col - 2 : col + TOTE + 2].any():
            lethal[row : row + TOTE, col : col + TOTE] = True
    return lethal


def scipy_full(lethal: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Plain full rebuild: exact EDT of the whole grid, then the same cost table."""
    d2 = np.rint(ndimage.distance_transform_edt(~lethal) ** 2).astype(np.int64)
    padded = np.append(table, np.uint8(0))  # one FREE entry for every longer distance
    return padded[np.minimum(d2, len(table))]


def best_ms(run: Callable[[], object], repeats: int) -> float:
    """Best wall time of ``repeats`` calls [ms]."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return 1000.0 * min(times)


def main(argv: list[str] | None = None) -> dict[str, object]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10, help="runs per figure (best kept)")
    parser.add_argument("--window", type=int, default=400, help="window side [cells]")
    parser.add_argument("--seed", type=int, default=0, help="seed of the tote positions")
    parser.add_argument("--json", action="store_true", help="print a JSON object last")
    args = parser.parse_args(argv)

    inflator = Inflator(InflationParams(), RESOLUTION)
    lethal = warehouse(args.seed)
    table = inflator.cost_by_sq_distance
    costs = inflator.inflate(lethal)  # warm-up: compiles or loads the kernel

    full_ms = best_ms(lambda: inflator.inflate(lethal), args.repeats)
    scipy_ms = best_ms(lambda: scipy_full(lethal, table), max(1, args.repeats // 3))
    reference = scipy_full(lethal, table)
    identical = bool(np.array_equal(costs, reference))

    # one scan's worth of change: move a tote inside a window at the grid's centre
    lo = SIDE // 2 - args.window // 2
    box = CellBox(lo, lo, lo + args.window - 1, lo + args.window - 1)
    moved = lethal.copy()
    moved[lo + 100 : lo + 100 + TOTE, lo + 140 : lo + 140 + TOTE] ^= True
    window_ms = best_ms(lambda: inflator.inflate_window(moved, costs, box), args.repeats)
    identical &= bool(np.array_equal(costs, scipy_full(moved, table)))

    result: dict[str, object] = {
        "grid": [SIDE, SIDE],
        "resolution_m": RESOLUTION,
        "radius_cells": inflator.radius_cells,
        "lethal_fraction": round(float(lethal.mean()), 4),
        "full_ms": round(full_ms, 2),
        "scipy_full_ms": round(scipy_ms, 2),
        "scipy_over_full": round(scipy_ms / full_ms, 1),
        "window_cells": [args.window, args.window],
        "window_ms": round(window_ms, 3),
        "identical": identical,
    }
    print(
        f"inflation of {SIDE} x {SIDE} cells at {RESOLUTION} m, radius "
        f"{inflator.params.inflation_radius} m ({inflator.radius_cells} cells), "
        f"{100 * lethal.mean():.1f} % lethal"
    )
    print(f"  full (fleetmap)        {full_ms:8.2f} ms")
    print(f"  full (scipy EDT+table) {scipy_ms:8.2f} ms  ({scipy_ms / full_ms:.1f}x slower)")
    print(f"  window {args.window} x {args.window}     {window_ms:8.3f} ms")
    print(f"  identical to scipy: {identical}")
    if args.json:
        print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
