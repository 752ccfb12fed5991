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
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from planner.lane_graph import Lane, lane_key

if TYPE_CHECKING:
    from planner.coordinator import _Tick, _Unit


class BlockedLanes:
    """Mixed into ``LaneCoordinator``: uses its table, graph, units, grants and log."""

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
