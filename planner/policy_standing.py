"""Lane coordination policy: standing units are moved out of a waiting unit's way.

A unit whose way is held by a unit standing still (parked, or with no
route) does not wait for it forever: the standing unit is moved aside to a free
neighbour off the waiting unit's route, or pushed on along it (never back toward the
waiting unit), or, with no free neighbour, one of its own standing neighbours is moved
first; an idle unit moved aside parks where it is moved to. Failing that, the waiting
unit takes a route around every parked unit if one exists. Either is tried when the
wait starts and every ``retry_s`` [s].
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from planner.coordinator import _Tick, _Unit


class StandingUnits:
    """Mixed into ``LaneCoordinator``: uses its table, graph, units, grants and log."""

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
