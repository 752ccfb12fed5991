"""The lane coordinator's shared state: what its policies may read and write.

``CoordinationState`` holds the lane graph, the reservation table
(``planner.reservations``), the units (``Unit``) by id and in natural id order, the
parked units, the nodes claimed by waiting units and the decision log, and the
operations every policy grants, plans and explains through: ``grant`` (open an edge's
windows), ``say`` (log a ``Decision``), ``plan``/``replan``/``detour`` (routes),
``step_blockers`` (who stops a unit taking its next step), ``park`` and
``release_behind``. The driver (``planner.coordinator.LaneCoordinator``) and the policies
(``planner.policy``) change the fleet only through it, so a policy is one module that
needs nothing from another's internals.

Settings are ``CoordinatorSettings``: one frozen record, validated where it is made.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mapserver.core.errors import FieldError
from planner.decisions import Action, Cause, Decision
from planner.lane_graph import LaneGraph
from planner.reservations import ReservationTable

__all__ = [
    "Behind",
    "CoordinationState",
    "CoordinatorSettings",
    "Tick",
    "Unit",
    "segment_distance",
]


@dataclass(frozen=True)
class CoordinatorSettings:
    """The lane coordinator's knobs.

    speed [m/s]: nominal driving speed for expected ends of windows. clear_m [m]:
    distance from a node beyond which a leaving unit releases it (at least the unit's
    length). arrive_tol [m]: distance from an edge's head at which the unit has arrived.
    retry_s [s]: how often a unit held up by a standing unit, or an unresolved deadlock,
    tries again to get out of it. reserve_ahead_m [m]: a unit this close to its edge's
    head is granted its next edge already, if it is free (0: only once it has arrived;
    ``planner.policy_reserve_ahead``). back_off_hops [edges]: how far a deadlocked unit
    looks for a place to back off to (``planner.policy_deadlocks``).
    """

    speed: float = 1.0
    clear_m: float = 1.0
    arrive_tol: float = 0.1
    retry_s: float = 1.0
    reserve_ahead_m: float = 0.0
    back_off_hops: int = 3

    def __post_init__(self) -> None:
        for name in ("speed", "clear_m", "arrive_tol", "retry_s"):
            value = getattr(self, name)
            if not (_is_number(value) and math.isfinite(value) and value > 0):
                raise FieldError(name, value, "must be a positive finite number")
        if not (
            _is_number(self.reserve_ahead_m)
            and math.isfinite(self.reserve_ahead_m)
            and self.reserve_ahead_m >= 0
        ):
            reason = "must be a finite number >= 0"
            raise FieldError("reserve_ahead_m", self.reserve_ahead_m, reason)
        hops = self.back_off_hops
        if isinstance(hops, bool) or not isinstance(hops, int) or hops < 1:
            raise FieldError("back_off_hops", hops, "must be an integer >= 1")


def _is_number(value: object) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float)


@dataclass(slots=True)
class Behind:
    """An edge a unit was granted past while still driving it (reserving ahead): what
    of it the unit still holds until its body has left it."""

    tail: str
    head: str
    tail_held: bool
    lane_held: bool = True


@dataclass(slots=True)
class Unit:
    """One unit as the coordinator tracks it.

    order: its natural-id sort key; priority: the requested one (larger goes first);
    goal: its goal node; route: the nodes left, from its node or its edge's tail; edge:
    the edge it drives (None at a node); tail_held: it still holds the edge's tail;
    turn_back: stopped on a blocked lane, to reverse to the tail; pos: its last reported
    (x, y) [m]; prev: the node it came from; waiting: the units it waits for, since
    ``wait_since`` [s]; retry_at [s]: when it next tries to get round standing units;
    plan_version: the graph version its route was planned on; since [s]: when its task
    began; behind: what it holds of edges it was granted past (``Behind``).
    """

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

    @property
    def standing(self) -> bool:
        """At a node with nowhere to go: parked at its goal, or with no route."""
        return self.edge is None and len(self.route) == 1


@dataclass
class Tick:
    """One call of the coordinator: its time ``now`` [s] and the decisions made."""

    now: float
    out: list[Decision] = field(default_factory=list)


class CoordinationState:
    """What the driver and its policies share (module docstring).

    graph: the lane graph; settings: ``CoordinatorSettings``; table: the reservation
    table; units: id -> ``Unit``; sorted: the units in natural id order; parked: node ->
    the idle unit parked there; intents: node -> the waiting unit that claimed it this
    tick (``planner.policy_pibt``; every grant honours it); log: every decision;
    deadlocks: wait-for cycles found (a cycle counts once while it persists).
    """

    def __init__(self, graph: LaneGraph, settings: CoordinatorSettings) -> None:
        self.graph = graph
        self.settings = settings
        self.table = ReservationTable(graph, settings.speed, settings.clear_m)
        self.units: dict[str, Unit] = {}
        self.sorted: list[Unit] = []
        self.parked: dict[str, str] = {}
        self.intents: dict[str, str] = {}
        self.log: list[Decision] = []
        self.deadlocks = 0
        self.ends = graph.corridor_ends
        self.crossings = graph.crossings
        self.xy = {n: graph.graph.nodes[n]["pos"] for n in graph.nodes}

    def add(self, u: Unit) -> None:
        """Track a new unit (kept in natural id order)."""
        self.units[u.uid] = u
        self.sorted = sorted(self.units.values(), key=lambda v: v.order)

    # ------------------------------------------------------------------ decisions

    def say(
        self,
        tick: Tick,
        u: Unit,
        action: Action,
        cause: Cause,
        detail: str,
        edge: tuple[str, str] | None = None,
        waiting_for: tuple[str, ...] = (),
    ) -> None:
        """Record a decision about ``u`` in this tick (its route as it is now)."""
        tick.out.append(
            Decision(tick.now, u.uid, action, cause, detail, edge, waiting_for, tuple(u.route))
        )

    def grant(
        self,
        tick: Tick,
        u: Unit,
        nxt: str,
        action: Action,
        cause: Cause,
        detail: str,
        waiting_for: tuple[str, ...] = (),
    ) -> None:
        """Open the windows of edge (node, nxt) for ``u``; the caller checked they are free."""
        cur = u.route[0]
        self.table.take_edge(u.uid, cur, nxt, tick.now)
        u.edge, u.tail_held = (cur, nxt), True
        u.waiting = ()
        self.say(tick, u, action, cause, detail, edge=(cur, nxt), waiting_for=waiting_for)

    def park(self, tick: Tick, u: Unit) -> None:
        """``u`` stays at its node, its goal, until its next task."""
        node = u.route[0]
        self.parked[node] = u.uid
        self.table.expect_node(node, math.inf)
        self.say(tick, u, Action.ARRIVED, Cause.GOAL, f"parked at its goal {node}")

    # ------------------------------------------------------------------ grants

    def step_blockers(self, uid: str, route: list[str]) -> tuple[str, ...]:
        """Who stops ``uid`` taking the first edge of ``route`` now: the blockers of that
        edge (and a waiting unit that claimed its head, ``intents``) and, if its head is
        a crossing the unit only passes through, of the edge out of it too (do not block
        the box: never stop inside a crossing)."""
        found = self.table.blockers(uid, route[0], route[1])
        claimant = self.intents.get(route[1])
        if (
            claimant is not None
            and claimant != uid
            and claimant not in found
            and self.units[claimant].edge is None
        ):
            found = (*found, claimant)
        if not found and len(route) > 2 and route[1] in self.crossings:
            found = self.table.blockers(uid, route[1], route[2])
        return found

    # ------------------------------------------------------------------ routing

    def plan(
        self,
        src: str,
        goal: str,
        avoid_edges: set[tuple[str, str]] | frozenset[tuple[str, str]] = frozenset(),
        avoid_nodes: set[str] | frozenset[str] = frozenset(),
        strict: bool = False,
    ) -> list[str] | None:
        """A route around parked units if there is one, else (unless strict) through them."""
        parked = {n for n in self.parked if n not in (src, goal)}
        if parked or strict:
            path = self.graph.shortest_route(src, goal, avoid_edges, parked | set(avoid_nodes))
            if path is not None or strict:
                return path
        return self.graph.shortest_route(src, goal, avoid_edges, avoid_nodes)

    def replan(self, tick: Tick, u: Unit, cause: Cause, detail: str) -> None:
        """New route to the goal from the unit's node (or its edge's head, keeping the edge)."""
        keep = [u.route[0]] if u.edge is not None else []
        src = u.edge[1] if u.edge is not None else u.route[0]
        path = self.plan(src, u.goal)
        u.plan_version = self.graph.version
        u.waiting = ()
        if path is None:
            u.route = [*keep, src]
            self.say(
                tick, u, Action.WAIT, Cause.NO_ROUTE, f"{detail}; no route from {src} to {u.goal}"
            )
        else:
            u.route = [*keep, *path]
            self.say(tick, u, Action.REROUTE, cause, detail)

    def detour(
        self,
        tick: Tick,
        u: Unit,
        avoid_edges: set[tuple[str, str]],
        avoid_nodes: set[str],
        cause: Cause,
        detail: str,
        waiting_for: tuple[str, ...],
        strict: bool = False,
    ) -> bool:
        """Reroute a waiting unit avoiding edges and nodes, if its new first step is free now.

        strict: only a route that avoids every parked unit will do.
        """
        cur = u.route[0]
        path = self.plan(cur, u.goal, avoid_edges, avoid_nodes - {u.goal}, strict)
        if path is None or len(path) < 2 or self.step_blockers(u.uid, path):
            return False
        u.route = path
        self.say(tick, u, Action.REROUTE, cause, detail, waiting_for=waiting_for)
        self.grant(tick, u, path[1], Action.GRANT, cause, f"{cur} -> {path[1]} (detour)")
        return True

    # ------------------------------------------------------------------ progress

    def release_behind(self, u: Unit) -> None:
        """Release what a unit has driven past (reserving ahead): the lanes before the one
        it is on now (the lane of its chain nearest to it, the later one on a tie: so a
        unit cutting a corner has left the first lane once nearer the second) and the
        nodes it is on or past and ``clear_m`` [m] from."""
        assert u.pos is not None
        chain = [(b.tail, b.head) for b in u.behind] + ([u.edge] if u.edge else [])
        gaps = [segment_distance(u.pos, self.xy[a], self.xy[b]) for a, b in chain]
        on = min(range(len(chain)), key=lambda k: (gaps[k], -k))
        for k, b in enumerate(u.behind[: on + 1]):
            if b.tail_held and math.dist(u.pos, self.xy[b.tail]) > self.settings.clear_m:
                self.table.release_node(u.uid, b.tail)
                b.tail_held = False
            if b.lane_held and k < on:
                self.table.release_lane(u.uid, b.tail, b.head)
                b.lane_held = False
        u.behind = [b for b in u.behind if b.tail_held or b.lane_held]


def segment_distance(
    p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]
) -> float:
    """[m] from point ``p`` to the segment a-b."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / length2
    t = min(1.0, max(0.0, t))
    return math.hypot(p[0] - a[0] - t * dx, p[1] - a[1] - t * dy)
