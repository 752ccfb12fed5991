"""The lane coordinator: which unit may drive which lane, when, and why it may not.

Reservations (``planner.reservations``: Silver's reservation table, windows opened by
grants and closed by the units' reported progress). Grants are made just in time, one
edge at a time, because the units' real timing is uncertain; a window is only ever
opened on a resource nobody else holds.

- A unit at a node holds that node, from the moment it claims it until it has left.
- To drive edge (u, v) a unit must be granted it: the lane {u, v} must be free (a lane
  has one holder, so it is never driven both ways at once), node v must be free, and no
  other unit may be driving the lane's corridor (``LaneGraph.corridors``: the chain of
  lanes through the waypoints of one aisle stretch) the other way. The grant reserves
  the lane and node v, so a unit on a lane can always enter its head (nobody stops on a
  lane for want of a node), and claims the corridor in its direction until the unit
  leaves it at one of its ends or stands still in it (parked, or with no route). Units
  thus follow one another through a corridor but never meet head-on inside it, where
  neither could give way.
- Do not block the box: a unit only passing through a *crossing* (a junction joining
  three or more lanes) must also be able to take the edge out of it when it is granted
  the edge in, so it never stops inside the crossing.
- The unit keeps node u until its position is more than ``clear_m`` [m] from it (its body
  has left the node), and the lane until it is within ``arrive_tol`` [m] of v. A unit
  that reaches its goal parks there, holding the node, until its next task.
- Each tick, units at a node ask for their next edge in the order (higher priority,
  longer wait, unit id). A unit that cannot have it waits, and the coordinator records
  whom it waits for.

At most one unit is on a lane at a time (the head-node reservation): split long lanes
with waypoints (``LaneGraph.from_warehouse(segment_m=...)``) so units can follow one
another. The only time a corridor is claimed both ways is while units turn back from a
lane that became blocked (below): the turning unit claims the way back at once, so that
the units following it may turn too.

Standing units. A unit whose way is held by a unit standing still (parked, or with no
route) does not wait for it forever: the standing unit is moved aside to a free
neighbour off the waiting unit's route, or pushed on along it (never back toward the
waiting unit), or, with no free neighbour, one of its own standing neighbours is moved
first; an idle unit moved aside parks where it is moved to. Failing that, the waiting
unit takes a route around every parked unit if one exists. Either is tried when the
wait starts and every ``retry_s`` [s].

Deadlocks. Waits form a wait-for graph (unit -> the units holding what it needs); a
cycle in it is a deadlock (Coffman, Elphick and Shoshani, *System Deadlocks*, ACM
Computing Surveys 3(2), 1971; Holt, *Some Deadlock Properties of Computer Systems*, ACM
Computing Surveys 4(3), 1972). After the tick's grants the coordinator finds cycles
with ``networkx.find_cycle``, one at a time, and breaks each. The unit that gives way is
the lowest-priority unit of the cycle standing at a node (ties: the larger unit id, in
natural order, so "u10" > "u9"). It is

1. rerouted: a route to its goal around the nodes held by the unit it waits for, or
   else around its contested next edge and node (never around its own goal), if the
   first step of that route can be granted now;
2. else backed off: to the nearest node within ``BACK_OFF_HOPS`` edges, over edges it
   could be granted now, where it may stop (not a crossing), preferring one off the
   route of the unit waiting for it, then the node it came from; it replans from there;
3. else the next unit of the cycle is tried. A cycle nobody can leave is recorded once
   as an unresolved wait and tried again every ``retry_s`` [s].

Blocked lanes. ``refresh(now)`` re-reads the costmap through the injected client
(``LaneGraph.refresh``: one ``POST /v1/query/segments``). For every lane newly blocked:

- a unit on the lane that is already past the blocked stretch (its position along the
  lane beyond the far end of the block) carries on to the lane's head and is rerouted
  from there;
- any other unit on the lane turns back to the node it came from, driving the lane in
  reverse (even a one-way lane: an emergency move, on a lane it holds alone); if that
  node has been taken meanwhile it stops where it is ("stranded") and waits for it. A
  unit whose position was never reported counts as still at the lane's start;
- every unit whose remaining route uses a blocked lane is rerouted from its node (or
  from its edge's head); with no route it waits at its node until a refresh changes the
  graph.

Decisions. Every route, grant, wait, reroute, back-off and arrival is a ``Decision`` with
its ``cause`` (a short code) and a sentence (``detail``), kept in ``log``: a replay can
explain each move. A wait is recorded when it starts and whenever what the unit waits
for changes, not on every tick.

Determinism: units are visited in natural unit-id order (or the grant order above),
nodes and lanes in sorted order; ``now`` is an argument, never the wall clock.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import networkx as nx

from planner.lane_graph import Lane, LaneGraph, SegmentQuerier, lane_key
from planner.reservations import Reservation, ReservationTable, unit_order

BACK_OFF_HOPS = 3
"""How far [edges] a deadlocked unit looks for a place to back off to."""

ACTIONS = ("route", "grant", "wait", "reroute", "back_off", "arrived")
"""Decision actions: a new task's route, an edge granted, a wait, a changed route, a
deadlock back-off (grants the back-off edge), arrival at the goal."""


@dataclass(frozen=True)
class Decision:
    """One coordinator decision about one unit, at ``time`` [s].

    action: one of ``ACTIONS``. cause: a short code: ``request`` (a new task), ``route``
    (the next edge of the route), ``node_held``, ``lane_held`` (the lane or its corridor),
    ``exit_held`` (the way out of a crossing), ``clear_way`` (moved aside for a waiting
    unit), ``parked_unit`` (rerouted around standing units), ``deadlock``,
    ``deadlock_unresolved``, ``lane_blocked``, ``no_route``, ``lane_cleared``, ``goal``;
    detail: the same in words. edge: the edge granted, asked for or reversed onto;
    waiting_for: the units it waits for (for a deadlock, every unit of the cycle);
    route: the unit's route after the decision.
    """

    time: float
    unit: str
    action: str
    cause: str
    detail: str
    edge: tuple[str, str] | None = None
    waiting_for: tuple[str, ...] = ()
    route: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, object]:
        """Plain JSON-ready form."""
        return {
            "time": self.time,
            "unit": self.unit,
            "action": self.action,
            "cause": self.cause,
            "detail": self.detail,
            "edge": list(self.edge) if self.edge else None,
            "waiting_for": list(self.waiting_for),
            "route": list(self.route),
        }


@dataclass(frozen=True)
class UnitStatus:
    """A unit as the coordinator sees it.

    state: "idle" (parked at its goal), "waiting" (at a node, its next edge not granted),
    "no_route" (at a node, no route to its goal), "moving" (on a granted edge) or
    "stranded" (stopped on a blocked lane, waiting to turn back). node: the node it stands
    at (None on a lane). edge: the edge it holds (tail, head) when on a lane. target: the
    node to drive to now (None: stand still). holds_tail: it still holds the edge's tail.
    route: the remaining nodes, from its node or from its edge's tail. behind_nodes,
    behind_lanes: what it still holds of the edges it was granted past while driving them
    (reserving ahead), in driving order; passing: the nodes it drives through before
    ``target``, in order.
    """

    unit: str
    state: str
    node: str | None
    edge: tuple[str, str] | None
    target: str | None
    holds_tail: bool
    goal: str
    route: tuple[str, ...]
    waiting_for: tuple[str, ...]
    priority: float
    behind_nodes: tuple[str, ...] = ()
    behind_lanes: tuple[Lane, ...] = ()
    passing: tuple[str, ...] = ()


@dataclass(slots=True)
class _Unit:
    uid: str
    order: tuple[object, ...]
    priority: float
    goal: str
    route: list[str]
    edge: tuple[str, str] | None = None
    tail_held: bool = False
    turn_back: bool = False
    pos: tuple[float, float] | None = None
    prev: str | None = None
    waiting: tuple[str, ...] = ()
    wait_since: float = 0.0
    retry_at: float = -math.inf
    plan_version: int = -1
    behind: list[_Behind] = field(default_factory=list)


@dataclass(slots=True)
class _Behind:
    """An edge a unit was granted past while still driving it (reserving ahead): what
    of it the unit still holds until its body has left it."""

    tail: str
    head: str
    tail_held: bool
    lane_held: bool = True


@dataclass
class _Tick:
    now: float
    out: list[Decision] = field(default_factory=list)


class LaneCoordinator:
    """Grants lanes to units on ``graph`` (module docstring).

    client: what ``refresh`` reads the costmap through (``MapClient`` or anything with its
    ``query_segments``); None if the map is never read. speed [m/s]: nominal driving speed
    for ``expected_end``. clear_m [m]: distance from a node beyond which a leaving unit
    releases it (at least the unit's length). arrive_tol [m]: distance from an edge's head
    at which the unit has arrived. retry_s [s]: how often a unit held up by a standing
    unit, or an unresolved deadlock, tries again to get out of it. reserve_ahead_m [m]:
    a unit this close to its edge's head is granted its next edge already, if it is free,
    so it drives on without stopping (0: only once it has arrived; see *Reserving
    ahead* in the module docstring).

    ``table`` is the reservation table; ``log`` every decision; ``deadlocks`` the number
    of wait-for cycles found.
    """

    def __init__(
        self,
        graph: LaneGraph,
        client: SegmentQuerier | None = None,
        *,
        speed: float = 1.0,
        clear_m: float = 1.0,
        arrive_tol: float = 0.1,
        retry_s: float = 1.0,
        reserve_ahead_m: float = 0.0,
    ) -> None:
        for name, value in (
            ("speed", speed),
            ("clear_m", clear_m),
            ("arrive_tol", arrive_tol),
            ("retry_s", retry_s),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        if not (math.isfinite(reserve_ahead_m) and reserve_ahead_m >= 0):
            raise ValueError(
                f"reserve_ahead_m must be a finite number >= 0, got {reserve_ahead_m!r}"
            )
        self.reserve_ahead_m = float(reserve_ahead_m)
        self.graph = graph
        self.client = client
        self.speed = float(speed)
        self.clear_m = float(clear_m)
        self.arrive_tol = float(arrive_tol)
        self.retry_s = float(retry_s)
        self.log: list[Decision] = []
        self.deadlocks = 0
        """Deadlocks detected (a cycle counts once while it persists)."""
        self._units: dict[str, _Unit] = {}
        self._sorted: list[_Unit] = []
        self.table = ReservationTable(graph, self.speed, self.clear_m)
        self._parked: dict[str, str] = {}  # node -> idle unit parked there
        self._ends = graph.corridor_ends
        self._crossings = graph.crossings
        self._xy = {n: graph.graph.nodes[n]["pos"] for n in graph.nodes}
        self._cycles: dict[tuple[str, ...], float] = {}  # unresolved cycle -> next attempt
        self._now = -math.inf

    # ------------------------------------------------------------------ queries

    @property
    def unit_ids(self) -> tuple[str, ...]:
        """Known units in natural id order."""
        return tuple(u.uid for u in self._sorted)

    def knows(self, unit_id: str) -> bool:
        """Has ``unit_id`` been given a task (it holds a node or a lane)?"""
        return unit_id in self._units

    def status(self, unit_id: str) -> UnitStatus:
        """What ``unit_id`` is doing (``UnitStatus``)."""
        u = self._unit(unit_id)
        if u.edge is not None:
            state, node = ("stranded" if u.turn_back else "moving"), None
            target = None if u.turn_back else u.edge[1]
        else:
            node, target = u.route[0], None
            if len(u.route) > 1:
                state = "waiting"
            else:
                state = "idle" if node == u.goal else "no_route"
        return UnitStatus(
            unit=u.uid,
            state=state,
            node=node,
            edge=u.edge,
            target=target,
            holds_tail=u.tail_held,
            goal=u.goal,
            route=tuple(u.route),
            waiting_for=u.waiting,
            priority=u.priority,
            behind_nodes=tuple(b.tail for b in u.behind if b.tail_held),
            behind_lanes=tuple(lane_key(b.tail, b.head) for b in u.behind if b.lane_held),
            passing=tuple(b.head for b in u.behind if b.lane_held),
        )

    def holder(self, node: str) -> str | None:
        """The unit holding ``node``, if any."""
        return self.table.holder(node)

    def reservations(self) -> list[Reservation]:
        """Every open window: nodes by id, lanes by key, corridor claims by corridor."""
        return self.table.snapshot()

    def wait_for(self) -> dict[str, tuple[str, ...]]:
        """The wait-for graph: each waiting unit -> the units it waits for."""
        return {u.uid: u.waiting for u in self._sorted if u.waiting}

    # ------------------------------------------------------------------ commands

    def request(
        self, unit_id: str, start_node: str, goal_node: str, priority: float, now: float
    ) -> list[Decision]:
        """Give ``unit_id`` a task: drive from ``start_node`` to ``goal_node``.

        A new unit appears at ``start_node``, which must be free. A known unit's
        ``start_node`` must be where it stands or, on a lane, the node it drives to (its
        edge's head; the tail when it is turning back): the route goes on from there.
        priority: larger wins deadlocks and goes first at contested nodes.
        """
        tick = self._begin(now)
        if not isinstance(unit_id, str) or not unit_id:
            raise ValueError(f"unit_id must be a non-empty string, got {unit_id!r}")
        self.graph.position(start_node)
        self.graph.position(goal_node)
        if isinstance(priority, bool) or not isinstance(priority, int | float):
            raise ValueError(f"priority must be a number, got {priority!r}")
        if not math.isfinite(priority):
            raise ValueError(f"priority must be finite, got {priority!r}")
        u = self._units.get(unit_id)
        if u is None:
            holder = self.table.holder(start_node)
            if holder is not None:
                raise ValueError(f"start_node {start_node!r} is held by unit {holder!r}")
            u = _Unit(unit_id, unit_order(unit_id), float(priority), goal_node, [start_node])
            self.table.take_node(unit_id, start_node, tick.now, math.inf)
            self._units[unit_id] = u
            self._sorted = sorted(self._units.values(), key=lambda v: v.order)
        else:
            expect = self._next_node(u)
            if start_node != expect:
                raise ValueError(
                    f"start_node {start_node!r} for unit {unit_id!r}: it stands at or drives "
                    f"to {expect!r}"
                )
            if self._parked.get(u.route[0]) == unit_id:
                del self._parked[u.route[0]]
            u.priority, u.goal = float(priority), goal_node
        u.waiting = ()
        if not u.turn_back:  # a unit turning back plans when it turns
            path = self._plan(start_node, goal_node)
            u.plan_version = self.graph.version
            u.route = ([u.route[0]] if u.edge else []) + (path or [start_node])
            if path is None:
                self._say(tick, u, "wait", "no_route", f"no route from {start_node} to {goal_node}")
            else:
                self._say(tick, u, "route", "request", f"task to {goal_node}")
        if u.edge is None and u.route == [goal_node]:
            self._park(tick, u)
        return self._end(tick)

    def tick(
        self, now: float, unit_positions: Mapping[str, tuple[float, float]] | None = None
    ) -> list[Decision]:
        """Advance to ``now`` [s]: take progress, grant edges, break deadlocks.

        unit_positions: unit id -> (x, y) [m] as the units report them; units not listed
        keep their last position, unknown ids are ignored. Returns this tick's decisions.
        """
        tick = self._begin(now)
        if unit_positions:
            for uid, xy in unit_positions.items():
                u = self._units.get(uid)
                if u is not None:
                    x, y = float(xy[0]), float(xy[1])
                    if not (math.isfinite(x) and math.isfinite(y)):
                        raise ValueError(f"unit_positions[{uid!r}] must be finite, got {xy!r}")
                    u.pos = (x, y)
        for u in self._sorted:
            if u.behind and u.pos is not None:
                self._release_behind(u)
            if u.edge is not None and u.pos is not None:
                self._progress(tick, u)
        ready = [u for u in self._sorted if (u.edge is None and len(u.route) > 1) or u.turn_back]
        ready.sort(key=lambda u: (-u.priority, u.wait_since if u.waiting else tick.now, u.order))
        for u in ready:
            if u.turn_back:
                self._turn_back(tick, u)
            else:
                self._ask(tick, u)
        self._break_deadlocks(tick)
        return self._end(tick)

    def refresh(self, now: float) -> list[Decision]:
        """Re-read the costmap (one segment query) and reroute around newly blocked lanes."""
        if self.client is None:
            raise ValueError("refresh needs a map client: LaneCoordinator(graph, client=None)")
        tick = self._begin(now)
        changes = self.graph.refresh(self.client)
        if changes.blocked:
            self._on_blocked(tick, set(changes.blocked))
        for u in self._sorted:  # units with no route try again on a changed graph
            if u.edge is None and len(u.route) == 1 and u.route[0] != u.goal:
                if u.plan_version != self.graph.version:
                    self._replan(tick, u, "lane_cleared", "the lane graph changed")
        return self._end(tick)

    # ------------------------------------------------------------------ progress

    def _progress(self, tick: _Tick, u: _Unit) -> None:
        """Release the tail once clear of it; arrive at the head when within tolerance."""
        assert u.edge is not None and u.pos is not None
        tail, head = u.edge
        x, y = u.pos
        if u.tail_held and not u.behind:  # a tail ahead of the unit is not left yet
            (tx, ty), (hx, hy) = self._xy[tail], self._xy[head]
            beyond = (x - tx) * (hx - tx) + (y - ty) * (hy - ty) > 0
            if beyond and math.hypot(x - tx, y - ty) > self.clear_m:
                self.table.release_node(u.uid, tail)
                u.tail_held = False
        hx, hy = self._xy[head]
        to_head = math.hypot(x - hx, y - hy)
        if u.turn_back:
            return
        if to_head > self.arrive_tol:
            if to_head <= self.reserve_ahead_m:
                self._reserve_ahead(tick, u)
            return
        for b in u.behind:  # arrived: every edge before this one is behind the body
            if b.lane_held:
                self.table.release_lane(u.uid, b.tail, b.head)
                b.lane_held = False
        self._release_behind(u)
        self.table.release_lane(u.uid, tail, head)
        self.table.release_node(u.uid, tail)
        u.edge, u.tail_held, u.prev = None, False, tail
        u.route.pop(0)
        if len(u.route) == 1:
            if head == u.goal:
                self._park(tick, u)
            else:  # no route onward: try again now (the graph may have changed)
                self._replan(tick, u, "no_route", f"reached {head} with no route to {u.goal}")
        if head in self._ends or len(u.route) == 1:
            self.table.unclaim(u.uid)  # out of the corridor, or standing in it

    def _reserve_ahead(self, tick: _Tick, u: _Unit) -> None:
        """Grant a unit near its edge's head the next edges of its route while each is
        free and its head is within ``reserve_ahead_m`` [m]; it keeps what it drives over
        until its body has left it (``_release_behind``)."""
        assert u.pos is not None
        edges = self.graph.graph.edges
        while u.edge is not None and len(u.route) > 2:
            tail, head = u.edge
            if math.dist(u.pos, self._xy[head]) > self.reserve_ahead_m:
                return
            rest = u.route[1:]
            chain = {tail, head, *(b.tail for b in u.behind)}
            if rest[1] in chain:  # the route comes back: drive up to the turn first
                return
            if edges[rest[0], rest[1]]["blocked"] or self._step_blockers(u.uid, rest):
                return
            u.behind.append(_Behind(tail, head, u.tail_held))
            u.route.pop(0)
            u.prev = tail
            self._grant(tick, u, rest[1], "grant", "route", f"{head} -> {rest[1]} (ahead)")

    def _release_behind(self, u: _Unit) -> None:
        """Release what a unit has driven past: the lanes before the one it is on now
        (the lane of its chain nearest to it, the later one on a tie: so a unit cutting
        a corner has left the first lane once nearer the second) and the nodes it is on
        or past and ``clear_m`` [m] from."""
        assert u.pos is not None
        chain = [(b.tail, b.head) for b in u.behind] + ([u.edge] if u.edge else [])
        gaps = [_segment_distance(u.pos, self._xy[a], self._xy[b]) for a, b in chain]
        on = min(range(len(chain)), key=lambda k: (gaps[k], -k))
        for k, b in enumerate(u.behind[: on + 1]):
            if b.tail_held and math.dist(u.pos, self._xy[b.tail]) > self.clear_m:
                self.table.release_node(u.uid, b.tail)
                b.tail_held = False
            if b.lane_held and k < on:
                self.table.release_lane(u.uid, b.tail, b.head)
                b.lane_held = False
        u.behind = [b for b in u.behind if b.tail_held or b.lane_held]

    def _park(self, tick: _Tick, u: _Unit) -> None:
        node = u.route[0]
        self._parked[node] = u.uid
        self.table.expect_node(node, math.inf)
        self._say(tick, u, "arrived", "goal", f"parked at its goal {node}")

    # ------------------------------------------------------------------ grants

    def _step_blockers(self, uid: str, route: list[str]) -> tuple[str, ...]:
        """Who stops ``uid`` taking the first edge of ``route`` now: the blockers of that
        edge and, if its head is a crossing the unit only passes through, of the edge out
        of it too (do not block the box: never stop inside a crossing)."""
        found = self.table.blockers(uid, route[0], route[1])
        if not found and len(route) > 2 and route[1] in self._crossings:
            found = self.table.blockers(uid, route[1], route[2])
        return found

    def _ask(self, tick: _Tick, u: _Unit) -> None:
        """A unit at a node asks for its next edge: grant, or wait (and maybe detour)."""
        cur, nxt = u.route[0], u.route[1]
        if self.graph.graph.edges[cur, nxt]["blocked"]:
            self._replan(tick, u, "lane_blocked", f"lane {cur}-{nxt} is blocked")
            if len(u.route) < 2:
                return
            cur, nxt = u.route[0], u.route[1]
        blockers = self._step_blockers(u.uid, u.route)
        if not blockers:
            self._grant(tick, u, nxt, "grant", "route", f"{cur} -> {nxt}")
            return
        changed = blockers != u.waiting
        standing = [self._units[b] for b in blockers if self._standing(self._units[b])]
        if standing and (changed or tick.now >= u.retry_at):
            u.retry_at = tick.now + self.retry_s
            if self._clear_way(tick, u, standing):
                changed = changed or not u.waiting
            else:
                avoid = set() if nxt == u.goal else {nxt}
                detail = f"{nxt} is held by standing unit(s) {', '.join(blockers)}"
                if self._detour(
                    tick, u, {(cur, nxt)}, avoid, "parked_unit", detail, blockers, strict=True
                ):
                    return
        if not changed:
            return
        if not u.waiting:
            u.wait_since = tick.now
        u.waiting = blockers
        who = ", ".join(blockers)
        holder = self.table.holder(nxt)
        if holder is not None and holder != u.uid:
            cause, detail = "node_held", f"node {nxt} is held by {holder}"
        elif self.table.blockers(u.uid, cur, nxt):
            cause, detail = "lane_held", f"lane {cur}-{nxt} or its corridor is held by {who}"
        else:
            cause, detail = "exit_held", f"the way out of crossing {nxt} is held by {who}"
        self._say(tick, u, "wait", cause, detail, edge=(cur, nxt), waiting_for=blockers)

    def _clear_way(self, tick: _Tick, w: _Unit, standing: list[_Unit]) -> bool:
        """Move standing units out of ``w``'s way, each to a free neighbour.

        Off w's route, or else further along it (a push: w meets the unit again one node
        on and pushes it on until it can step off); never back toward w, which would only
        swap the two places. A unit with no free neighbour has one of its standing
        neighbours (off w's route) moved aside first, to be moved itself on a later try:
        a push two deep. An idle unit parks where it is moved to (that becomes its goal:
        its task was done, the next one is the caller's to give); a unit with no route
        keeps its goal. True if a unit moved.
        """
        on_route = {n: i for i, n in enumerate(w.route)}
        moved = False
        for p in standing:
            here = on_route.get(p.route[0], len(on_route))
            behind = {n for n, i in on_route.items() if i <= here}  # back toward w
            if self._move_aside(tick, p, behind, set(on_route), w.uid):
                moved = True
                continue
            for q_node in sorted(self.graph.graph.successors(p.route[0])):
                holder = self.table.holder(q_node)
                q = self._units[holder] if holder is not None else None
                if q is None or q_node in on_route or q is w or not self._standing(q):
                    continue
                if self._move_aside(tick, q, set(on_route) | {p.route[0]}, set(), w.uid):
                    moved = True
                    break
        return moved

    def _move_aside(
        self, tick: _Tick, p: _Unit, never: set[str], rather_not: set[str], for_uid: str
    ) -> bool:
        """Grant standing unit ``p`` the edge to a free neighbour not in ``never``.

        Preference: not in ``rather_not``, not a crossing, not a moving or waiting unit's
        goal, then edge weight and node id.
        """
        node = p.route[0]
        edges = self.graph.graph.edges
        options = [
            m
            for m in self.graph.graph.successors(node)
            if m not in never
            and not edges[node, m]["blocked"]
            and not self.table.blockers(p.uid, node, m)
        ]
        if not options:
            return False
        goals = {u.goal for u in self._sorted if not self._standing(u)}
        step = min(
            options,
            key=lambda m: (
                m in rather_not,
                m in self._crossings,
                m in goals,
                edges[node, m]["weight"],
                m,
            ),
        )
        if self._parked.get(node) == p.uid:
            del self._parked[node]
            p.goal = step
        p.route = [node, step]
        detail = f"standing at {node}, moving aside to {step} for {for_uid}"
        self._grant(tick, p, step, "back_off", "clear_way", detail, (for_uid,))
        return True

    def _grant(
        self,
        tick: _Tick,
        u: _Unit,
        nxt: str,
        action: str,
        cause: str,
        detail: str,
        waiting_for: tuple[str, ...] = (),
    ) -> None:
        """Open the windows of edge (node, nxt) for ``u``; the caller checked they are free."""
        cur = u.route[0]
        self.table.take_edge(u.uid, cur, nxt, tick.now)
        u.edge, u.tail_held = (cur, nxt), True
        u.waiting = ()
        self._say(tick, u, action, cause, detail, edge=(cur, nxt), waiting_for=waiting_for)

    def _detour(
        self,
        tick: _Tick,
        u: _Unit,
        avoid_edges: set[tuple[str, str]],
        avoid_nodes: set[str],
        cause: str,
        detail: str,
        waiting_for: tuple[str, ...],
        strict: bool = False,
    ) -> bool:
        """Reroute a waiting unit avoiding edges and nodes, if its new first step is free now.

        strict: only a route that avoids every parked unit will do.
        """
        cur = u.route[0]
        path = self._plan(cur, u.goal, avoid_edges, avoid_nodes - {u.goal}, strict)
        if path is None or len(path) < 2 or self._step_blockers(u.uid, path):
            return False
        u.route = path
        self._say(tick, u, "reroute", cause, detail, waiting_for=waiting_for)
        self._grant(tick, u, path[1], "grant", cause, f"{cur} -> {path[1]} (detour)")
        return True

    def _back_off(
        self, tick: _Tick, u: _Unit, behind: _Unit, detail: str, waiting_for: tuple[str, ...]
    ) -> bool:
        """Move aside to the nearest free place to stop, then replan from there.

        Searches breadth-first, up to ``BACK_OFF_HOPS`` edges, over edges ``u`` could be
        granted now, for a node that is not a crossing. Preference: fewest hops, then off
        the route of ``behind`` (the unit of the cycle waiting for ``u``), then the node
        ``u`` came from, then weight and node id. With no such node, any free neighbour
        other than the contested one will do.
        """
        cur, nxt = u.route[0], u.route[1]
        in_way = set(behind.route)
        edges = self.graph.graph.edges

        def free(a: str) -> list[str]:
            return [
                m
                for m in self.graph.graph.successors(a)
                if not edges[a, m]["blocked"] and not self.table.blockers(u.uid, a, m)
            ]

        def rank(path: list[str]) -> tuple[object, ...]:
            m = path[-1]
            return (m in in_way, m != u.prev, self.graph.route_length(path), m)

        paths = [[cur]]
        seen = {cur}
        best: list[str] | None = None
        for _ in range(BACK_OFF_HOPS):
            paths = [[*p, m] for p in paths for m in free(p[-1]) if m not in seen]
            seen.update(p[-1] for p in paths)
            stops = [p for p in paths if p[-1] not in self._crossings]
            if stops:
                best = min(stops, key=rank)
                break
        if best is None:
            near = [[cur, m] for m in free(cur) if m != nxt]
            if not near:
                return False
            best = min(near, key=rank)
        rest = self._plan(best[-1], u.goal, {(cur, nxt)}) or [best[-1]]
        u.route = [*best, *rest[1:]]
        self._grant(tick, u, best[1], "back_off", "deadlock", detail, waiting_for)
        return True

    # ------------------------------------------------------------------ deadlocks

    def _break_deadlocks(self, tick: _Tick) -> None:
        """Find wait-for cycles one at a time and make one unit of each give way."""
        waiting = [u for u in self._sorted if u.waiting]
        seen: dict[tuple[str, ...], float] = {}
        if len(waiting) >= 2:
            graph = nx.DiGraph()
            for u in waiting:
                graph.add_edges_from((u.uid, b) for b in u.waiting if self._units[b].waiting)
            while graph.number_of_edges():
                try:
                    cycle = [a for a, _ in nx.find_cycle(graph)]
                except nx.NetworkXNoCycle:
                    break
                members = tuple(sorted(cycle, key=unit_order))
                retry_at = self._cycles.get(members)
                if retry_at is None:
                    self.deadlocks += 1
                loser = None
                if retry_at is None or tick.now >= retry_at:
                    loser = self._give_way(tick, cycle, members)
                    retry_at = tick.now + self.retry_s
                if loser is None:
                    seen[members] = retry_at
                graph.remove_nodes_from([loser] if loser else cycle)
        self._cycles = seen

    def _give_way(self, tick: _Tick, cycle: list[str], members: tuple[str, ...]) -> str | None:
        """Reroute or back off the cycle's loser; returns who gave way, None if nobody can."""
        text = " -> ".join([*cycle, cycle[0]])
        units = [self._units[uid] for uid in cycle if self._units[uid].edge is None]
        units.sort(key=lambda u: u.order, reverse=True)  # larger id loses ties ...
        units.sort(key=lambda u: u.priority)  # ... among the lowest priority (stable sort)
        for u in units:
            cur, nxt = u.route[0], u.route[1]
            k = cycle.index(u.uid)
            ahead = self._units[cycle[(k + 1) % len(cycle)]]  # the one u waits for
            held = self.table.nodes_of(ahead.uid)
            detail = f"deadlock {text}: rerouting around {', '.join(sorted(held))}"
            if self._detour(tick, u, set(), held - {cur}, "deadlock", detail, members):
                return u.uid
            detail = f"deadlock {text}: rerouting around {cur} -> {nxt}"
            if self._detour(tick, u, {(cur, nxt)}, {nxt}, "deadlock", detail, members):
                return u.uid
            behind = self._units[cycle[k - 1]]
            detail = f"deadlock {text}: backing off from {cur}"
            if self._back_off(tick, u, behind, detail, members):
                return u.uid
        if members not in self._cycles:
            for uid in members:
                self._say(
                    tick,
                    self._units[uid],
                    "wait",
                    "deadlock_unresolved",
                    f"deadlock {text}: no unit can give way",
                    waiting_for=members,
                )
        return None

    # ------------------------------------------------------------------ blocked lanes

    def _on_blocked(self, tick: _Tick, blocked: set[Lane]) -> None:
        """Turn back, carry on or reroute every unit whose remaining route uses ``blocked``."""
        for u in self._sorted:
            if u.turn_back:
                continue  # it plans when it has turned back
            if u.edge is not None and lane_key(*u.edge) in blocked:
                self._on_blocked_lane(tick, u)
                continue
            start = 1 if u.edge is not None else 0
            rest = u.route[start:]
            hits = [lane_key(a, b) for a, b in zip(rest, rest[1:], strict=False)]
            hit = next((k for k in hits if k in blocked), None)
            if hit is not None:
                self._replan(tick, u, "lane_blocked", f"lane {hit[0]}-{hit[1]} is blocked")

    def _on_blocked_lane(self, tick: _Tick, u: _Unit) -> None:
        """A unit on a newly blocked lane: carry on if past the block, else turn back."""
        assert u.edge is not None
        tail, head = u.edge
        edges = self.graph.graph.edges
        if (tail, head) in edges:
            length, (near, far) = edges[tail, head]["length"], edges[tail, head]["block_span"]
        else:  # reversing a one-way lane: mirror the span of its only edge
            length, (n0, f0) = edges[head, tail]["length"], edges[head, tail]["block_span"]
            near, far = length - f0, length - n0
        s = 0.0
        if u.pos is not None:
            (tx, ty), (hx, hy) = self._xy[tail], self._xy[head]
            s = ((u.pos[0] - tx) * (hx - tx) + (u.pos[1] - ty) * (hy - ty)) / length
        where = f"{near:.2f}-{far:.2f} m along {tail} -> {head}"
        if s > far:
            self._replan(tick, u, "lane_blocked", f"blocked {where}, behind the unit: carrying on")
            return
        u.turn_back = True
        self.table.claim_reverse(u.uid, tail, head, tick.now)  # so followers may turn too
        self._say(
            tick,
            u,
            "reroute",
            "lane_blocked",
            f"blocked {where}, ahead of the unit at {s:.2f} m: turning back to {tail}",
            edge=(head, tail),
        )
        self._turn_back(tick, u)

    def _turn_back(self, tick: _Tick, u: _Unit) -> None:
        """Reverse onto the lane's tail if free, else wait for it where the unit stands."""
        assert u.edge is not None
        tail, head = u.edge
        holder = self.table.holder(tail)
        if holder is not None and holder != u.uid:
            if u.waiting != (holder,):
                u.wait_since = tick.now if not u.waiting else u.wait_since
                u.waiting = (holder,)
                self._say(
                    tick,
                    u,
                    "wait",
                    "lane_blocked",
                    f"stopped on blocked lane {tail}-{head}; {tail} is held by {holder}",
                    edge=(head, tail),
                    waiting_for=u.waiting,
                )
            return
        self.table.reverse_lane(u.uid, tail, head, tick.now, self._back_time(u))
        u.edge, u.tail_held, u.turn_back = (head, tail), False, False
        u.waiting = ()
        path = self._plan(tail, u.goal)
        u.plan_version = self.graph.version
        u.route = [head, *(path or [tail])]
        self._say(
            tick, u, "grant", "lane_blocked", f"reversing {head} -> {tail}", edge=(head, tail)
        )

    def _back_time(self, u: _Unit) -> float:
        """Nominal time [s] to drive back to the edge's tail from the unit's position."""
        assert u.edge is not None
        tx, ty = self._xy[u.edge[0]]
        x, y = u.pos if u.pos is not None else (tx, ty)
        return math.hypot(x - tx, y - ty) / self.speed

    # ------------------------------------------------------------------ routing

    def _plan(
        self,
        src: str,
        goal: str,
        avoid_edges: set[tuple[str, str]] | frozenset[tuple[str, str]] = frozenset(),
        avoid_nodes: set[str] | frozenset[str] = frozenset(),
        strict: bool = False,
    ) -> list[str] | None:
        """A route around parked units if there is one, else (unless strict) through them."""
        parked = {n for n in self._parked if n not in (src, goal)}
        if parked or strict:
            path = self.graph.shortest_route(src, goal, avoid_edges, parked | set(avoid_nodes))
            if path is not None or strict:
                return path
        return self.graph.shortest_route(src, goal, avoid_edges, avoid_nodes)

    def _replan(self, tick: _Tick, u: _Unit, cause: str, detail: str) -> None:
        """New route to the goal from the unit's node (or its edge's head, keeping the edge)."""
        keep = [u.route[0]] if u.edge is not None else []
        src = u.edge[1] if u.edge is not None else u.route[0]
        path = self._plan(src, u.goal)
        u.plan_version = self.graph.version
        u.waiting = ()
        if path is None:
            u.route = [*keep, src]
            self._say(tick, u, "wait", "no_route", f"{detail}; no route from {src} to {u.goal}")
        else:
            u.route = [*keep, *path]
            self._say(tick, u, "reroute", cause, detail)

    # ------------------------------------------------------------------ helpers

    def _begin(self, now: float) -> _Tick:
        if isinstance(now, bool) or not isinstance(now, int | float) or not math.isfinite(now):
            raise ValueError(f"now must be a finite number of seconds, got {now!r}")
        if now < self._now:
            raise ValueError(f"now must not go backwards: got {now!r} after {self._now!r}")
        self._now = float(now)
        return _Tick(float(now))

    def _end(self, tick: _Tick) -> list[Decision]:
        self.log.extend(tick.out)
        return tick.out

    def _say(
        self,
        tick: _Tick,
        u: _Unit,
        action: str,
        cause: str,
        detail: str,
        edge: tuple[str, str] | None = None,
        waiting_for: tuple[str, ...] = (),
    ) -> None:
        tick.out.append(
            Decision(tick.now, u.uid, action, cause, detail, edge, waiting_for, tuple(u.route))
        )

    @staticmethod
    def _standing(u: _Unit) -> bool:
        """At a node with nowhere to go: parked at its goal, or with no route."""
        return u.edge is None and len(u.route) == 1

    def _next_node(self, u: _Unit) -> str:
        """Where the unit stands, or the node it drives to."""
        if u.edge is None:
            return u.route[0]
        return u.edge[0] if u.turn_back else u.edge[1]

    def _unit(self, unit_id: str) -> _Unit:
        u = self._units.get(unit_id)
        if u is None:
            raise ValueError(f"unit_id {unit_id!r} is not known to the coordinator")
        return u


def _segment_distance(
    p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]
) -> float:
    """[m] from point ``p`` to the segment a-b."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / length2
    t = min(1.0, max(0.0, t))
    return math.hypot(p[0] - a[0] - t * dx, p[1] - a[1] - t * dy)
