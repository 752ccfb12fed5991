"""Costmap refresh benchmark: incremental update after one scan vs a scipy full rebuild.

Run: ``python tests/benchmarks/costmap.py [--scans N] [--json]``

A 100 m x 100 m warehouse (``fleet.boxworld.warehouse_layout``) at 0.05 m: 2000 x 2000
cells. Units drive its aisles and post 1080-beam, 20 m scans. Each scan is fused into the
belief grid (``decay`` policy) and the layered costmap (obstacle + inflation, Nav2
defaults 0.55 m / k = 10 /m, 0.3 m inscribed) is refreshed with the scan's box.

Printed [ms]: the refresh per scan (``LayeredCostmap.update``: obstacle classification,
decay schedule, inflation and change detection in the scan's box), median and p95; the
full incremental build; and, in the same run, the plain full rebuild a naive server would
do after every scan: classify the whole belief grid at the stamp with numpy and inflate
it with ``scipy.ndimage.distance_transform_edt`` plus the cost table. ``--json`` prints
the figures as one JSON object on the last line. Measures only; tests assert behaviour.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy import ndimage

from fleet.boxworld import sample_scans, warehouse_layout
from mapserver.core.belief import BeliefGrid, CellState
from mapserver.core.costvalues import LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams, Inflator, merge_inflation
from mapserver.costmap.layered import LayeredCostmap
from mapserver.costmap.layers import InflationLayer, ObstacleLayer

RESOLUTION = 0.05  # [m/cell]
SIDE_M = 100.0  # [m]


def scipy_rebuild(belief: BeliefGrid, inflator: Inflator) -> np.ndarray:
    """The whole costmap from scratch: numpy classification + scipy EDT + cost table."""
    states = belief.states_at()
    master = np.full(states.shape, UNKNOWN, dtype=np.uint8)
    master[states == CellState.FREE] = 0
    master[states == CellState.OCCUPIED] = LETHAL
    d2 = ndimage.distance_transform_edt(master != LETHAL) ** 2
    table = inflator.cost_by_sq_distance
    idx = np.minimum(np.rint(d2).astype(np.int64), table.shape[0])
    inflation = np.where(idx < table.shape[0], table[np.minimum(idx, table.shape[0] - 1)], 0)
    return merge_inflation(master, inflation.astype(np.uint8))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=200, help="scans timed (default 200)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print figures as JSON last")
    args = parser.parse_args()

    warehouse = warehouse_layout(SIDE_M, SIDE_M, seed=args.seed)
    scans = sample_scans(warehouse, args.scans + 50, seed=args.seed)
    side = int(round(SIDE_M / RESOLUTION))
    geometry = GridGeometry(side, side, RESOLUTION)
    params = InflationParams()
    belief = BeliefGrid(geometry)
    t0 = time.perf_counter()
    costmap = LayeredCostmap(
        geometry, [ObstacleLayer(belief), InflationLayer(params, geometry)], history=256
    )
    full_ms = (time.perf_counter() - t0) * 1e3  # includes numba warm-up on a first run
    for scan in scans[:50]:  # warm-up: JIT and a populated map
        costmap.update(belief.stamp, [belief.fuse(scan).box])
    refresh = []
    for scan in scans[50:]:
        box = belief.fuse(scan).box
        t0 = time.perf_counter()
        costmap.update(belief.stamp, [box])
        refresh.append((time.perf_counter() - t0) * 1e3)
    t0 = time.perf_counter()
    rebuilt = costmap.build_costs(belief.stamp)
    full_incremental_ms = (time.perf_counter() - t0) * 1e3
    inflator = Inflator(params, RESOLUTION)
    rebuilds = []
    for _ in range(3):
        t0 = time.perf_counter()
        naive = scipy_rebuild(belief, inflator)
        rebuilds.append((time.perf_counter() - t0) * 1e3)
    figures = {
        "grid": f"{side}x{side}",
        "scans_timed": len(refresh),
        "refresh_ms_median": float(np.median(refresh)),
        "refresh_ms_p95": float(np.percentile(refresh, 95)),
        "full_build_ms": full_incremental_ms,
        "first_build_ms_with_jit": full_ms,
        "scipy_full_rebuild_ms": min(rebuilds),
        "speedup_vs_scipy_rebuild": min(rebuilds) / float(np.median(refresh)),
        "identical_to_scipy": bool(np.array_equal(rebuilt, naive))
        and bool(np.array_equal(costmap.costs, naive)),
    }
    print(f"costmap {side} x {side} at {RESOLUTION} m, radius {params.inflation_radius} m")
    print(f"  refresh after one 1080-beam scan: median {figures['refresh_ms_median']:.2f} ms, "
          f"p95 {figures['refresh_ms_p95']:.2f} ms over {len(refresh)} scans")  # fmt: skip
    print(f"  full build (fleetmap)            {full_incremental_ms:.1f} ms")
    print(f"  full rebuild (numpy + scipy EDT) {min(rebuilds):.1f} ms "
          f"({figures['speedup_vs_scipy_rebuild']:.0f}x the per-scan refresh)")  # fmt: skip
    print(f"  identical to the scipy rebuild: {figures['identical_to_scipy']}")
    if args.json:
        print(json.dumps(figures))


if __name__ == "__main__":
    main()
