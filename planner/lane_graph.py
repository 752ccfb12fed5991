"""The lane graph: the junctions, stations and lane stretches units drive along.

A ``LaneGraph`` wraps a networkx ``DiGraph`` (Hagberg, Schult and Swart, *Exploring
network structure, dynamics, and function using NetworkX*, SciPy 2008):

- nodes are places a unit can stop: ``junction`` (a crossing of two lane centre lines),
  ``station`` (a named stop on a lane) and ``waypoint`` (a stop that splits a long lane so
  that units can follow one another). Node attribute ``pos``: (x, y) [m] in ``map``.
- each lane stretch between two neighbouring nodes is one undirected *lane*, keyed by its
  two node ids in sorted order, and carries two directed edges, or one if the lane is
  one-way. Edge attributes:

  ============== ==============================================================
  ``lane``        the lane key ``(a, b)``, ``a < b``
  ``length``      [m] straight-line distance between the two nodes
  ``base``        [m] the weight before any costmap reading (= ``length``)
  ``weight``      [m] the routing weight (see *Weights*)
  ``penalty``     [m] ``weight - length``: what the costmap adds
  ``blocked``     True when the costmap blocks the lane: never routed over
  ``max_cost``    highest known Nav2 cost on the lane (None: none known or not read)
  ``unknown``     fraction 0..1 of the lane's cells that are unknown (None: not read)
  ``block_span``  (near, far) [m] from the edge's tail: where the blocked cells start
                  and end along this edge's direction; None when not blocked
  ``block_cells`` the centres (x, y) [m] of the first blocked cell seen from the edge's
                  tail, then from its head (as the map reported them; one when both
                  are the same cell or one reading was clear); None when not blocked
  ``corridor``    index into ``corridors`` of the corridor the lane belongs to
  ``heading``     +1 along the corridor's node order, -1 against it
  ============== ==============================================================

Corridors. A *corridor* is a maximal chain of lanes through nodes that join exactly
two lanes and are not junctions (waypoints and stations along one aisle stretch): a
unit in it can only go on or go back. ``corridors[k]`` is its node list, from the end
with the smaller id; ``corridor_ends`` are the nodes where corridors end (junctions,
dead ends, branchings). The coordinator lets units follow one another through a
corridor but never lets two drive it in opposite directions at once. ``crossings`` are
the junctions joining three or more lanes, where the coordinator never lets a unit stop
on its way through.

Weights. ``refresh(client)`` reads every lane in ONE ``query_segments`` call, each lane
both ways (a->b and b->a: the first blocked cell seen from each end bounds the block).
A lane is blocked if either reading is blocked (a lethal or inscribed cell on it), and::

    c = min(max_cost, 252)        (None -> 0: no known cell, unknown_fraction covers it)
    weight = length * (1 + cost_factor * c / 252 + unknown_factor * unknown_fraction)

taking the larger ``max_cost`` and ``unknown_fraction`` of the two readings. It is the
shape of NavFn's cost-aware step (a neutral cost plus a factor times the cell cost), per
metre of lane; with the defaults ``cost_factor = unknown_factor = 1`` a lane that brushes
the inflation band at full graded cost, or that was never seen, counts double.

Routing is Dijkstra (Dijkstra, *A note on two problems in connexion with graphs*,
Numerische Mathematik 1, 1959) over unblocked edges, by networkx's bidirectional
variant. Ties between equal routes follow networkx's insertion order, which here is the
sorted order of node ids and lane keys: the same graph gives the same routes.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence, Set
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import networkx as nx
import numpy as np

from mapserver.core.costvalues import MAX_GRADED

if TYPE_CHECKING:
    from fleet.boxworld import Warehouse

Lane = tuple[str, str]
"""An undirected lane: its two end node ids in sorted order."""

NODE_KINDS = ("junction", "station", "waypoint")


class SegmentReading(Protocol):
    """One segment of the map as the lane graph reads it (``MapClient``'s ``SegmentOut``,
    docs/http-api.md 2.5): max_cost 0..255 (None: no known cell), blocked (a cell on it is lethal
    or inscribed), unknown_fraction 0..1 of its cells, first_blocked [x, y] [m] or None."""

    @property
    def max_cost(self) -> int | None: ...
    @property
    def blocked(self) -> bool: ...
    @property
    def unknown_fraction(self) -> float: ...
    @property
    def first_blocked(self) -> Sequence[float] | None: ...


class SegmentQuerier(Protocol):
    """What the lane graph needs of the map: ``MapClient.query_segments`` (docs/http-api.md 2.5)."""

    def query_segments(self, segments: Sequence[Sequence[float]]) -> Sequence[SegmentReading]:
        """One reading per segment ``(x0, y0, x1, y1)`` [m], in order."""
        ...


@dataclass(frozen=True)
class LaneChanges:
    """What a ``refresh`` changed: lanes newly ``blocked``, lanes ``cleared``, sorted."""

    blocked: tuple[Lane, ...]
    cleared: tuple[Lane, ...]


def lane_key(a: str, b: str) -> Lane:
    """The lane between nodes a and b, whichever way it is driven."""
    return (a, b) if a < b else (b, a)


class LaneGraph:
    """Nodes and lanes with costmap-derived weights and blocked flags.

    positions: node id -> (x, y) [m]. lanes: pairs of node ids, one per lane (either
    order; no lane twice). one_way: (a, b) pairs, each naming a lane driven only a -> b.
    kinds: node id -> "junction" | "station" | "waypoint" (default "junction").
    cost_factor, unknown_factor: >= 0, the weight rule's factors (module docstring).
    """

    def __init__(
        self,
        positions: Mapping[str, tuple[float, float]],
        lanes: Iterable[tuple[str, str]],
        one_way: Iterable[tuple[str, str]] = (),
        *,
        kinds: Mapping[str, str] | None = None,
        cost_factor: float = 1.0,
        unknown_factor: float = 1.0,
    ) -> None:
        for name, value in (("cost_factor", cost_factor), ("unknown_factor", unknown_factor)):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        self.cost_factor = float(cost_factor)
        self.unknown_factor = float(unknown_factor)
        kinds = kinds or {}
        graph = nx.DiGraph()
        for node in sorted(positions):
            x, y = positions[node]
            if not (isinstance(node, str) and node and math.isfinite(x) and math.isfinite(y)):
                raise ValueError(f"positions[{node!r}] must be a finite (x, y), got {(x, y)!r}")
            kind = kinds.get(node, "junction")
            if kind not in NODE_KINDS:
                raise ValueError(f"kinds[{node!r}] must be one of {NODE_KINDS}, got {kind!r}")
            graph.add_node(node, pos=(float(x), float(y)), kind=kind)
        keys: list[Lane] = []
        for a, b in lanes:
            for end in (a, b):
                if end not in graph:
                    raise ValueError(f"lane ({a!r}, {b!r}) names {end!r}, which has no position")
            if a == b:
                raise ValueError(f"lane ({a!r}, {b!r}) must join two different nodes")
            keys.append(lane_key(a, b))
        if len(set(keys)) != len(keys):
            dup = next(k for k in sorted(keys) if keys.count(k) > 1)
            raise ValueError(f"lane {dup!r} is given twice")
        directed = _one_way_table(one_way, set(keys))
        for key in sorted(keys):
            a, b = key
            (ax, ay), (bx, by) = graph.nodes[a]["pos"], graph.nodes[b]["pos"]
            length = math.hypot(bx - ax, by - ay)
            if not length > 0:
                raise ValueError(f"lane {key!r} has zero length: both ends at {(ax, ay)!r}")
            for u, v in ((a, b), (b, a)):
                if directed.get(key, u) == u:
                    graph.add_edge(
                        u,
                        v,
                        lane=key,
                        length=length,
                        base=length,
                        weight=length,
                        penalty=0.0,
                        blocked=False,
                        max_cost=None,
                        unknown=None,
                        block_span=None,
                        block_cells=None,
                    )
        self.graph = graph
        self.lanes: tuple[Lane, ...] = tuple(sorted(keys))
        self.nodes: tuple[str, ...] = tuple(graph.nodes)
        self.version = 0
        """Bumped by every ``refresh`` that changed a weight or a blocked flag."""
        self._xy = np.array([graph.nodes[n]["pos"] for n in self.nodes], dtype=np.float64)
        self._index = {n: i for i, n in enumerate(self.nodes)}
        self.corridors, self.corridor_ends = _label_corridors(graph, self.lanes)
        und = graph.to_undirected(as_view=True)
        self.crossings = frozenset(
            n for n in self.nodes if graph.nodes[n]["kind"] == "junction" and und.degree(n) >= 3
        )
        """Junctions joining three or more lanes: places where units must not stop."""

    @classmethod
    def from_warehouse(
        cls,
        warehouse: Warehouse,
        stations: Mapping[str, tuple[float, float]] | None = None,
        one_way: Iterable[tuple[str, str]] = (),
        *,
        segment_m: float | None = None,
        station_snap_m: float = 1.0,
        cost_factor: float = 1.0,
        unknown_factor: float = 1.0,
    ) -> LaneGraph:
        """The lane grid of ``warehouse`` (``fleet.boxworld.warehouse_layout``).

        Junction ``j{ix}_{iy}`` sits at ``(lane_x[ix], lane_y[iy])`` [m]; a *stretch*
        joins two junctions adjacent along a lane line (the layout keeps it clear of
        racks). stations: id -> (x, y) [m]; each is placed at its projection on the
        nearest stretch, which must be within ``station_snap_m`` [m], strictly between the
        stretch's junctions; the station splits the stretch. segment_m [m]: split every
        piece longer than this into equal lanes at waypoints ``w{ix}_{iy}{h|v}{k}`` (the
        k-th stop along the stretch leaving junction (ix, iy) to the right (h) or up (v)).
        one_way: (junction_a, junction_b) stretches driven only a -> b; the pieces of a
        split stretch inherit the direction.
        """
        if segment_m is not None and not (math.isfinite(segment_m) and segment_m > 0):
            raise ValueError(f"segment_m must be a positive number of metres, got {segment_m!r}")
        if not (math.isfinite(station_snap_m) and station_snap_m >= 0):
            raise ValueError(f"station_snap_m must be >= 0 m, got {station_snap_m!r}")
        xs, ys = warehouse.lane_x, warehouse.lane_y
        positions: dict[str, tuple[float, float]] = {}
        kinds: dict[str, str] = {}
        for iy, y in enumerate(ys):
            for ix, x in enumerate(xs):
                positions[f"j{ix}_{iy}"] = (x, y)
        # Stretches: (tail junction, head junction, waypoint id prefix), tail at lower x / y.
        stretches = [
            (f"j{ix}_{iy}", f"j{ix + 1}_{iy}", f"w{ix}_{iy}h")
            for iy in range(len(ys))
            for ix in range(len(xs) - 1)
        ]
        stretches += [
            (f"j{ix}_{iy}", f"j{ix}_{iy + 1}", f"w{ix}_{iy}v")
            for ix in range(len(xs))
            for iy in range(len(ys) - 1)
        ]
        directed = _one_way_table(one_way, {lane_key(a, b) for a, b, _ in stretches})
        stops = _place_stations(stations or {}, stretches, positions, station_snap_m)
        lanes: list[tuple[str, str]] = []
        piece_one_way: list[tuple[str, str]] = []
        for index, (a, b, prefix) in enumerate(stretches):
            (ax, ay), (bx, by) = positions[a], positions[b]
            length = math.hypot(bx - ax, by - ay)
            marks = [(0.0, a), *stops.get(index, []), (length, b)]
            chain = [a]
            for (t0, _), (t1, end) in zip(marks, marks[1:], strict=False):
                parts = (
                    1 if segment_m is None else max(1, math.ceil(round((t1 - t0) / segment_m, 9)))
                )
                for k in range(1, parts):
                    t = t0 + (t1 - t0) * k / parts
                    node = f"{prefix}{len(chain)}"
                    positions[node] = (ax + (bx - ax) * t / length, ay + (by - ay) * t / length)
                    kinds[node] = "waypoint"
                    chain.append(node)
                chain.append(end)
            forward = directed.get(lane_key(a, b))
            for u, v in zip(chain, chain[1:], strict=False):
                lanes.append((u, v))
                if forward is not None:
                    piece_one_way.append((u, v) if forward == a else (v, u))
        for sid in stations or {}:
            kinds[sid] = "station"
        return cls(
            positions,
            lanes,
            piece_one_way,
            kinds=kinds,
            cost_factor=cost_factor,
            unknown_factor=unknown_factor,
        )

    # -- reading

    def position(self, node: str) -> tuple[float, float]:
        """(x, y) [m] of ``node``."""
        self._check_node("node", node)
        return self.graph.nodes[node]["pos"]

    def nearest_node(self, x: float, y: float) -> str:
        """The node nearest to (x, y) [m]; ties go to the smallest node id."""
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"(x, y) must be finite, got {(x, y)!r}")
        if not self.nodes:
            raise ValueError("the lane graph has no nodes")
        d2 = (self._xy[:, 0] - x) ** 2 + (self._xy[:, 1] - y) ** 2
        return self.nodes[int(np.argmin(d2))]  # nodes are sorted; argmin takes the first

    def nearest_free_node(self, x: float, y: float, taken: Set[str]) -> str | None:
        """The node nearest to (x, y) [m] that is not in ``taken`` (ties: the smallest node
        id); None when every node is taken.

        Distances are ``math.dist``'s: squared distances in numpy find the few nodes
        within rounding of the nearest, and ``math.dist`` decides among those, so the
        answer is the one a scan of every node with ``math.dist`` gives."""
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"(x, y) must be finite, got {(x, y)!r}")
        d2 = (self._xy[:, 0] - x) ** 2 + (self._xy[:, 1] - y) ** 2
        if taken:
            d2[[self._index[n] for n in taken if n in self._index]] = math.inf
        best = d2.min(initial=math.inf)
        if best == math.inf:
            return None
        near = np.flatnonzero(d2 <= best * (1 + 1e-9) + 1e-300)
        return min(
            (self.nodes[i] for i in near), key=lambda n: (math.dist(self.position(n), (x, y)), n)
        )

    def shortest_route(
        self,
        a: str,
        b: str,
        avoid_edges: frozenset[tuple[str, str]] | set[tuple[str, str]] = frozenset(),
        avoid_nodes: frozenset[str] | set[str] = frozenset(),
    ) -> list[str] | None:
        """The least-weight node list from ``a`` to ``b`` over unblocked edges, or None.

        avoid_edges: directed edges (u, v) not to use. avoid_nodes: nodes not to pass
        through (``a`` and ``b`` themselves are always allowed). ``[a]`` when a == b.
        """
        self._check_node("a", a)
        self._check_node("b", b)
        if a == b:
            return [a]

        def weight(u: str, v: str, d: Mapping[str, object]) -> float | None:
            if d["blocked"] or (u, v) in avoid_edges or (v in avoid_nodes and v != b):
                return None  # networkx hides an edge whose weight is None
            return d["weight"]  # type: ignore[return-value]

        try:
            return nx.bidirectional_dijkstra(self.graph, a, b, weight=weight)[1]
        except nx.NetworkXNoPath:
            return None

    def is_blocked(self, a: str, b: str) -> bool:
        """Whether the lane between a and b (either direction) is blocked."""
        edges = self.graph.edges
        return any(edges[e]["blocked"] for e in ((a, b), (b, a)) if e in edges)

    def route_length(self, route: Sequence[str]) -> float:
        """Length [m] of a node list along its edges."""
        edges = self.graph.edges
        return float(sum(edges[u, v]["length"] for u, v in zip(route, route[1:], strict=False)))

    # -- costmap

    def refresh(self, client: SegmentQuerier) -> LaneChanges:
        """Update every edge's weight and blocked flag from the costmap (module docstring).

        One ``client.query_segments`` call with two segments per lane, a->b then b->a.
        """
        if not self.lanes:
            return LaneChanges((), ())
        pos = self.graph.nodes
        segments = []
        for a, b in self.lanes:
            (ax, ay), (bx, by) = pos[a]["pos"], pos[b]["pos"]
            segments += [(ax, ay, bx, by), (bx, by, ax, ay)]
        infos = client.query_segments(segments)
        if len(infos) != len(segments):
            raise ValueError(
                f"query_segments answered {len(infos)} segments for the {len(segments)} asked"
            )
        blocked: list[Lane] = []
        cleared: list[Lane] = []
        changed = False
        for k, (a, b) in enumerate(self.lanes):
            fwd, back = infos[2 * k], infos[2 * k + 1]
            reading = _lane_reading(pos[a]["pos"], pos[b]["pos"], fwd, back)
            was = self.is_blocked(a, b)
            for u, v in ((a, b), (b, a)):
                if not self.graph.has_edge(u, v):
                    continue
                d = self.graph.edges[u, v]
                weight = d["length"] * (
                    1.0
                    + self.cost_factor * reading.cost / float(MAX_GRADED)
                    + self.unknown_factor * reading.unknown
                )
                span, cells = reading.span, reading.cells
                if span is not None and u == b:
                    span = (d["length"] - span[1], d["length"] - span[0])
                    cells = cells[::-1]
                if (d["blocked"], d["weight"]) != (reading.blocked, weight):
                    changed = True
                d.update(
                    weight=weight,
                    penalty=weight - d["length"],
                    blocked=reading.blocked,
                    max_cost=reading.max_cost,
                    unknown=reading.unknown,
                    block_span=span,
                    block_cells=_distinct(cells) if reading.blocked else None,
                )
            if reading.blocked and not was:
                blocked.append((a, b))
            elif was and not reading.blocked:
                cleared.append((a, b))
        if changed:
            self.version += 1
        return LaneChanges(tuple(blocked), tuple(cleared))

    def _check_node(self, name: str, node: str) -> None:
        if node not in self.graph:
            raise ValueError(f"{name} {node!r} is not a node of the lane graph")


@dataclass(frozen=True)
class _Reading:
    """One lane's costmap reading: blocked, cost c (0..252), unknown fraction, block span."""

    blocked: bool
    max_cost: int | None
    cost: float
    unknown: float
    span: tuple[float, float] | None  # [m] from the lane's first node (a), a->b
    cells: tuple[tuple[float, float] | None, tuple[float, float] | None]  # first blocked
    # cell seen from a, from b (None: that reading found none)


