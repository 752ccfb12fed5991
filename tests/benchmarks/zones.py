"""Zones benchmark: a site split among map servers, one per zone with overlapping borders.

Run: ``python -m tests.benchmarks.zones [--width 400] [--height 200] [--units 1000]
[--range 20] [--zones 1 2 4 8] [--scan-ms 0.9] [--seed 0] [--json]``

The design of docs/scaling.md, as ``mapserver.client.zones.ZoneLayout`` lays it out
(``map_server.zones`` of a scenario runs it): the site is cut into vertical strips, one
map server each; a strip's server maps its strip plus a border of the LiDAR's reach
(``--range``) and the inflation radius on each side, and a unit posts to every zone whose
strip (plus the inflation radius) its LiDAR reaches (the ``Scan`` is sent to each; each
server fuses what falls in its grid). Reads stitch the strips.

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

from mapserver.client.zones import ZoneLayout
from mapserver.core.geometry import GridGeometry

RATE_HZ = 10.0
RESOLUTION = 0.05  # [m/cell]
INFLATION_M = 0.55  # [m] the default inflation radius: the margin of each strip


def zone_loads(layout: ZoneLayout, xs: np.ndarray) -> np.ndarray:
    """Units that post to each zone of ``layout``, for units at ``xs`` [m]."""
    return layout.posts_to_many(xs).sum(axis=0)


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
    site = GridGeometry(round(args.width / RESOLUTION), round(args.height / RESOLUTION), RESOLUTION)
    for zones in args.zones:
        layout = ZoneLayout.strips(site, zones, args.range, INFLATION_M)
        loads = zone_loads(layout, xs)
        cells = max(layout.geometry(k).size for k in range(zones))
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
