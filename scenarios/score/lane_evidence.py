"""What blocked a lane freeze: the blocked lanes on a unit's way and their first blocked
cells, as the lane coordinator saw them (its last ``LaneGraph.refresh``).

A lane freeze is a unit with a task that the coordinator holds (``UnitStatus.state``):

- ``no_route``: at a node, no route to its goal node over unblocked lanes. The lanes
  named are the *cut* that keeps it from its goal: every blocked edge (u, v), driven in
  its allowed direction, from a node u the unit can reach over unblocked lanes to a node
  v from which the goal is reachable (blocked or not) without coming back among the
  reachable nodes. Every route from the unit to its goal crosses one of them, and
  clearing any one opens a way past it; lanes into pockets that lead nowhere but back
  are left out. Ordered: those on the unit's shortest route ignoring blocks (by length,
  the way it would drive on a clear floor) first, in route order, then the rest by key.
- ``stranded``: on a lane that became blocked ahead of it, waiting to turn back: that
  lane (named even when a later refresh has cleared it; it then has no cells).

The points of a lane are its ``block_cells`` (``planner.lane_graph``): the first blocked
cell seen from each end, the one met first when driving it toward the goal first. The
runner reads their evidence (p_occ, last_observed, ground truth, the scans that last
marked them) as for a path freeze's cells.
"""

from __future__ import annotations

from collections.abc import Iterable

import networkx as nx

from planner.coordinator import LaneCoordinator
from planner.freeze import Lane, LaneBlock, Point
from planner.lane_graph import LaneGraph, lane_key


def lane_block(coordinator: LaneCoordinator, graph: LaneGraph, unit_id: str) -> LaneBlock | None:
    """The lane block holding ``unit_id`` now (module docstring); None when the coordinator
    does not hold it (it is not in state ``no_route`` or ``stranded``)."""
    status = coordinator.status(unit_id)
    if status.state == "no_route" and status.node is not None:
        edges = blocking_cut(graph, status.node, status.goal)
        origin: tuple[str, ...] = (status.node,)
    elif status.state == "stranded" and status.edge is not None:
        edges = [status.edge]
        origin = tuple(status.edge)
    else:
        return None
    lanes: list[Lane] = []
    points: list[Point] = []
    for u, v in edges:
        key = lane_key(u, v)
        if key not in lanes:
            lanes.append(key)
        for point in _cells(graph, u, v):
            if point not in points:
                points.append(point)
    return LaneBlock(origin, status.goal, tuple(lanes), tuple(points))


def lane_blocking_points(
    coordinator: LaneCoordinator, graph: LaneGraph, unit_id: str
) -> tuple[Point, ...]:
    """The first blocked cells [m] of the lanes that hold ``unit_id`` (``lane_block``);
    empty when the coordinator does not hold it."""
    block = lane_block(coordinator, graph, unit_id)
    return () if block is None else block.points


def blocking_cut(graph: LaneGraph, node: str, goal: str) -> list[tuple[str, str]]:
    """The blocked directed edges that keep ``node`` from ``goal`` (module docstring)."""
    g = graph.graph
    reach = _reachable(g, node, lambda u, v: not g.edges[u, v]["blocked"])
    if goal in reach:
        return []
    outside = g.subgraph(n for n in g if n not in reach)
    onward = set(nx.ancestors(outside, goal)) | {goal}  # reach the goal avoiding ``reach``
    cut = {
        (u, v) for u in reach for v in g.successors(u) if v in onward and g.edges[u, v]["blocked"]
    }
    try:
        route = nx.bidirectional_dijkstra(g, node, goal, weight="length")[1]
    except nx.NetworkXNoPath:
        route = []
    first = [e for e in zip(route, route[1:], strict=False) if e in cut]
    return first + sorted(cut - set(first), key=lambda e: (lane_key(*e), e))


def _reachable(g: nx.DiGraph, start: str, usable) -> set[str]:
    seen = {start}
    todo = [start]
    while todo:
        u = todo.pop()
        for v in g.successors(u):
            if v not in seen and usable(u, v):
                seen.add(v)
                todo.append(v)
    return seen


def _cells(graph: LaneGraph, u: str, v: str) -> Iterable[Point]:
    """Edge (u, v)'s first blocked cells, the one seen from u first (mirrored for a
    one-way lane driven backwards)."""
    edges = graph.graph.edges
    if (u, v) in edges:
        return edges[u, v].get("block_cells") or ()
    return tuple(reversed(edges[v, u].get("block_cells") or ()))