def _label_corridors(
    graph: nx.DiGraph, lanes: tuple[Lane, ...]
) -> tuple[tuple[tuple[str, ...], ...], frozenset[str]]:
    """Split the lanes into corridors; set each edge's ``corridor`` and ``heading``."""
    und = graph.to_undirected(as_view=True)
    ends = frozenset(n for n in graph if und.degree(n) != 2 or graph.nodes[n]["kind"] == "junction")
    corridor_of: dict[Lane, int] = {}
    corridors: list[tuple[str, ...]] = []
    for lane in lanes:  # sorted: corridors are numbered by their smallest lane
        if lane in corridor_of:
            continue
        chain = list(lane)
        ring = False
        while chain[-1] not in ends and not ring:
            step = next(n for n in sorted(und[chain[-1]]) if n != chain[-2])
            ring = step == chain[0]
            if not ring:
                chain.append(step)
        while chain[0] not in ends and not ring:
            chain.insert(0, next(n for n in sorted(und[chain[0]]) if n != chain[1]))
        if ring:  # a closed loop of pass-through nodes: cut it at its first lane
            chain.append(chain[0])
        elif chain[-1] < chain[0]:
            chain.reverse()
        index = len(corridors)
        corridors.append(tuple(chain))
        for u, v in zip(chain, chain[1:], strict=False):
            corridor_of[lane_key(u, v)] = index
            for a, b, heading in ((u, v, 1), (v, u, -1)):
                if graph.has_edge(a, b):
                    graph.edges[a, b].update(corridor=index, heading=heading)
    return tuple(corridors), ends


