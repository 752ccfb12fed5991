"""An external planner on fleetmap's shared costmap.

It reads the costmap with ``MapClient``, plans its own route with scipy's Dijkstra over
the known, passable cells (4-connected; a step costs 1 + cost / 252, so it keeps away
from obstacles when it can), then asks the server whether the route is still clear.

    python docs/examples/external_planner.py URL START_X,START_Y GOAL_X,GOAL_Y [TOKEN]

prints ``{"found", "length_m", "map_version", "path", "blocked"}`` as JSON (exit 1: no path).
"""

import json
import sys

import httpx
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from mapserver.client import Grid, MapClient
from mapserver.core.costvalues import INSCRIBED


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
    url, start, goal = argv[1], *(tuple(map(float, a.split(","))) for a in argv[2:4])
    with httpx.Client(base_url=url) as http:
        client = MapClient(http, token=argv[4] if len(argv) > 4 else None)
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
