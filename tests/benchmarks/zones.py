"""Zones benchmark: a site split among map servers, one per zone with overlapping borders.

Run: ``python -m tests.benchmarks.zones [--width 400] [--height 200] [--units 1000]
[--range 20] [--zones 1 2 4 8] [--scan-ms 0.9] [--seed 0] [--json]``

The design of docs/scaling.md: the site is cut into vertical strips, one map server
each; a strip's server maps its strip plus a border of ``--range`` metres on each side
(a LiDAR's reach), so every cell a scan can observe lies inside the server of the strip
the unit stands in, and units within ``--range`` of a cut post to both servers (the
``Scan`` is sent twice; each server fuses what falls in its grid). A planner reads the
server of the strip it plans in; a path across a cut is planned to a lane crossing in the
shared border, then on in the next strip.

For ``--units`` units spread uniformly over the site (``--seed``), each scanning at 10 Hz,
printed per zone count: the scans/s the busiest server takes, the share of units that
post twice, the grid cells per server (0.05 m) and, at ``--scan-ms`` [ms] of one core per
scan (the ingest thread's cost measured by ``tests.benchmarks.fleet_load``'s profile), the
ingest cores the busiest server needs. Pure arithmetic on sampled positions (no servers
run): it measures what the partition costs in duplicated scans and grid, not HTTP.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

RATE_HZ = 10.0
RESOLUTION = 0.05  # [m/cell]


def zone_loads(xs: np.ndarray, width: float, zones: int, reach: float) -> np.ndarray:
    """Units that post to each zone: a unit at x posts to every strip whose extended
    range [x0 - reach, x1 + reach] holds x."""
    edges = np.linspace(0.0, width, zones + 1)
    return np.array(
        [
            np.count_nonzero((xs >= lo - reach) & (xs < hi + reach))
            for lo, hi in zip(edges[:-1], edges[1:], strict=True)
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--width", type=float, default=400.0, help="[m] site, along the cuts' normal"
    )
    parser.add_argument("--height", type=float, default=200.0, help="[m] site")
    parser.add_argument("--units", type=int, default=1000)
    parser.add_argument("--range", type=float, default=20.0, help="[m] LiDAR reach: the border")
    parser.add_argument("--zones", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--scan-ms", type=float, default=0.9, help="[ms] one core per scan")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    xs = rng.uniform(0.0, args.width, args.units)
    rows = []
    print(f"site {args.width:g} m x {args.height:g} m, {args.units} units at {RATE_HZ:g} Hz, "
          f"border {args.range:g} m, {args.scan_ms:g} ms of a core per scan")  # fmt: skip
    print(f"{'zones':>5} {'busiest scans/s':>15} {'extra scans':>13} "
          f"{'cells/server':>12} {'cores (busiest)':>15}")  # fmt: skip
    for zones in args.zones:
        loads = zone_loads(xs, args.width, zones, args.range)
        strip = args.width / zones + 2 * args.range * (zones > 1)
        cells = round(min(strip, args.width) / RESOLUTION) * round(args.height / RESOLUTION)
        row = {
            "zones": zones,
            "busiest_scans_per_s": float(loads.max() * RATE_HZ),
            "duplicated_share": float(loads.sum() / args.units - 1.0),
            "cells_per_server": cells,
            "cores_busiest": float(loads.max() * RATE_HZ * args.scan_ms / 1e3),
        }
        rows.append(row)
        print(f"{zones:5d} {row['busiest_scans_per_s']:15.0f} {row['duplicated_share']:13.1%} "
              f"{cells:12d} {row['cores_busiest']:15.2f}")  # fmt: skip
    if args.json:
        print(json.dumps(rows))


if __name__ == "__main__":
    main()