def _lane_reading(
    a: tuple[float, float], b: tuple[float, float], fwd: SegmentReading, back: SegmentReading
) -> _Reading:
    """Combine the a->b and b->a readings of one lane (the module docstring's rule)."""
    known = [c for c in (fwd.max_cost, back.max_cost) if c is not None]
    max_cost = max(known) if known else None
    blocked = bool(fwd.blocked or back.blocked)
    span = None
    if blocked:
        length = math.hypot(b[0] - a[0], b[1] - a[1])
        near = 0.0 if fwd.first_blocked is None else _dist(a, fwd.first_blocked)
        far = length if back.first_blocked is None else length - _dist(b, back.first_blocked)
        near, far = min(max(near, 0.0), length), min(max(far, 0.0), length)
        span = (min(near, far), max(near, far))
    return _Reading(
        blocked=blocked,
        max_cost=max_cost,
        cost=float(min(max_cost if max_cost is not None else 0, int(MAX_GRADED))),
        unknown=float(max(fwd.unknown_fraction, back.unknown_fraction)),
        span=span,
        cells=(_point(fwd.first_blocked), _point(back.first_blocked)),
    )


def _point(p: Sequence[float] | None) -> tuple[float, float] | None:
    return None if p is None else (float(p[0]), float(p[1]))


