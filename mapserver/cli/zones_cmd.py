"""``fleetmap zones``: lay out a site's zones, one map server per strip (docs/scaling.md).

The site's grid and the number of zones in, ``ZoneLayout.strips`` out: a table of each
zone's core and grid, and with ``--out DIR``

- ``DIR/zone-<k>.yaml``: the ``grid`` settings of zone k's server, a ``fleetmap serve
  --config`` file (add the site's other settings to it, the same in every zone);
- ``DIR/zones.yaml``: the layout (``ZoneLayout.to_dict``), which a fleet reads back with
  ``ZoneLayout.from_dict`` to route its scans and reads with a ``ZonedMapClient``.

Bad values exit 2 with one line naming the option, and nothing is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

import yaml

from mapserver.cli.args import xy_pair
from mapserver.client.zones import MAX_ZONES, ZoneLayout
from mapserver.core.errors import FieldError
from mapserver.core.geometry import GridGeometry

FLAGS = {
    "width": "--width",
    "height": "--height",
    "resolution": "--resolution",
    "origin_x": "--origin",
    "origin_y": "--origin",
    "zones": "--zones",
    "range_m": "--range",
    "margin_m": "--inflation-radius",
}
"""The option behind each value a ``FieldError`` may name."""


def add_zones_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``zones``."""
    parser = subparsers.add_parser(
        "zones",
        help="lay out a site's zones: one map server per strip, with overlapping borders",
        description="Cut a site's grid into strips, one map server each, with borders for "
        "the LiDARs' reach and the costmap's inflation (docs/scaling.md); print them and, "
        "with --out, write each zone's grid settings and the layout for the fleet's client.",
    )
    parser.add_argument("--width", type=int, required=True, help="[cells] the site's grid")
    parser.add_argument("--height", type=int, required=True, help="[cells] the site's grid")
    parser.add_argument("--resolution", type=float, default=0.05, help="[m/cell]")
    parser.add_argument(
        "--origin", type=xy_pair, default=(0.0, 0.0), help="X,Y [m] of cell (0,0)'s corner"
    )
    parser.add_argument(
        "--zones", type=int, required=True, help=f"how many map servers, 1 to {MAX_ZONES}"
    )
    parser.add_argument("--range", type=float, default=20.0, help="[m] the LiDARs' range_max")
    parser.add_argument(
        "--inflation-radius", type=float, default=0.55, help="[m] the costmap's inflation"
    )
    parser.add_argument(
        "--out", type=Path, help="write zone-<k>.yaml and zones.yaml here (default: print only)"
    )
    parser.add_argument("--json", action="store_true", help="print the layout as JSON last")
    parser.set_defaults(handler=run_zones)


def run_zones(args: argparse.Namespace) -> int:
    """Lay out, print, write; 2 on a bad value (nothing written)."""
    try:
        site = GridGeometry(args.width, args.height, args.resolution, *args.origin)
        layout = ZoneLayout.strips(site, args.zones, args.range, args.inflation_radius)
    except FieldError as exc:
        flag = FLAGS.get(exc.field, exc.field)
        print(f"fleetmap zones: error: {flag}: {exc.detail} (see --help)",
              file=sys.stderr)  # fmt: skip
        return 2
    print(describe(layout))
    if args.out is not None:
        try:
            written = write_layout(layout, args.out)
        except OSError as exc:
            print(f"fleetmap zones: error: --out {args.out}: cannot write ({exc.strerror}; "
                  "choose another folder)", file=sys.stderr)  # fmt: skip
            return 2
        print(f"wrote {', '.join(str(p) for p in written)}")
    if args.json:
        print(json.dumps(layout.to_dict()))
    return 0


def describe(layout: ZoneLayout) -> str:
    """The layout as a few lines of text: the rule, then a row per zone."""
    site, res = layout.site, layout.site.resolution
    lines = [
        f"site: {site.describe()}; {layout.zones} zones",
        f"a scan goes to every zone whose core plus {layout.margin_cells * res:g} m lies "
        f"within {layout.reach_m:g} m of its sensor; each zone's grid reaches "
        f"{layout.border_cells} cells ({layout.border_cells * res:g} m) past its core",
        f"{'zone':>4}  {'core x [m]':>21}  {'grid x [m]':>21}  {'grid cells':>13}",
    ]
    for k in range(layout.zones):
        first, end = layout.core(k)
        g = layout.geometry(k)
        core = f"{site.origin_x + first * res:g} to {site.origin_x + end * res:g}"
        grid = f"{g.origin_x:g} to {g.origin_x + g.width * res:g}"
        lines.append(f"{k:4d}  {core:>21}  {grid:>21}  {f'{g.width} x {g.height}':>13}")
    return "\n".join(lines)


def write_layout(layout: ZoneLayout, out: Path) -> list[Path]:
    """``zone-<k>.yaml`` for each zone and ``zones.yaml`` in ``out`` (made if missing)."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for k in range(layout.zones):
        path = out / f"zone-{k}.yaml"
        path.write_text(yaml.safe_dump({"grid": asdict(layout.geometry(k))}, sort_keys=False))
        written.append(path)
    path = out / "zones.yaml"
    path.write_text(yaml.safe_dump(layout.to_dict(), sort_keys=False))
    return [*written, path]
