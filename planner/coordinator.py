"""The lane coordinator: which unit may drive which lane, when, and why it may not.

Reservations (``planner.reservations``: Silver's reservation table, windows opened by
grants and closed by the units' reported progress). Grants are made just in time, one
edge at a time (or a few ahead of a moving unit: reserving ahead), because the units'
real timing is uncertain; a window is only ever opened on a resource nobody else holds.

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

At most one unit drives into a lane at a time (the head-node reservation): split long
lanes with waypoints (``LaneGraph.from_warehouse(segment_m=...)``) so units can follow
one another. The only time a corridor is claimed both ways is while units turn back
from a lane that became blocked (``policy_blocked_lanes``): the turning unit claims the
way back at once, so that the units following it may turn too.

The driver grants, tracks progress and keeps the log; each policy lives in a module
of its own, mixed into ``LaneCoordinator``:

- ``planner.policy_reserve_ahead``: granting the next lanes before a unit arrives;
- ``planner.policy_standing``: moving standing units out of a waiting unit's way;
- ``planner.policy_deadlocks``: finding and breaking wait-for cycles;
- ``planner.policy_blocked_lanes``: turning back or rerouting off lanes the costmap
  blocks;
- ``planner.policy_pibt``: with ``policy="pibt"``, units at nodes decide by priority
  inheritance with backtracking (Okumura et al., AIJ 2022) instead of the greedy
  grants above; the deadlock breaker stays as a safety net.

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

from planner.lane_graph import Lane, LaneGraph, SegmentQuerier, lane_key
from planner.policy_blocked_lanes import BlockedLanes
from planner.policy_deadlocks import Deadlocks
from planner.policy_pibt import Pibt
from planner.policy_reserve_ahead import Behind, ReserveAhead
from planner.policy_standing import StandingUnits
from planner.reservations import Reservation, ReservationTable, unit_order

POLICIES = ("reserve_ahead", "pibt")
"""Coordination policies: ``reserve_ahead`` (the default: a waiting unit is granted its
next edge as soon as it is free, units in priority order, and deadlocks are broken when
found) or ``pibt`` (``planner.policy_pibt``: priority inheritance with backtracking)."""

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
    since: float = 0.0
    behind: list[Behind] = field(default_factory=list)


@dataclass
class _Tick:
    now: float
    out: list[Decision] = field(default_factory=list)


class LaneCoordinator(ReserveAhead, StandingUnits, Deadlocks, BlockedLanes, Pibt):
    """Grants lanes to units on ``graph`` (module docstring).

    client: what ``refresh`` reads the costmap through (``MapClient`` or anything with its
    ``query_segments``); None if the map is never read. speed [m/s]: nominal driving speed
    for ``expected_end``. clear_m [m]: distance from a node beyond which a leaving unit
    releases it (at least the unit's length). arrive_tol [m]: distance from an edge's head
    at which the unit has arrived. retry_s [s]: how often a unit held up by a standing
    unit, or an unresolved deadlock, tries again to get out of it. reserve_ahead_m [m]:
    a unit this close to its edge's head is granted its next edge already, if it is free,
    so it drives on without stopping (0: only once it has arrived; see *Reserving
    ahead* in the module docstring). policy: one of ``POLICIES``: how units at nodes are
    granted their next edges.

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
        policy: str = "reserve_ahead",
    ) -> None:
        if policy not in POLICIES:
            raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
        self.policy = policy
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
        self._intents: dict[str, str] = {}  # pibt: node -> the waiting unit claiming it
        self._dist_cache: dict[str, tuple[int, dict[str, float]]] = {}  # pibt: goal -> ...

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
        u.since = tick.now
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
        if self.policy == "pibt":
            for u in ready:
                if u.turn_back:
                    self._turn_back(tick, u)
            self._pibt_round(tick, [u for u in ready if not u.turn_back])
            self._break_deadlocks(tick)
            return self._end(tick)
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
        claimant = self._intents.get(route[1])
        if (
            claimant is not None
            and claimant != uid
            and claimant not in found
            and self._units[claimant].edge is None
        ):
            found = (*found, claimant)  # pibt: a waiting unit claimed it
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