def _distinct(
    cells: Sequence[tuple[float, float] | None],
) -> tuple[tuple[float, float], ...]:
    """The known cells, in order, each once."""
    out: list[tuple[float, float]] = []
    for c in cells:
        if c is not None and c not in out:
            out.append(c)
    return tuple(out)


def one_way_loops(n_x: int, n_y: int) -> tuple[tuple[str, str], ...]:
    """One-way "highways" for the ``n_x`` x ``n_y`` junction grid of ``from_warehouse``,
    as pairs (a, b) of neighbouring junctions, each stretch driven only a -> b.

    Kiva's traffic pattern (Wurman, D'Andrea and Mountz, *Coordinating Hundreds of
    Cooperative, Autonomous Vehicles in Warehouses*, AI Magazine 29(1), 2008): the
    perimeter is one counter-clockwise loop (bottom row east, right column north, top row
    west, left column south) and the lines inside it alternate, rows starting westward
    and columns starting northward. Every inside row and column starts on a perimeter
    side that passes all of them and ends on one that leads back, so every junction can
    reach every other (the graph is strongly connected) and no lane is ever driven
    head-on. Needs at least two lanes each way.
    """
    if n_x < 2 or n_y < 2:
        raise ValueError(f"one-way loops need at least 2 x 2 junctions, got {n_x} x {n_y}")
    pairs: list[tuple[str, str]] = []
    for iy in range(n_y):
        east = iy == 0 or (iy != n_y - 1 and iy % 2 == 0)
        for ix in range(n_x - 1):
            a, b = f"j{ix}_{iy}", f"j{ix + 1}_{iy}"
            pairs.append((a, b) if east else (b, a))
    for ix in range(n_x):
        north = ix == n_x - 1 or (ix != 0 and ix % 2 == 1)
        for iy in range(n_y - 1):
            a, b = f"j{ix}_{iy}", f"j{ix}_{iy + 1}"
            pairs.append((a, b) if north else (b, a))
    return tuple(pairs)


