"""Lane coordination policy: units on, or routed over, lanes the costmap blocks.

``refresh(now)`` re-reads the costmap through the injected client
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

A stranded unit is among the ready units of every tick's ``decide``; the policy that
decides for it calls ``turn_back``.
"""

from __future__ import annotations

import math

from planner.coordination_state import CoordinationState, Tick, Unit
from planner.decisions import Action, Cause
from planner.lane_graph import Lane, lane_key
from planner.policy import CoordinationPolicy


class BlockedLanes(CoordinationPolicy):
    """Turns back, carries on or reroutes the units a newly blocked lane concerns."""

    name = "blocked_lanes"

    def lanes_blocked(self, state: CoordinationState, tick: Tick, blocked: set[Lane]) -> None:
        """Turn back, carry on or reroute every unit whose remaining route uses ``blocked``."""
        for u in state.sorted:
            if u.turn_back:
                continue  # it plans when it has turned back
            if u.edge is not None and lane_key(*u.edge) in blocked:
                self._on_blocked_lane(state, tick, u)
                continue
            start = 1 if u.edge is not None else 0
            rest = u.route[start:]
            hits = [lane_key(a, b) for a, b in zip(rest, rest[1:], strict=False)]
            hit = next((k for k in hits if k in blocked), None)
            if hit is not None:
                state.replan(tick, u, Cause.LANE_BLOCKED, f"lane {hit[0]}-{hit[1]} is blocked")

    def _on_blocked_lane(self, state: CoordinationState, tick: Tick, u: Unit) -> None:
        """A unit on a newly blocked lane: carry on if past the block, else turn back."""
        assert u.edge is not None
        tail, head = u.edge
        edges = state.graph.graph.edges
        if (tail, head) in edges:
            length, (near, far) = edges[tail, head]["length"], edges[tail, head]["block_span"]
        else:  # reversing a one-way lane: mirror the span of its only edge
            length, (n0, f0) = edges[head, tail]["length"], edges[head, tail]["block_span"]
            near, far = length - f0, length - n0
        s = 0.0
        if u.pos is not None:
            (tx, ty), (hx, hy) = state.xy[tail], state.xy[head]
            s = ((u.pos[0] - tx) * (hx - tx) + (u.pos[1] - ty) * (hy - ty)) / length
        where = f"{near:.2f}-{far:.2f} m along {tail} -> {head}"
        if s > far:
            state.replan(
                tick, u, Cause.LANE_BLOCKED, f"blocked {where}, behind the unit: carrying on"
            )
            return
        u.turn_back = True
        state.table.claim_reverse(u.uid, tail, head, tick.now)  # so followers may turn too
        state.say(
            tick,
            u,
            Action.REROUTE,
            Cause.LANE_BLOCKED,
            f"blocked {where}, ahead of the unit at {s:.2f} m: turning back to {tail}",
            edge=(head, tail),
        )
        turn_back(state, tick, u)


def turn_back(state: CoordinationState, tick: Tick, u: Unit) -> None:
    """Reverse ``u`` onto its lane's tail if free, else it waits for it where it stands."""
    assert u.edge is not None
    tail, head = u.edge
    holder = state.table.holder(tail)
    if holder is not None and holder != u.uid:
        if u.waiting != (holder,):
            u.wait_since = tick.now if not u.waiting else u.wait_since
            u.waiting = (holder,)
            state.say(
                tick,
                u,
                Action.WAIT,
                Cause.LANE_BLOCKED,
                f"stopped on blocked lane {tail}-{head}; {tail} is held by {holder}",
                edge=(head, tail),
                waiting_for=u.waiting,
            )
        return
    state.table.reverse_lane(u.uid, tail, head, tick.now, _back_time(state, u))
    u.edge, u.tail_held, u.turn_back = (head, tail), False, False
    u.waiting = ()
    path = state.plan(tail, u.goal)
    u.plan_version = state.graph.version
    u.route = [head, *(path or [tail])]
    state.say(
        tick, u, Action.GRANT, Cause.LANE_BLOCKED, f"reversing {head} -> {tail}", edge=(head, tail)
    )


def _back_time(state: CoordinationState, u: Unit) -> float:
    """Nominal time [s] to drive back to the edge's tail from the unit's position."""
    assert u.edge is not None
    tx, ty = state.xy[u.edge[0]]
    x, y = u.pos if u.pos is not None else (tx, ty)
    return math.hypot(x - tx, y - ty) / state.settings.speed
