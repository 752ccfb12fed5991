"""Lane coordination policy: reserving ahead.

A moving unit within ``reserve_ahead_m`` [m] of its edge's head is granted the next
edge of its route at once if it is free (the same checks as a unit asking at a node),
and again while the new head is within reach, so it drives on through nodes without
stopping; with ``reserve_ahead_m = 0`` a unit is granted its next edge only once it has
arrived. The windowed reservations of rolling-horizon planning (Li et al., *Lifelong
Multi-Agent Path Finding in Large-Scale Warehouses*, AAAI 2021) in space rather than
time: the window is the braking distance plus a margin.

What a unit was granted past it keeps until its body has left it: the edges it drove
past are kept in order (``Behind``, released by ``CoordinationState.release_behind`` as
the unit's progress is taken). A route that comes back over a node of the chain is
driven up to the turn first.
"""

from __future__ import annotations

import math

from planner.coordination_state import Behind, CoordinationState, Tick, Unit
from planner.decisions import Action, Cause
from planner.policy import CoordinationPolicy


class ReserveAhead(CoordinationPolicy):
    """Grants a unit near its edge's head its next edges (module docstring).

    reserve_ahead_m [m]: how near (0: never ahead).
    """

    name = "reserve_ahead"

    def __init__(self, reserve_ahead_m: float) -> None:
        self.reserve_ahead_m = reserve_ahead_m

    def approaching(self, state: CoordinationState, tick: Tick, unit: Unit, to_head: float) -> None:
        if to_head <= self.reserve_ahead_m:
            self.reserve(state, tick, unit)

    def reserve(self, state: CoordinationState, tick: Tick, u: Unit) -> None:
        """Grant ``u`` the next edges of its route while each is free and its head is
        within ``reserve_ahead_m`` [m]; it keeps what it drives over until its body has
        left it."""
        assert u.pos is not None
        edges = state.graph.graph.edges
        while u.edge is not None and len(u.route) > 2:
            tail, head = u.edge
            if math.dist(u.pos, state.xy[head]) > self.reserve_ahead_m:
                return
            rest = u.route[1:]
            chain = {tail, head, *(b.tail for b in u.behind)}
            if rest[1] in chain:  # the route comes back: drive up to the turn first
                return
            if edges[rest[0], rest[1]]["blocked"] or state.step_blockers(u.uid, rest):
                return
            u.behind.append(Behind(tail, head, u.tail_held))
            u.route.pop(0)
            u.prev = tail
            state.grant(tick, u, rest[1], Action.GRANT, Cause.ROUTE, f"{head} -> {rest[1]} (ahead)")