def one_way_aisles(n_x: int, n_y: int) -> tuple[tuple[str, str], ...]:
    """One-way rows for the ``n_x`` x ``n_y`` junction grid of ``from_warehouse``: every
    horizontal stretch (the aisles between rack rows, and the staging and top rows) is
    driven one way, the rows alternating east / west from the bottom one (east); the
    columns (cross-aisles and the perimeter's sides) stay two-way.

    The long stretches, where two units meeting head-on have nowhere to pass, carry one
    direction; the short column stretches keep trips short. With at least two rows the
    graph stays strongly connected (a row of each direction, joined by two-way
    columns; Robbins, *A theorem on graphs, with an application to a problem of traffic
    control*, Amer. Math. Monthly 46, 1939, for why an orientation needs the two-way
    links). Needs at least two junctions each way.
    """
    if n_x < 2 or n_y < 2:
        raise ValueError(f"one-way aisles need at least 2 x 2 junctions, got {n_x} x {n_y}")
    pairs: list[tuple[str, str]] = []
    for iy in range(n_y):
        for ix in range(n_x - 1):
            a, b = f"j{ix}_{iy}", f"j{ix + 1}_{iy}"
            pairs.append((a, b) if iy % 2 == 0 else (b, a))
    return tuple(pairs)


def _dist(p: tuple[float, float], q: Sequence[float]) -> float:
    return math.hypot(q[0] - p[0], q[1] - p[1])


