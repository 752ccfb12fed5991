"""An external planner on fleetmap's shared costmap.

It reads the costmap with ``MapClient``, plans its own route with scipy's Dijkstra over
the known, passable cells (4-connected; a step costs 1 + cost / 252, so it keeps away
from obstacles when it can), then asks the server whether the route is still clear.

    python docs/examples/external_planner.py URL START_X,START_Y GOAL_X,GOAL_Y [TOKEN]

prints ``{"found", "length_m", "map_version", "path", "blocked"}`` as JSON (exit 1: no path;
exit 2 with the usage or a one-line error: bad arguments, a point off the map, a server
that cannot be reached or refuses the token).
"""

import argparse
import json
import sys

import httpx
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from mapserver.cli.map_build import xy_pair
from mapserver.client import Grid, MapClient
from mapserver.core.costvalues import INSCRIBED
from mapserver.core.errors import FleetmapError


def plan(costs: Grid, start: tuple[float, float], goal: tuple[float, float]) -> list:
    """Cell centres [m] from start to goal over cells cheaper than INSCRIBED ([] if none)."""
    g = costs.geometry
    ids = np.arange(g.size).reshape(g.shape)
    ok = costs.data < INSCRIBED  # lethal, inscribed and unknown (255) are not passable
    weight = 1.0 + costs.data / 252.0
    edges = []
    for a, b in ((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :])):
        both = ok[a] & ok[b]  # neighbours right and up, both passable
        edges.append((ids[a][both], ids[b][both], (weight[a][both] + weight[b][both]) / 2))
    src, dst, w = (np.concatenate(part) for part in zip(*edges, strict=True))
    graph = coo_matrix((w, (src, dst)), shape=(g.size, g.size)).tocsr()
    s, t = (g.index(*g.world_to_cell_checked(*p)) for p in (start, goal))
    dist, pred = dijkstra(graph, directed=False, indices=s, return_predecessors=True)
    if not np.isfinite(dist[t]):
        return []
    cells = [t]
    while cells[-1] != s:
        cells.append(pred[cells[-1]])
    return [g.cell_to_world(int(i) % g.width, int(i) // g.width) for i in reversed(cells)]


def main(argv: list[str]) -> int:
    """Parse ``argv`` (usage and a one-line error, exit 2, for bad arguments), plan, and
    print the JSON reply; a server that cannot be reached or refuses is one line, exit 2."""
    parser = argparse.ArgumentParser(
        prog="external_planner.py",
        description="Plan a route on a fleetmap server's costmap and check it is clear.",
    )
    parser.add_argument("url", type=server_url, help="the map server: http://HOST:PORT")
    parser.add_argument("start", type=xy_pair, metavar="START_X,START_Y", help="[m]")
    parser.add_argument("goal", type=xy_pair, metavar="GOAL_X,GOAL_Y", help="[m]")
    parser.add_argument("token", nargs="?", help="a reader token, if the server has tokens")
    args = parser.parse_args(argv[1:])
    try:
        with httpx.Client(base_url=args.url) as http:
            return route(MapClient(http, token=args.token), args.start, args.goal)
    except FleetmapError as exc:
        print(f"external_planner.py: error: {exc}", file=sys.stderr)
        return 2


def server_url(text: str) -> str:
    """argparse type: an http(s) URL with a host."""
    parsed = httpx.URL(text) if text.startswith(("http://", "https://")) else None
    if parsed is None or not parsed.host:
        raise argparse.ArgumentTypeError(f"expected http://HOST:PORT, got {text!r}")
    return text


def route(client: MapClient, start: tuple[float, float], goal: tuple[float, float]) -> int:
    """Plan from ``start`` to ``goal`` [m] on the client's costmap, print the reply; 1 when
    there is no route."""
    costs = client.costmap()
    path = plan(costs, start, goal)
    if not path:
        print(json.dumps({"found": False, "map_version": costs.version}))
        return 1
    steps = [(*a, *b) for a, b in zip(path, path[1:], strict=False)]
    blocked = any(s.blocked for s in client.query_segments(steps)) if steps else False
    length = float(np.hypot(*np.diff(np.array(path), axis=0).T).sum())
    report = {"found": True, "length_m": round(length, 3), "map_version": costs.version}
    print(json.dumps({**report, "path": path, "blocked": blocked}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
