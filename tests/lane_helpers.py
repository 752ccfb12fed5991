"""Helpers for lane-graph and coordinator tests: small grids, a fake costmap, a driver."""

from __future__ import annotations

import itertools
import math

import numpy as np

from fleet.boxworld import BoxWorld, Warehouse
from mapserver.client import SegmentOut
from mapserver.core.costvalues import LETHAL
from planner.coordinator import LaneCoordinator
from planner.lane_graph import LaneGraph

SPACING = 3.0  # [m] between grid nodes


def grid_graph(nx_: int, ny_: int, one_way=(), spacing: float = SPACING, **kw) -> LaneGraph:
    """Nodes ``n{i}_{j}`` at (i, j) * spacing [m], lanes between 4-neighbours; ``kw`` as
    ``LaneGraph``'s."""
    pos = {f"n{i}_{j}": (i * spacing, j * spacing) for i in range(nx_) for j in range(ny_)}
    lanes = [(f"n{i}_{j}", f"n{i + 1}_{j}") for i in range(nx_ - 1) for j in range(ny_)]
    lanes += [(f"n{i}_{j}", f"n{i}_{j + 1}") for i in range(nx_) for j in range(ny_ - 1)]
    return LaneGraph(pos, lanes, one_way, **kw)


def pocket_graph() -> LaneGraph:
    """A corridor a - b - c (3 m lanes) with a pocket p off its middle node b::

    a - b - c
        |
        p
    """
    return LaneGraph(
        {"a": (0.0, 0.0), "b": (3.0, 0.0), "c": (6.0, 0.0), "p": (3.0, -3.0)},
        [("a", "b"), ("b", "c"), ("b", "p")],
    )


def warehouse_graph(nx_: int, ny_: int, segment_m: float | None = None, one_way=()) -> LaneGraph:
    """``LaneGraph.from_warehouse`` of an empty floor with lane lines every SPACING [m]."""
    xs = tuple(SPACING * (i + 1) for i in range(nx_))
    ys = tuple(SPACING * (j + 1) for j in range(ny_))
    floor = Warehouse(BoxWorld(np.zeros((0, 4))), SPACING * (nx_ + 1), SPACING * (ny_ + 1), xs, ys)
    return LaneGraph.from_warehouse(floor, one_way=one_way, segment_m=segment_m)


class FakeMap:
    """``query_segments`` over obstacle points and per-segment readings, counting calls.

    A segment is blocked when an obstacle lies within 0.05 m of it; ``first_blocked`` is
    the obstacle met first from the segment's start and ``max_cost`` is then LETHAL.
    ``readings[{(x0, y0), (x1, y1)}] = (max_cost, unknown_fraction)`` sets the rest.
    """

    def __init__(self) -> None:
        self.obstacles: list[tuple[float, float]] = []
        self.readings: dict[frozenset, tuple[int | None, float]] = {}
        self.calls: list[list] = []

    def set_reading(self, a, b, max_cost: int | None, unknown: float) -> None:
        self.readings[frozenset((tuple(a), tuple(b)))] = (max_cost, unknown)

    def query_segments(self, segments):
        self.calls.append([tuple(s) for s in segments])
        out = []
        for x0, y0, x1, y1 in segments:
            length = math.hypot(x1 - x0, y1 - y0)
            hits = []
            for ox, oy in self.obstacles:
                t = ((ox - x0) * (x1 - x0) + (oy - y0) * (y1 - y0)) / length
                px, py = x0 + (x1 - x0) * t / length, y0 + (y1 - y0) * t / length
                if -1e-9 <= t <= length + 1e-9 and math.hypot(ox - px, oy - py) <= 0.05:
                    hits.append((t, (ox, oy)))
            cost, unknown = self.readings.get(frozenset(((x0, y0), (x1, y1))), (0, 0.0))
            first = min(hits)[1] if hits else None
            out.append(
                SegmentOut(
                    max_cost=int(LETHAL) if hits else cost,
                    blocked=bool(hits),
                    unknown_fraction=unknown,
                    first_blocked=first,
                )
            )
        return out