def _one_way_table(one_way: Iterable[tuple[str, str]], lanes: set[Lane]) -> dict[Lane, str]:
    """lane -> the node it must be driven away from; ValueError names a bad pair."""
    table: dict[Lane, str] = {}
    for pair in one_way:
        a, b = pair
        key = lane_key(a, b)
        if key not in lanes:
            raise ValueError(f"one_way pair ({a!r}, {b!r}) is not a lane of the graph")
        if table.get(key, a) != a:
            raise ValueError(f"one_way gives lane {key!r} both directions")
        table[key] = a
    return table


def nearest_stretch(
    x: float,
    y: float,
    stretches: list[tuple[str, str, str]],
    positions: Mapping[str, tuple[float, float]],
    indices: Iterable[int],
) -> tuple[float, int, float] | None:
    """Of the stretches at ``indices``, the first nearest (x, y) [m], measured exactly:
    (distance [m], its index, the foot's distance from its tail [m]); None for none."""
    best: tuple[float, int, float] | None = None
    for index in indices:
        a, b, _ = stretches[index]
        (ax, ay), (bx, by) = positions[a], positions[b]
        length = math.hypot(bx - ax, by - ay)
        t = min(max(((x - ax) * (bx - ax) + (y - ay) * (by - ay)) / length, 0.0), length)
        gap = math.hypot(ax + (bx - ax) * t / length - x, ay + (by - ay) * t / length - y)
        if best is None or gap < best[0]:
            best = (gap, index, t)
    return best


