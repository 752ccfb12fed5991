"""Lane coordination policy: deadlocks found and broken.

Waits form a wait-for graph (unit -> the units holding what it needs); a
cycle in it is a deadlock (Coffman, Elphick and Shoshani, *System Deadlocks*, ACM
Computing Surveys 3(2), 1971; Holt, *Some Deadlock Properties of Computer Systems*, ACM
Computing Surveys 4(3), 1972). After the tick's grants the coordinator finds cycles
with ``networkx.find_cycle``, one at a time, and breaks each. The unit that gives way is
the lowest-priority unit of the cycle standing at a node (ties: the larger unit id, in
natural order, so "u10" > "u9"). It is

1. rerouted: a route to its goal around the nodes held by the unit it waits for, or
   else around its contested next edge and node (never around its own goal), if the
   first step of that route can be granted now;
2. else backed off: to the nearest node within ``BACK_OFF_HOPS`` edges, over edges it
   could be granted now, where it may stop (not a crossing), preferring one off the
   route of the unit waiting for it, then the node it came from; it replans from there;
3. else the next unit of the cycle is tried. A cycle nobody can leave is recorded once
   as an unresolved wait and tried again every ``retry_s`` [s].
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import networkx as nx

from planner.reservations import unit_order

if TYPE_CHECKING:
    from planner.coordinator import _Tick, _Unit

BACK_OFF_HOPS = 3
"""How far [edges] a deadlocked unit looks for a place to back off to."""


class Deadlocks:
    """Mixed into ``LaneCoordinator``: uses its table, graph, units, grants and log."""

    def _detour(
        self,
        tick: _Tick,
        u: _Unit,
        avoid_edges: set[tuple[str, str]],
        avoid_nodes: set[str],
        cause: str,
        detail: str,
        waiting_for: tuple[str, ...],
        strict: bool = False,
    ) -> bool:
        """Reroute a waiting unit avoiding edges and nodes, if its new first step is free now.

        strict: only a route that avoids every parked unit will do.
        """
        cur = u.route[0]
        path = self._plan(cur, u.goal, avoid_edges, avoid_nodes - {u.goal}, strict)
        if path is None or len(path) < 2 or self._step_blockers(u.uid, path):
            return False
        u.route = path
        self._say(tick, u, "reroute", cause, detail, waiting_for=waiting_for)
        self._grant(tick, u, path[1], "grant", cause, f"{cur} -> {path[1]} (detour)")
        return True

    def _back_off(
        self, tick: _Tick, u: _Unit, behind: _Unit, detail: str, waiting_for: tuple[str, ...]
    ) -> bool:
        """Move aside to the nearest free place to stop, then replan from there.

        Searches breadth-first, up to ``BACK_OFF_HOPS`` edges, over edges ``u`` could be
        granted now, for a node that is not a crossing. Preference: fewest hops, then off
        the route of ``behind`` (the unit of the cycle waiting for ``u``), then the node
        ``u`` came from, then weight and node id. With no such node, any free neighbour
        other than the contested one will do.
        """
        cur, nxt = u.route[0], u.route[1]
        in_way = set(behind.route)
        edges = self.graph.graph.edges

        def free(a: str) -> list[str]:
            return [
                m
                for m in self.graph.graph.successors(a)
                if not edges[a, m]["blocked"] and not self.table.blockers(u.uid, a, m)
            ]

        def rank(path: list[str]) -> tuple[object, ...]:
            m = path[-1]
            return (m in in_way, m != u.prev, self.graph.route_length(path), m)

        paths = [[cur]]
        seen = {cur}
        best: list[str] | None = None
        for _ in range(BACK_OFF_HOPS):
            paths = [[*p, m] for p in paths for m in free(p[-1]) if m not in seen]
            seen.update(p[-1] for p in paths)
            stops = [p for p in paths if p[-1] not in self._crossings]
            if stops:
                best = min(stops, key=rank)
                break
        if best is None:
            near = [[cur, m] for m in free(cur) if m != nxt]
            if not near:
                return False
            best = min(near, key=rank)
        rest = self._plan(best[-1], u.goal, {(cur, nxt)}) or [best[-1]]
        u.route = [*best, *rest[1:]]
        self._grant(tick, u, best[1], "back_off", "deadlock", detail, waiting_for)
        return True

    def _break_deadlocks(self, tick: _Tick) -> None:
        """Find wait-for cycles one at a time and make one unit of each give way."""
        waiting = [u for u in self._sorted if u.waiting]
        seen: dict[tuple[str, ...], float] = {}
        if len(waiting) >= 2:
            graph = nx.DiGraph()
            for u in waiting:
                graph.add_edges_from((u.uid, b) for b in u.waiting if self._units[b].waiting)
            while graph.number_of_edges():
                try:
                    cycle = [a for a, _ in nx.find_cycle(graph)]
                except nx.NetworkXNoCycle:
                    break
                members = tuple(sorted(cycle, key=unit_order))
                retry_at = self._cycles.get(members)
                if retry_at is None:
                    self.deadlocks += 1
                loser = None
                if retry_at is None or tick.now >= retry_at:
                    loser = self._give_way(tick, cycle, members)
                    retry_at = tick.now + self.retry_s
                if loser is None:
                    seen[members] = retry_at
                graph.remove_nodes_from([loser] if loser else cycle)
        self._cycles = seen

    def _give_way(self, tick: _Tick, cycle: list[str], members: tuple[str, ...]) -> str | None:
        """Reroute or back off the cycle's loser; returns who gave way, None if nobody can."""
        text = " -> ".join([*cycle, cycle[0]])
        units = [self._units[uid] for uid in cycle if self._units[uid].edge is None]
        units.sort(key=lambda u: u.order, reverse=True)  # larger id loses ties ...
        units.sort(key=lambda u: u.priority)  # ... among the lowest priority (stable sort)
        for u in units:
            cur, nxt = u.route[0], u.route[1]
            k = cycle.index(u.uid)
            ahead = self._units[cycle[(k + 1) % len(cycle)]]  # the one u waits for
            held = self.table.nodes_of(ahead.uid)
            detail = f"deadlock {text}: rerouting around {', '.join(sorted(held))}"
            if self._detour(tick, u, set(), held - {cur}, "deadlock", detail, members):
                return u.uid
            detail = f"deadlock {text}: rerouting around {cur} -> {nxt}"
            if self._detour(tick, u, {(cur, nxt)}, {nxt}, "deadlock", detail, members):
                return u.uid
            behind = self._units[cycle[k - 1]]
            detail = f"deadlock {text}: backing off from {cur}"
            if self._back_off(tick, u, behind, detail, members):
                return u.uid
        if members not in self._cycles:
            for uid in members:
                self._say(
                    tick,
                    self._units[uid],
                    "wait",
                    "deadlock_unresolved",
                    f"deadlock {text}: no unit can give way",
                    waiting_for=members,
                )
        return None
