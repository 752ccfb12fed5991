"""Lane coordination policy ``pibt``: priority inheritance with backtracking.

After Okumura, Machida, Défago and Tamura, *Priority Inheritance with Backtracking for
Iterative Multi-agent Path Finding*, Artificial Intelligence 310, 103752 (2022). Each
coordination tick every unit standing at a node decides where to go next, in priority
order (highest first):

- priority: the time [s] since the unit was given its current leg (``request``), so it
  rises while the unit has not reached its goal and resets when it gets the next one;
  ties by the requested priority (higher first), then the natural unit id. A unit parked
  at its goal, or with no route, never decides on its own: it only moves when pushed; a
  parked unit pushed off its goal parks where it is pushed (its leg was done; the next
  is the caller's to give), as ``planner.policy_standing`` moves parked units aside.
- candidates: the node's successors over unblocked edges, and staying put, sorted by
  the least-weight distance [m] from the candidate to the unit's goal (ties: a node
  nobody else holds, as in the authors' implementations, then the next node of its
  route, off the pushing unit's route, not a crossing, then the node id). A unit stays when staying
  ranks before every candidate it can have.
- a candidate node another unit has claimed this tick is out; so is one whose way is
  held by a unit that cannot move (an ancestor in the current chain of pushes, a unit
  that already decided to stay, a unit stranded on a blocked lane).
- a candidate held by a lower-priority unit standing at a node that has not decided yet
  makes that unit decide first (priority inheritance): it must move somewhere other
  than its parent's node and the node its parent wants; if it cannot, the parent
  backtracks and tries its next candidate, and reports failure to its own parent when
  none is left (backtracking).
- a candidate whose holders will leave (units already driving, or that decided to move
  this tick) is claimed: the unit waits for it, and nobody else may take it this tick.

Adaptation to the lane coordinator (its reservation table is PIBT's occupancy):
a unit may only drive an edge once the table grants it, and a node is free only once its
holder's body has left it, so a pushed unit moves first and the pushing unit is granted
the node on a later tick (a unit never follows into a node in the same tick, and a ring
of units cannot rotate at once: a ring is resolved by one of its units stepping out).
Corridor claims and lane holds are kept: their holders count as blockers like a node's
holder; a unit claims the corridor of the edge it wants when it decides (unless another
unit claims it the other way), so its stale claim from the edge it last drove does not
stop the units it pushes ahead of it. The nodes claimed by waiting units
(``CoordinationState.intents``) are also withheld from units reserving ahead, so moving
units cannot starve a waiting unit. A unit moved off its route is given a new route from
its new node. The deadlock breaker (``planner.policy_deadlocks``) still runs after the
round as a logged safety net.

Determinism: units in the order above, candidates in sorted order; ``now`` is the tick's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import networkx as nx

from planner.coordination_state import CoordinationState, Tick, Unit
from planner.decisions import Action, Cause
from planner.lane_graph import LaneGraph
from planner.policy import CoordinationPolicy
from planner.policy_blocked_lanes import turn_back

PUSH, MOVING, HARD = "push", "moving", "hard"
"""How a blocker of a candidate edge behaves: it must be pushed (a standing unit that has
not decided yet), it will leave (driving, or decided to move), or it will not."""


@dataclass
class _Round:
    """One tick's PIBT state: the shared state and the tick, who decided (True: moves or
    will move; False: stays), which node each claiming unit wants, and the chain of units
    being pushed."""

    state: CoordinationState
    tick: Tick
    decided: dict[str, bool] = field(default_factory=dict)
    wanted: dict[str, str] = field(default_factory=dict)
    chain: list[str] = field(default_factory=list)


class Pibt(CoordinationPolicy):
    """Units at nodes decide by priority inheritance with backtracking (module docstring);
    units stopped on a blocked lane turn back first."""

    name = "pibt"

    def __init__(self) -> None:
        self._dist_cache: dict[str, tuple[int, dict[str, float]]] = {}  # goal -> version, m

    def decide(self, state: CoordinationState, tick: Tick, ready: list[Unit]) -> list[Unit]:
        for u in ready:
            if u.turn_back:
                turn_back(state, tick, u)
        self._round(state, tick, [u for u in ready if not u.turn_back])
        return []

    def _round(self, state: CoordinationState, tick: Tick, ready: list[Unit]) -> None:
        """Every ready unit (at a node with a route) decides, highest priority first."""
        r = _Round(state, tick)
        ready = sorted(ready, key=lambda u: self._pibt_rank(u, tick.now))
        for u in ready:
            if u.uid in r.decided or u.edge is not None or len(u.route) < 2:
                continue
            cur, nxt = u.route[0], u.route[1]
            if state.graph.graph.edges[cur, nxt]["blocked"]:
                state.replan(tick, u, Cause.LANE_BLOCKED, f"lane {cur}-{nxt} is blocked")
                if len(u.route) < 2:
                    continue
            self._pibt(r, u, None)
        state.intents = {n: uid for n, uid in r.wanted.items() if state.units[uid].edge is None}

    def _pibt_rank(self, u: Unit, now: float) -> tuple[object, ...]:
        """Sort key: longest since its leg began first, then requested priority, id."""
        return (-(now - u.since), -u.priority, u.order)

    def _pibt(self, r: _Round, u: Unit, parent: Unit | None) -> bool:
        """Decide for ``u`` (pushed by ``parent``, or a root when None): True if it moves
        or will move off its node, False if it stays."""
        state, tick = r.state, r.tick
        v = u.route[0]
        r.decided[u.uid] = False
        r.chain.append(u.uid)
        first_block: tuple[str, tuple[str, ...]] | None = None
        try:
            for m in self._pibt_candidates(state, u, parent):
                if m == v:
                    break  # staying ranks before the rest
                if m in r.wanted:
                    first_block = first_block or (m, (r.wanted[m],))
                    continue
                blockers = state.table.blockers(u.uid, v, m)
                kinds = [self._blocker_kind(r, b, v, m) for b in blockers]
                if HARD in kinds:
                    first_block = first_block or (m, blockers)
                    continue
                r.wanted[m] = u.uid
                before = self._pibt_claim(state, u, v, m, tick.now)
                if not all(self._pushed(r, b, u, m) for b in blockers):
                    del r.wanted[m]
                    state.table.restore_claim(u.uid, before)
                    first_block = first_block or (m, blockers)
                    continue
                r.decided[u.uid] = True
                left = state.table.blockers(u.uid, v, m)
                if left:
                    if not u.standing:  # a standing unit is pushed again if need be
                        self._pibt_wait(state, tick, u, m, left)
                else:
                    self._pibt_grant(state, tick, u, m, parent)
                return True
            if first_block is not None and not u.standing:
                self._pibt_wait(state, tick, u, *first_block)
            return False
        finally:
            r.chain.pop()

    def _pushed(self, r: _Round, uid: str, parent: Unit, m: str) -> bool:
        """Make blocker ``uid`` of ``parent``'s candidate ``m`` leave if it must (an earlier
        push may already have decided it): False if it will not leave."""
        kind = self._blocker_kind(r, uid, parent.route[0], m)
        if kind == PUSH:
            return self._pibt(r, r.state.units[uid], parent)
        return kind == MOVING

    def _pibt_claim(
        self, state: CoordinationState, u: Unit, v: str, m: str, now: float
    ) -> tuple[int, int, float] | None:
        """Claim the corridor of edge (v, m) along it for ``u``, which wants to drive it,
        unless another unit claims it the other way; returns the claim it had (to put
        back if ``u`` does not go). A standing unit's claim is that of the last edge it
        drove, which may point the other way and would stop the units it pushes."""
        before = state.table.claim_of(u.uid)
        d = state.graph.graph.edges[v, m]
        if not state.table.claimants(d["corridor"], -d["heading"]) - {u.uid}:
            state.table.claim(u.uid, d["corridor"], d["heading"], now)
        return before

    def _blocker_kind(self, r: _Round, uid: str, v: str, m: str) -> str:
        """PUSH, MOVING or HARD (module docstring) for a unit in the way of edge (v, m).
        A unit driving (or about to drive) the edge's corridor the other way is coming
        toward the asking unit, not leaving: HARD."""
        state = r.state
        b = state.units[uid]
        if uid in r.chain or b.turn_back:
            return HARD
        if b.edge is None and uid not in r.decided:
            return PUSH
        if b.edge is None and not r.decided[uid]:
            return HARD
        claim = state.table.claim_of(uid)
        d = state.graph.graph.edges[v, m]
        if claim is not None and claim[:2] == (d["corridor"], -d["heading"]):
            if state.table.holder(m) != uid:
                return HARD
        return MOVING

    def _pibt_candidates(self, state: CoordinationState, u: Unit, parent: Unit | None) -> list[str]:
        """Where ``u`` may go, best first (module docstring); staying only for a root."""
        v = u.route[0]
        edges = state.graph.graph.edges
        options = [m for m in state.graph.graph.successors(v) if not edges[v, m]["blocked"]]
        if parent is None:
            options.append(v)
        dist = self._distances_to(state.graph, u.goal)
        nxt = u.route[1] if len(u.route) > 1 else None
        avoid = set(parent.route) if parent is not None else set()
        return sorted(
            options,
            key=lambda m: (
                dist.get(m, math.inf),
                state.table.holder(m) not in (None, u.uid),
                m != nxt,
                m in avoid,
                m in state.crossings,
                m,
            ),
        )

    def _distances_to(self, graph: LaneGraph, goal: str) -> dict[str, float]:
        """Least weight [m] from every node to ``goal`` over unblocked edges (cached per
        graph version)."""
        cached = self._dist_cache.get(goal)
        if cached is not None and cached[0] == graph.version:
            return cached[1]

        def weight(a: str, b: str, d: dict) -> float | None:
            return None if d["blocked"] else d["weight"]

        reverse = graph.graph.reverse(copy=False)
        dist = nx.single_source_dijkstra_path_length(reverse, goal, weight=weight)
        self._dist_cache[goal] = (graph.version, dist)
        return dist

    def _pibt_grant(
        self, state: CoordinationState, tick: Tick, u: Unit, m: str, parent: Unit | None
    ) -> None:
        """Grant ``u`` the edge to ``m``, with a new route when ``m`` is off its route."""
        v = u.route[0]
        if u.standing:
            if state.parked.get(v) == u.uid:  # a parked unit parks where it is pushed
                del state.parked[v]
                u.goal = m
            path = state.plan(m, u.goal) or [m]
            u.route = [v, *path]
        elif u.route[1] != m:
            path = state.plan(m, u.goal) or [m]
            u.route = [v, *path]
            why = f"pushed by {parent.uid}" if parent else "its next node is taken"
            state.say(tick, u, Action.REROUTE, Cause.PIBT, f"via {m}: {why}")
        if parent is None:
            state.grant(tick, u, m, Action.GRANT, Cause.ROUTE, f"{v} -> {m}")
        else:
            detail = f"{v} -> {m}: out of the way of {parent.uid} (priority inheritance)"
            state.grant(tick, u, m, Action.BACK_OFF, Cause.INHERIT, detail, (parent.uid,))

    def _pibt_wait(
        self, state: CoordinationState, tick: Tick, u: Unit, m: str, blockers: tuple[str, ...]
    ) -> None:
        """Record that ``u`` waits at its node for ``m`` (when what it waits for changes)."""
        if blockers == u.waiting:
            return
        if not u.waiting:
            u.wait_since = tick.now
        u.waiting = blockers
        cur = u.route[0]
        holder = state.table.holder(m)
        if holder is not None and holder != u.uid:
            cause, detail = Cause.NODE_HELD, f"node {m} is held by {holder}"
        else:
            who = ", ".join(blockers)
            cause, detail = Cause.LANE_HELD, f"the way to {m} is held or claimed by {who}"
        state.say(tick, u, Action.WAIT, cause, detail, edge=(cur, m), waiting_for=blockers)
