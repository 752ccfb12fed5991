"""The planner's grid as a networkx graph: a slow, obviously correct reference for tests
and benchmarks (same 8-connectivity, weights and corner rule as ``grid_search``)."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np

from planner.grid_search import cell_weights


def networkx_grid(costs: np.ndarray, resolution: float, allow_unknown: bool = True) -> nx.DiGraph:
    """Nodes (row, col) of enterable cells; edge u -> v weighs step [m] x weight(v)."""
    weights = cell_weights(allow_unknown)
    passable = weights[costs] != np.inf
    h, w = costs.shape
    graph = nx.DiGraph()
    graph.add_nodes_from((int(r), int(c)) for r, c in zip(*np.nonzero(passable), strict=True))
    for r, c in zip(*np.nonzero(passable), strict=True):
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = r + dr, c + dc
                if (dr, dc) == (0, 0) or not (0 <= rr < h and 0 <= cc < w) or not passable[rr, cc]:
                    continue
                if dr and dc and not (passable[r, cc] and passable[rr, c]):
                    continue  # no cutting an impassable corner
                step = resolution * (math.sqrt(2) if dr and dc else 1.0)
                graph.add_edge(
                    (int(r), int(c)), (int(rr), int(cc)), weight=step * weights[costs[rr, cc]]
                )
    return graph
