"""``fleetmap plan MAP.yaml --start X,Y --goal X,Y``: plan on a saved map.

The map's occupied cells are inflated as the server's costmap would be (default
inflation parameters), then searched; ``--json`` prints the docs/http-api.md 2.6 plan response
(``map_version`` 0: a file has no versions).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

from mapserver.cli.args import xy_pair
from mapserver.core.inflation import InflationParams
from mapserver.costmap.layered import LayeredCostmap
from mapserver.costmap.layers import InflationLayer, StaticLayer
from mapserver.store.mapfiles import MapFileError, read_ros_map
from planner.grid_search import ALGORITHMS, GridPlanner, PlanRequestError


def add_plan_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "plan",
        help="plan on a saved map",
        description="Plan a path on a saved map (a ROS map YAML): its occupied cells are "
        "inflated as the server's costmap would be, then searched from --start to --goal.",
    )
    parser.add_argument("map", type=Path, help="ROS map YAML")
    parser.add_argument("--start", type=xy_pair, required=True, metavar="X,Y", help="[m]")
    parser.add_argument("--goal", type=xy_pair, required=True, metavar="X,Y", help="[m]")
    parser.add_argument("--algorithm", choices=ALGORITHMS, default="astar", help="search algorithm")
    parser.add_argument(
        "--no-unknown", action="store_true", help="never plan through unknown cells"
    )
    parser.add_argument("--json", action="store_true", help="print the plan response as JSON")
    parser.set_defaults(handler=run_plan)


def run_plan(args: argparse.Namespace) -> int:
    try:
        ros_map = read_ros_map(args.map)
    except (MapFileError, OSError) as exc:
        print(f"fleetmap plan: error: {exc}", file=sys.stderr)
        return 2
    geometry = ros_map.geometry
    layers = [StaticLayer(ros_map), InflationLayer(InflationParams(), geometry)]
    costs = LayeredCostmap(geometry, layers, history=1).costs
    try:
        result = GridPlanner(geometry).plan(
            costs, args.start, args.goal, args.algorithm, not args.no_unknown
        )
    except PlanRequestError as exc:
        print(f"fleetmap plan: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({**asdict(result), "map_version": 0}))
    elif result.found:
        print(
            f"path of {len(result.path)} cells, {result.length:.2f} m, cost {result.cost:.2f}, "
            f"clearance {result.min_clearance:.2f} m, {result.expanded} nodes expanded in "
            f"{result.planning_ms:.1f} ms"
        )
    else:
        print(f"no path ({result.expanded} nodes expanded in {result.planning_ms:.1f} ms)")
    return 0 if result.found else 1