class _NearestStretches:
    """The stretches (lane segments between junctions) nearest a point, found for all of
    them at once in numpy: ``candidates`` gives the indices, in order, whose distance is
    within ``TIE_M`` of the least, which the caller measures again exactly (``math``)
    and takes the first least of, as a loop over every stretch would."""

    TIE_M = 1e-9  # [m] numpy's and math's distances may differ in their last bits

    def __init__(
        self, stretches: list[tuple[str, str, str]], positions: Mapping[str, tuple[float, float]]
    ) -> None:
        ends = np.array(
            [(*positions[a], *positions[b]) for a, b, _ in stretches], dtype=np.float64
        ).reshape(-1, 4)
        self.ax, self.ay = ends[:, 0], ends[:, 1]
        self.dx, self.dy = ends[:, 2] - ends[:, 0], ends[:, 3] - ends[:, 1]
        self.length = np.hypot(self.dx, self.dy)

    def candidates(self, x: float, y: float) -> list[int]:
        """Indices of the stretches nearest (x, y) [m] (see the class docstring)."""
        if not len(self.length):
            return []
        with np.errstate(invalid="ignore", divide="ignore"):
            along = ((x - self.ax) * self.dx + (y - self.ay) * self.dy) / self.length
            t = np.minimum(np.maximum(along, 0.0), self.length)
            gap = np.hypot(
                self.ax + self.dx * t / self.length - x, self.ay + self.dy * t / self.length - y
            )
        finite = np.isfinite(gap)
        if not finite.any():
            return list(range(len(gap)))  # let the exact loop say what it says
        least = gap[finite].min()
        return [int(i) for i in np.flatnonzero(~finite | (gap <= least + self.TIE_M))]


def _place_stations(
    stations: Mapping[str, tuple[float, float]],
    stretches: list[tuple[str, str, str]],
    positions: dict[str, tuple[float, float]],
    snap_m: float,
) -> dict[int, list[tuple[float, str]]]:
    """stretch index -> [(distance from its tail [m], station id)], sorted; adds positions."""
    stops: dict[int, list[tuple[float, str]]] = {}
    near = _NearestStretches(stretches, positions)
    for sid in sorted(stations):
        x, y = stations[sid]
        if not (isinstance(sid, str) and sid and math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"stations[{sid!r}] must be a finite (x, y), got {(x, y)!r}")
        if sid in positions:
            raise ValueError(f"station id {sid!r} is already a node id")
        best = nearest_stretch(x, y, stretches, positions, near.candidates(x, y))
        if best is None or best[0] > snap_m:
            gap = "no lane" if best is None else f"{best[0]:.3f} m from the nearest lane"
            raise ValueError(
                f"stations[{sid!r}] at {(x, y)!r} is {gap}, more than station_snap_m = {snap_m} m"
            )
        _, index, t = best
        a, b, _ = stretches[index]
        (ax, ay), (bx, by) = positions[a], positions[b]
        length = math.hypot(bx - ax, by - ay)
        taken = [0.0, length] + [s for s, _ in stops.get(index, [])]
        if min(abs(t - s) for s in taken) < 1e-6:
            raise ValueError(
                f"stations[{sid!r}] at {(x, y)!r} falls on another node of lane {a}-{b}"
            )
        positions[sid] = (ax + (bx - ax) * t / length, ay + (by - ay) * t / length)
        stops.setdefault(index, []).append((t, sid))
    for marks in stops.values():
        marks.sort()
    return stops
