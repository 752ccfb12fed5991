"""The lane coordinator's reservation table: who holds which node, lane and corridor.

A reservation table in the sense of Silver, *Cooperative Pathfinding* (AIIDE 2005):
resources keyed to time windows, claimed before use so that units never plan into each
other. Here the resources are those of a ``LaneGraph``:

- a node: at most one holder;
- a lane (an undirected lane key): at most one holder, with the node it drives away
  from (``tail``), so never driven both ways at once;
- a corridor (``LaneGraph.corridors``): any number of units claim it, each along a
  heading (+1 along the corridor's node order, -1 against it).

A window opens when a resource is taken and closes when it is released; both are
events the caller drives (grants and the units' reported progress), so windows never
close by the clock. ``expected_end`` is the nominal close at the table's speed, kept to
explain a schedule, and a window stays open past it as long as its holder is there.
The table does not decide who may go: ``blockers`` says who is in the way, and the
coordinator decides.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from planner.lane_graph import Lane, LaneGraph, lane_key


@dataclass(frozen=True)
class Reservation:
    """An open window: ``unit`` holds a resource since ``start`` [s].

    kind: "node", "lane" or "corridor"; resource: the node id, the lane key or the index
    into ``LaneGraph.corridors``; tail: for a lane, the node its holder drives away from,
    for a corridor the end it drives away from (None for nodes); expected_end [s]: the
    nominal end at the table's speed (``inf`` when not known: a parked unit, a corridor).
    """

    unit: str
    kind: str
    resource: str | Lane | int
    tail: str | None
    start: float
    expected_end: float


@dataclass(slots=True)
class _Hold:
    unit: str
    start: float
    expected_end: float
    tail: str | None = None


def unit_order(unit_id: str) -> tuple[object, ...]:
    """Natural sort key of a unit id: digit runs compare as numbers ("u9" < "u10")."""
    return tuple(int(p) if i % 2 else p for i, p in enumerate(re.split(r"(\d+)", unit_id)))


class ReservationTable:
    """Node, lane and corridor reservations on ``graph``.

    speed [m/s]: nominal speed for ``expected_end``; clear_m [m]: distance a unit drives
    to clear a node it leaves (for ``expected_end`` only).
    """

    def __init__(self, graph: LaneGraph, speed: float, clear_m: float) -> None:
        self.graph = graph
        self.speed = speed
        self.clear_m = clear_m
        self._nodes: dict[str, _Hold] = {}
        self._lanes: dict[Lane, _Hold] = {}
        self._claims: dict[int, dict[int, set[str]]] = {}  # corridor -> heading -> units
        self._claim_of: dict[str, tuple[int, int, float]] = {}  # unit -> corridor, heading, since

    # -- questions

    def holder(self, node: str) -> str | None:
        """The unit holding ``node``, if any."""
        hold = self._nodes.get(node)
        return None if hold is None else hold.unit

    def nodes_of(self, unit: str) -> set[str]:
        """The nodes ``unit`` holds."""
        return {n for n, h in self._nodes.items() if h.unit == unit}

    def blockers(self, unit: str, cur: str, nxt: str) -> tuple[str, ...]:
        """Other units in the way of ``unit`` taking edge (cur, nxt) now, in natural order:
        the holders of node ``nxt`` and of lane {cur, nxt}, and every unit claiming the
        lane's corridor the other way."""
        found: set[str] = set()
        d = self.graph.graph.edges[cur, nxt]
        claims = self._claims.get(d["corridor"])
        if claims:
            found.update(o for o in claims.get(-d["heading"], ()) if o != unit)
        for hold in (self._nodes.get(nxt), self._lanes.get(lane_key(cur, nxt))):
            if hold is not None and hold.unit != unit:
                found.add(hold.unit)
        return tuple(sorted(found, key=unit_order))

    def claim_of(self, unit: str) -> tuple[int, int, float] | None:
        """``unit``'s corridor claim: (corridor, heading, since [s]), or None."""
        return self._claim_of.get(unit)

    def claimants(self, corridor: int, heading: int) -> set[str]:
        """The units claiming ``corridor`` along ``heading`` (+1 / -1)."""
        return set(self._claims.get(corridor, {}).get(heading, ()))

    def snapshot(self) -> list[Reservation]:
        """Every open window: nodes by id, lanes by key, corridor claims by corridor."""
        ends = self.graph.corridors
        return (
            [
                Reservation(h.unit, "node", n, None, h.start, h.expected_end)
                for n, h in sorted(self._nodes.items())
            ]
            + [
                Reservation(h.unit, "lane", k, h.tail, h.start, h.expected_end)
                for k, h in sorted(self._lanes.items())
            ]
            + [
                Reservation(u, "corridor", c, ends[c][0 if h > 0 else -1], since, math.inf)
                for u, (c, h, since) in sorted(
                    self._claim_of.items(), key=lambda i: (i[1][0], unit_order(i[0]))
                )
            ]
        )

    # -- changes

    def take_node(self, unit: str, node: str, now: float, expected_end: float) -> None:
        """Open ``unit``'s window on ``node`` (the caller checked it is free)."""
        self._nodes[node] = _Hold(unit, now, expected_end)

    def expect_node(self, node: str, expected_end: float) -> None:
        """Re-estimate when ``node``'s window closes [s]."""
        self._nodes[node].expected_end = expected_end

    def release_node(self, unit: str, node: str) -> None:
        """Close ``unit``'s window on ``node`` (nothing if it does not hold it)."""
        hold = self._nodes.get(node)
        if hold is not None and hold.unit == unit:
            del self._nodes[node]

    def take_edge(self, unit: str, cur: str, nxt: str, now: float) -> None:
        """Open ``unit``'s windows for edge (cur, nxt): the lane, node ``nxt`` and the
        corridor's heading; the caller checked ``blockers`` is empty."""
        d = self.graph.graph.edges[cur, nxt]
        length = d["length"]
        self.claim(unit, d["corridor"], d["heading"], now)
        self._lanes[lane_key(cur, nxt)] = _Hold(unit, now, now + length / self.speed, cur)
        self._nodes[nxt] = _Hold(unit, now, now + (length + self.clear_m) / self.speed)
        self._nodes[cur].expected_end = now + self.clear_m / self.speed

    def reverse_lane(self, unit: str, tail: str, head: str, now: float, back_s: float) -> None:
        """``unit`` on edge (tail, head) turns back: it now drives the lane away from
        ``head``, holds ``tail`` (expected in ``back_s`` [s]) and no longer ``head``."""
        self._lanes[lane_key(tail, head)].tail = head
        if self.holder(tail) != unit:
            self._nodes[tail] = _Hold(unit, now, now + back_s)
        self.release_node(unit, head)

    def release_lane(self, unit: str, a: str, b: str) -> None:
        """Close ``unit``'s window on lane {a, b} (nothing if it does not hold it)."""
        key = lane_key(a, b)
        hold = self._lanes.get(key)
        if hold is not None and hold.unit == unit:
            del self._lanes[key]

    def claim(self, unit: str, corridor: int, heading: int, now: float) -> None:
        """``unit`` drives ``corridor`` along ``heading`` (+1 / -1) from ``now`` [s]."""
        mine = self._claim_of.get(unit)
        if mine is not None and mine[:2] == (corridor, heading):
            return
        self.unclaim(unit)
        self._claims.setdefault(corridor, {}).setdefault(heading, set()).add(unit)
        self._claim_of[unit] = (corridor, heading, now)

    def claim_reverse(self, unit: str, tail: str, head: str, now: float) -> None:
        """``unit`` on edge (tail, head) will drive back: claim its corridor the other way
        (the edge may be the only one of a one-way lane)."""
        edges = self.graph.graph.edges
        if (tail, head) in edges:
            d, heading = edges[tail, head], -edges[tail, head]["heading"]
        else:
            d, heading = edges[head, tail], edges[head, tail]["heading"]
        self.claim(unit, d["corridor"], heading, now)

    def restore_claim(self, unit: str, claim: tuple[int, int, float] | None) -> None:
        """Put back a claim ``claim_of(unit)`` returned (None: no claim)."""
        self.unclaim(unit)
        if claim is not None:
            corridor, heading, since = claim
            self.claim(unit, corridor, heading, since)

    def unclaim(self, unit: str) -> None:
        """``unit`` no longer drives a corridor."""
        mine = self._claim_of.pop(unit, None)
        if mine is None:
            return
        corridor, heading, _ = mine
        units = self._claims[corridor][heading]
        units.discard(unit)
        if not units:
            del self._claims[corridor][heading]
            if not self._claims[corridor]:
                del self._claims[corridor]
