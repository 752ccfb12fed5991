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

The driver (``LaneCoordinator``) takes requests and progress and keeps the log; the
policies decide, each an object behind ``planner.policy.CoordinationPolicy``, driven
in the order of the chosen set (``planner.policy_sets``), on the state they share
(``planner.coordination_state``):

- ``planner.policy_reserve_ahead``: granting the next lanes before a unit arrives;
- ``planner.policy_grants``: granting waiting units their next edges when free, and
  ``planner.policy_standing``: moving standing units out of a waiting unit's way;
- ``planner.policy_deadlocks``: finding and breaking wait-for cycles;
- ``planner.policy_blocked_lanes``: turning back or rerouting off lanes the costmap
  blocks;
- ``planner.policy_pibt``: with ``policy="pibt"``, units at nodes decide by priority
  inheritance with backtracking (Okumura et al., AIJ 2022) instead of the greedy
  grants above; the deadlock breaker stays as a safety net.

Decisions. Every route, grant, wait, reroute, back-off and arrival is a ``Decision``
(``planner.decisions``) with its ``Action``, its ``Cause`` and a sentence (``detail``),
kept in ``log``: a replay can explain each move. A wait is recorded when it starts and
whenever what the unit waits for changes, not on every tick.

Determinism: units are visited in natural unit-id order (or the grant order above),
nodes and lanes in sorted order; ``now`` is an argument, never the wall clock.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from planner.coordination_state import CoordinationState, CoordinatorSettings, Tick, Unit
from planner.decisions import ACTIONS, Action, Cause, Decision
from planner.lane_graph import Lane, LaneGraph, SegmentQuerier, lane_key
from planner.policy import make_policies
from planner.policy_sets import BUILT_IN  # registers the built-in policy sets
from planner.reservations import Reservation, ReservationTable, unit_order

__all__ = [
    "ACTIONS",
    "POLICIES",
    "Action",
    "Cause",
    "CoordinatorSettings",
    "Decision",
    "LaneCoordinator",
    "UnitStatus",
]

POLICIES = BUILT_IN
"""The built-in coordination policies: ``reserve_ahead`` (the default: a waiting unit is
granted its next edge as soon as it is free, units in priority order, and deadlocks are
broken when found) or ``pibt`` (``planner.policy_pibt``: priority inheritance with
backtracking). ``planner.policy.policy_names()`` adds any registered since."""


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