def claims(coord: LaneCoordinator) -> tuple[dict, dict]:
    """What each unit's state says it must hold: node -> [units], lane -> [(unit, tail)]."""
    nodes: dict[str, list[str]] = {}
    lanes: dict[tuple[str, str], list[tuple[str, str]]] = {}
    for uid in coord.unit_ids:
        st = coord.status(uid)
        for n in st.behind_nodes:
            nodes.setdefault(n, []).append(uid)
        for lane in st.behind_lanes:  # driven past, still under the unit's body
            lanes.setdefault(lane, []).append((uid, None))
        if st.edge is None:
            nodes.setdefault(st.node, []).append(uid)
            continue
        tail, head = st.edge  # the head is reserved at the grant, the tail until left
        for n in (head, tail) if st.holds_tail else (head,):
            nodes.setdefault(n, []).append(uid)
        lanes.setdefault(tuple(sorted(st.edge)), []).append((uid, tail))
    return nodes, lanes


def check_no_conflicts(coord: LaneCoordinator, positions: dict, min_gap: float) -> None:
    """No node claimed by two units, no lane by two, the table agrees, units apart."""
    nodes, lanes = claims(coord)
    for node, units in nodes.items():
        assert len(units) == 1, f"node {node} claimed by {units}"
        assert coord.holder(node) == units[0], f"node {node}: table says {coord.holder(node)}"
    held = {r.resource for r in coord.reservations() if r.kind == "node"}
    assert held == set(nodes), f"held but unclaimed: {held - set(nodes)}"
    table = {r.resource: (r.unit, r.tail) for r in coord.reservations() if r.kind == "lane"}
    assert set(table) == set(lanes), f"lanes held but unclaimed: {set(table) - set(lanes)}"
    for lane, holders in lanes.items():
        assert len(holders) == 1, f"lane {lane} held by {holders}"
        unit, tail = holders[0]
        assert table[lane][0] == unit and tail in (None, table[lane][1]), (
            f"lane {lane}: table says {table[lane]}"
        )
    for a, b in itertools.combinations(sorted(positions), 2):
        (ax, ay), (bx, by) = positions[a], positions[b]
        assert math.hypot(ax - bx, ay - by) >= min_gap, (
            f"{a} and {b} at {positions[a]}, {positions[b]}"
        )


class Drive:
    """Units driven by the coordinator: each tick they move ``speed * dt`` along the lanes
    toward their status ``target`` (through its ``passing`` nodes first), report
    positions, and the no-conflict invariants are checked. ``moved[uid]``: [m] how far
    each unit moved on each tick."""

    def __init__(self, coord: LaneCoordinator, dt: float = 0.5, speed: float = 1.0) -> None:
        self.coord, self.dt, self.speed = coord, dt, speed
        self.positions: dict[str, tuple[float, float]] = {}
        self.now = 0.0
        self.min_gap = coord.settings.clear_m - coord.settings.arrive_tol - 1e-9
        self.moved: dict[str, list[float]] = {}

    def add(self, uid: str, start: str, goal: str, priority: float = 0.0) -> None:
        self.coord.request(uid, start, goal, priority, self.now)
        self.positions.setdefault(uid, self.coord.graph.position(start))

    def step(self) -> list:
        self.now += self.dt
        for uid in self.coord.unit_ids:
            status = self.coord.status(uid)
            via = [*status.passing, status.target] if status.target is not None else []
            budget = self.speed * self.dt
            while via and budget > 1e-12:
                (x, y), (tx, ty) = self.positions[uid], self.coord.graph.position(via[0])
                gap = math.hypot(tx - x, ty - y)
                move = min(gap, budget)
                if gap > 0:
                    self.positions[uid] = (x + (tx - x) * move / gap, y + (ty - y) * move / gap)
                budget -= move
                if move < gap or len(via) == 1:
                    break
                via.pop(0)
            self.moved.setdefault(uid, []).append(self.speed * self.dt - budget)
        decisions = self.coord.tick(self.now, self.positions)
        self.check()
        return decisions

    def check(self) -> None:
        check_no_conflicts(self.coord, self.positions, self.min_gap)

    def run(self, max_ticks: int) -> int | None:
        """Step until every unit is idle; the number of ticks, or None if it never was."""
        for k in range(1, max_ticks + 1):
            self.step()
            if all(self.coord.status(u).state == "idle" for u in self.coord.unit_ids):
                return k
        return None
