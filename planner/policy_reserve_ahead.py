"""Lane coordination policy: reserving ahead.

A moving unit within ``reserve_ahead_m`` [m] of its edge's head is granted the next
edge of its route at once if it is free (the same checks as a unit asking at a node),
and again while the new head is within reach, so it drives on through nodes without
stopping; with ``reserve_ahead_m = 0`` a unit is granted its next edge only once it has
arrived. The windowed reservations of rolling-horizon planning (Li et al., *Lifelong
Multi-Agent Path Finding in Large-Scale Warehouses*, AAAI 2021) in space rather than
time: the window is the braking distance plus a margin.

What a unit was granted past it keeps until its body has left it: the edges it drove
past are kept in order (``Behind``); the lane of its chain nearest to its position
(the later one on a tie, so a unit cutting a corner has left the first lane once it is
nearer the second) is the one it is on, the lanes before it are released, and each node
once the unit is on or past it and ``clear_m`` [m] from it. A route that comes back over
a node of the chain is driven up to the turn first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from planner.coordinator import _Tick, _Unit


@dataclass(slots=True)
class Behind:
    """An edge a unit was granted past while still driving it (reserving ahead): what
    of it the unit still holds until its body has left it."""

    tail: str
    head: str
    tail_held: bool
    lane_held: bool = True


class ReserveAhead:
    """Mixed into ``LaneCoordinator``: uses its table, graph, units, grants and log."""

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
            u.behind.append(Behind(tail, head, u.tail_held))
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


def _segment_distance(
    p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]
) -> float:
    """[m] from point ``p`` to the segment a-b."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / length2
    t = min(1.0, max(0.0, t))
    return math.hypot(p[0] - a[0] - t * dx, p[1] - a[1] - t * dy)