class LaneCoordinator:
    """Grants lanes to units on ``graph`` (module docstring): the driver of its policies.

    client: what ``refresh`` reads the costmap through (``MapClient`` or anything with its
    ``query_segments``); None if the map is never read. policy: a registered policy set
    (``planner.policy.policy_names``): how units are granted their next edges.
    settings: ``CoordinatorSettings``, or ``knobs``, its fields by name (``clear_m=1.2``;
    the rest default).

    ``state`` is what the policies share (``CoordinationState``): ``table`` is its
    reservation table, ``log`` every decision, ``deadlocks`` the number of wait-for
    cycles found; ``policies`` the set's policies in driving order.
    """

    def __init__(
        self,
        graph: LaneGraph,
        client: SegmentQuerier | None = None,
        *,
        policy: str = POLICIES[0],
        settings: CoordinatorSettings | None = None,
        **knobs: float,
    ) -> None:
        if settings is not None and knobs:
            raise ValueError(f"give settings or {', '.join(sorted(knobs))}, not both")
        if settings is None:
            settings = CoordinatorSettings(**knobs)
        self.policies = make_policies(policy, settings)
        self.policy = policy
        self.settings = settings
        self.graph = graph
        self.client = client
        self.state = CoordinationState(graph, settings)
        self._now = -math.inf

    @property
    def table(self) -> ReservationTable:
        """The reservation table (``planner.reservations.ReservationTable``)."""
        return self.state.table

    @property
    def log(self) -> list[Decision]:
        """Every decision so far, in order."""
        return self.state.log

    @property
    def deadlocks(self) -> int:
        """Deadlocks detected (a cycle counts once while it persists)."""
        return self.state.deadlocks

    # ------------------------------------------------------------------ queries

    @property
    def unit_ids(self) -> tuple[str, ...]:
        """Known units in natural id order."""
        return tuple(u.uid for u in self.state.sorted)

    def knows(self, unit_id: str) -> bool:
        """Has ``unit_id`` been given a task (it holds a node or a lane)?"""
        return unit_id in self.state.units

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

    def start_node(self, unit_id: str) -> str | None:
        """The node ``unit_id`` stands at or, on a lane, drives to now: ``status``'s
        ``node or target`` (None while it waits to turn back on a blocked lane), without
        building the whole status."""
        u = self._unit(unit_id)
        if u.edge is None:
            return u.route[0]
        return None if u.turn_back else u.edge[1]

    def holder(self, node: str) -> str | None:
        """The unit holding ``node``, if any."""
        return self.state.table.holder(node)

    def reservations(self) -> list[Reservation]:
        """Every open window: nodes by id, lanes by key, corridor claims by corridor."""
        return self.state.table.snapshot()

    def wait_for(self) -> dict[str, tuple[str, ...]]:
        """The wait-for graph: each waiting unit -> the units it waits for."""
        return {u.uid: u.waiting for u in self.state.sorted if u.waiting}

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
        st = self.state
        u = st.units.get(unit_id)
        if u is None:
            holder = st.table.holder(start_node)
            if holder is not None:
                raise ValueError(f"start_node {start_node!r} is held by unit {holder!r}")
            u = Unit(unit_id, unit_order(unit_id), float(priority), goal_node, [start_node])
            st.table.take_node(unit_id, start_node, tick.now, math.inf)
            st.add(u)
        else:
            expect = self._next_node(u)
            if start_node != expect:
                raise ValueError(
                    f"start_node {start_node!r} for unit {unit_id!r}: it stands at or drives "
                    f"to {expect!r}"
                )
            if st.parked.get(u.route[0]) == unit_id:
                del st.parked[u.route[0]]
            u.priority, u.goal = float(priority), goal_node
        u.since = tick.now
        u.waiting = ()
        if not u.turn_back:  # a unit turning back plans when it turns
            path = st.plan(start_node, goal_node)
            u.plan_version = self.graph.version
            u.route = ([u.route[0]] if u.edge else []) + (path or [start_node])
            if path is None:
                detail = f"no route from {start_node} to {goal_node}"
                st.say(tick, u, Action.WAIT, Cause.NO_ROUTE, detail)
            else:
                st.say(tick, u, Action.ROUTE, Cause.REQUEST, f"task to {goal_node}")
        if u.edge is None and u.route == [goal_node]:
            st.park(tick, u)
        return self._end(tick)

    def tick(
        self, now: float, unit_positions: Mapping[str, tuple[float, float]] | None = None
    ) -> list[Decision]:
        """Advance to ``now`` [s]: take progress, let the policies decide and settle
        (``planner.policy``: ``approaching``, ``decide``, ``settle``, in set order).

        unit_positions: unit id -> (x, y) [m] as the units report them; units not listed
        keep their last position, unknown ids are ignored. Returns this tick's decisions.
        """
        tick = self._begin(now)
        st = self.state
        if unit_positions:
            for uid, xy in unit_positions.items():
                u = st.units.get(uid)
                if u is not None:
                    x, y = float(xy[0]), float(xy[1])
                    if not (math.isfinite(x) and math.isfinite(y)):
                        raise ValueError(f"unit_positions[{uid!r}] must be finite, got {xy!r}")
                    u.pos = (x, y)
        for u in st.sorted:
            if u.behind and u.pos is not None:
                st.release_behind(u)
            if u.edge is not None and u.pos is not None:
                self._progress(tick, u)
        ready = [u for u in st.sorted if (u.edge is None and len(u.route) > 1) or u.turn_back]
        for policy in self.policies:
            ready = policy.decide(st, tick, ready)
        for policy in self.policies:
            policy.settle(st, tick)
        return self._end(tick)

    def refresh(self, now: float) -> list[Decision]:
        """Re-read the costmap (one segment query); the policies react to newly blocked
        lanes (``lanes_blocked``), then units with no route try the changed graph."""
        if self.client is None:
            raise ValueError("refresh needs a map client: LaneCoordinator(graph, client=None)")
        tick = self._begin(now)
        st = self.state
        changes = self.graph.refresh(self.client)
        if changes.blocked:
            blocked = set(changes.blocked)
            for policy in self.policies:
                policy.lanes_blocked(st, tick, blocked)
        for u in st.sorted:  # units with no route try again on a changed graph
            if u.edge is None and len(u.route) == 1 and u.route[0] != u.goal:
                if u.plan_version != self.graph.version:
                    st.replan(tick, u, Cause.LANE_CLEARED, "the lane graph changed")
        return self._end(tick)

    # ------------------------------------------------------------------ progress

    def _progress(self, tick: Tick, u: Unit) -> None:
        """Release the tail once clear of it; arrive at the head when within tolerance
        (before that, the policies hear how near it is: ``approaching``)."""
        assert u.edge is not None and u.pos is not None
        st = self.state
        tail, head = u.edge
        x, y = u.pos
        if u.tail_held and not u.behind:  # a tail ahead of the unit is not left yet
            (tx, ty), (hx, hy) = st.xy[tail], st.xy[head]
            beyond = (x - tx) * (hx - tx) + (y - ty) * (hy - ty) > 0
            if beyond and math.hypot(x - tx, y - ty) > self.settings.clear_m:
                st.table.release_node(u.uid, tail)
                u.tail_held = False
        hx, hy = st.xy[head]
        to_head = math.hypot(x - hx, y - hy)
        if u.turn_back:
            return
        if to_head > self.settings.arrive_tol:
            for policy in self.policies:
                policy.approaching(st, tick, u, to_head)
            return
        for b in u.behind:  # arrived: every edge before this one is behind the body
            if b.lane_held:
                st.table.release_lane(u.uid, b.tail, b.head)
                b.lane_held = False
        st.release_behind(u)
        st.table.release_lane(u.uid, tail, head)
        st.table.release_node(u.uid, tail)
        u.edge, u.tail_held, u.prev = None, False, tail
        u.route.pop(0)
        if len(u.route) == 1:
            if head == u.goal:
                st.park(tick, u)
            else:  # no route onward: try again now (the graph may have changed)
                detail = f"reached {head} with no route to {u.goal}"
                st.replan(tick, u, Cause.NO_ROUTE, detail)
        if head in st.ends or len(u.route) == 1:
            st.table.unclaim(u.uid)  # out of the corridor, or standing in it

    # ------------------------------------------------------------------ helpers

    def _begin(self, now: float) -> Tick:
        if isinstance(now, bool) or not isinstance(now, int | float) or not math.isfinite(now):
            raise ValueError(f"now must be a finite number of seconds, got {now!r}")
        if now < self._now:
            raise ValueError(f"now must not go backwards: got {now!r} after {self._now!r}")
        self._now = float(now)
        return Tick(float(now))

    def _end(self, tick: Tick) -> list[Decision]:
        self.state.log.extend(tick.out)
        return tick.out

    @staticmethod
    def _next_node(u: Unit) -> str:
        """Where the unit stands, or the node it drives to."""
        if u.edge is None:
            return u.route[0]
        return u.edge[0] if u.turn_back else u.edge[1]

    def _unit(self, unit_id: str) -> Unit:
        u = self.state.units.get(unit_id)
        if u is None:
            raise ValueError(f"unit_id {unit_id!r} is not known to the coordinator")
        return u
