"""Lane coordination policy ``reserve_ahead``'s grants: each waiting unit is granted its
next edge as soon as it is free.

The units ready to decide go in the order (higher priority, longer wait, unit id). A
unit stopped on a blocked lane turns back (``planner.policy_blocked_lanes.turn_back``).
A unit at a node asks for its next edge: a blocked one makes it reroute first; a free
one is granted (``CoordinationState.step_blockers``: the lane, its corridor, the head
node and, through a crossing, the way out); else it waits, recording whom it waits for
(``node_held``, ``lane_held`` or ``exit_held``) when the wait starts and whenever that
changes. When some of those are units standing still, they are moved out of its way
(``planner.policy_standing``), or failing that it takes a route around every parked
unit, when the wait starts and every ``retry_s`` [s].
"""

from __future__ import annotations

from planner.coordination_state import CoordinationState, Tick, Unit
from planner.decisions import Action, Cause
from planner.policy import CoordinationPolicy
from planner.policy_blocked_lanes import turn_back
from planner.policy_standing import clear_way


class GrantWhenFree(CoordinationPolicy):
    """Grants every ready unit its next edge once it is free (module docstring).

    retry_s [s]: how often a unit held up by standing units tries again to get round them.
    """

    name = "grant_when_free"

    def __init__(self, retry_s: float) -> None:
        self.retry_s = retry_s

    def decide(self, state: CoordinationState, tick: Tick, ready: list[Unit]) -> list[Unit]:
        now = tick.now
        order = sorted(
            ready, key=lambda u: (-u.priority, u.wait_since if u.waiting else now, u.order)
        )
        for u in order:
            if u.turn_back:
                turn_back(state, tick, u)
            else:
                self._ask(state, tick, u)
        return []

    def _ask(self, state: CoordinationState, tick: Tick, u: Unit) -> None:
        """A unit at a node asks for its next edge: grant, or wait (and maybe detour)."""
        cur, nxt = u.route[0], u.route[1]
        if state.graph.graph.edges[cur, nxt]["blocked"]:
            state.replan(tick, u, Cause.LANE_BLOCKED, f"lane {cur}-{nxt} is blocked")
            if len(u.route) < 2:
                return
            cur, nxt = u.route[0], u.route[1]
        blockers = state.step_blockers(u.uid, u.route)
        if not blockers:
            state.grant(tick, u, nxt, Action.GRANT, Cause.ROUTE, f"{cur} -> {nxt}")
            return
        changed = blockers != u.waiting
        standing = [state.units[b] for b in blockers if state.units[b].standing]
        if standing and (changed or tick.now >= u.retry_at):
            u.retry_at = tick.now + self.retry_s
            if clear_way(state, tick, u, standing):
                changed = changed or not u.waiting
            else:
                avoid = set() if nxt == u.goal else {nxt}
                detail = f"{nxt} is held by standing unit(s) {', '.join(blockers)}"
                if state.detour(
                    tick, u, {(cur, nxt)}, avoid, Cause.PARKED_UNIT, detail, blockers, strict=True
                ):
                    return
        if not changed:
            return
        if not u.waiting:
            u.wait_since = tick.now
        u.waiting = blockers
        who = ", ".join(blockers)
        holder = state.table.holder(nxt)
        if holder is not None and holder != u.uid:
            cause, detail = Cause.NODE_HELD, f"node {nxt} is held by {holder}"
        elif state.table.blockers(u.uid, cur, nxt):
            cause, detail = Cause.LANE_HELD, f"lane {cur}-{nxt} or its corridor is held by {who}"
        else:
            cause, detail = Cause.EXIT_HELD, f"the way out of crossing {nxt} is held by {who}"
        state.say(tick, u, Action.WAIT, cause, detail, edge=(cur, nxt), waiting_for=blockers)
