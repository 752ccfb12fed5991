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
2. else backed off: to the nearest node within ``back_off_hops`` edges, over edges it
   could be granted now, where it may stop (not a crossing), preferring one off the
   route of the unit waiting for it, then the node it came from; it replans from there;
3. else the next unit of the cycle is tried. A cycle nobody can leave is recorded once
   as an unresolved wait and tried again every ``retry_s`` [s].
"""

from __future__ import annotations

import networkx as nx

from planner.coordination_state import CoordinationState, Tick, Unit
from planner.decisions import Action, Cause
from planner.policy import CoordinationPolicy
from planner.reservations import unit_order


class Deadlocks(CoordinationPolicy):
    """Finds wait-for cycles after the tick's grants and breaks each (module docstring).

    retry_s [s]: how often an unresolved cycle is tried again; back_off_hops [edges]:
    how far a backing-off unit looks for a place to stop.
    """

    name = "deadlocks"

    def __init__(self, retry_s: float, back_off_hops: int) -> None:
        self.retry_s = retry_s
        self.back_off_hops = back_off_hops
        self._cycles: dict[tuple[str, ...], float] = {}  # unresolved cycle -> next attempt

    def settle(self, state: CoordinationState, tick: Tick) -> None:
        """Find wait-for cycles one at a time and make one unit of each give way."""
        waiting = [u for u in state.sorted if u.waiting]
        seen: dict[tuple[str, ...], float] = {}
        if len(waiting) >= 2:
            graph = nx.DiGraph()
            for u in waiting:
                graph.add_edges_from((u.uid, b) for b in u.waiting if state.units[b].waiting)
            while graph.number_of_edges():
                try:
                    cycle = [a for a, _ in nx.find_cycle(graph)]
                except nx.NetworkXNoCycle:
                    break
                members = tuple(sorted(cycle, key=unit_order))
                retry_at = self._cycles.get(members)
                if retry_at is None:
                    state.deadlocks += 1
                loser = None
                if retry_at is None or tick.now >= retry_at:
                    loser = self._give_way(state, tick, cycle, members)
                    retry_at = tick.now + self.retry_s
                if loser is None:
                    seen[members] = retry_at
                graph.remove_nodes_from([loser] if loser else cycle)
        self._cycles = seen

    def _give_way(
        self, state: CoordinationState, tick: Tick, cycle: list[str], members: tuple[str, ...]
    ) -> str | None:
        """Reroute or back off the cycle's loser; returns who gave way, None if nobody can."""
        text = " -> ".join([*cycle, cycle[0]])
        units = [state.units[uid] for uid in cycle if state.units[uid].edge is None]
        units.sort(key=lambda u: u.order, reverse=True)  # larger id loses ties ...
        units.sort(key=lambda u: u.priority)  # ... among the lowest priority (stable sort)
        for u in units:
            cur, nxt = u.route[0], u.route[1]
            k = cycle.index(u.uid)
            ahead = state.units[cycle[(k + 1) % len(cycle)]]  # the one u waits for
            held = state.table.nodes_of(ahead.uid)
            detail = f"deadlock {text}: rerouting around {', '.join(sorted(held))}"
            if state.detour(tick, u, set(), held - {cur}, Cause.DEADLOCK, detail, members):
                return u.uid
            detail = f"deadlock {text}: rerouting around {cur} -> {nxt}"
            if state.detour(tick, u, {(cur, nxt)}, {nxt}, Cause.DEADLOCK, detail, members):
                return u.uid
            behind = state.units[cycle[k - 1]]
            detail = f"deadlock {text}: backing off from {cur}"
            if self._back_off(state, tick, u, behind, detail, members):
                return u.uid
        if members not in self._cycles:
            for uid in members:
                state.say(
                    tick,
                    state.units[uid],
                    Action.WAIT,
                    Cause.DEADLOCK_UNRESOLVED,
                    f"deadlock {text}: no unit can give way",
                    waiting_for=members,
                )
        return None

    def _back_off(
        self,
        state: CoordinationState,
        tick: Tick,
        u: Unit,
        behind: Unit,
        detail: str,
        waiting_for: tuple[str, ...],
    ) -> bool:
        """Move aside to the nearest free place to stop, then replan from there.

        Searches breadth-first, up to ``back_off_hops`` edges, over edges ``u`` could be
        granted now, for a node that is not a crossing. Preference: fewest hops, then off
        the route of ``behind`` (the unit of the cycle waiting for ``u``), then the node
        ``u`` came from, then weight and node id. With no such node, any free neighbour
        other than the contested one will do.
        """
        cur, nxt = u.route[0], u.route[1]
        in_way = set(behind.route)
        edges = state.graph.graph.edges

        def free(a: str) -> list[str]:
            return [
                m
                for m in state.graph.graph.successors(a)
                if not edges[a, m]["blocked"] and not state.table.blockers(u.uid, a, m)
            ]

        def rank(path: list[str]) -> tuple[object, ...]:
            m = path[-1]
            return (m in in_way, m != u.prev, state.graph.route_length(path), m)

        paths = [[cur]]
        seen = {cur}
        best: list[str] | None = None
        for _ in range(self.back_off_hops):
            paths = [[*p, m] for p in paths for m in free(p[-1]) if m not in seen]
            seen.update(p[-1] for p in paths)
            stops = [p for p in paths if p[-1] not in state.crossings]
            if stops:
                best = min(stops, key=rank)
                break
        if best is None:
            near = [[cur, m] for m in free(cur) if m != nxt]
            if not near:
                return False
            best = min(near, key=rank)
        rest = state.plan(best[-1], u.goal, {(cur, nxt)}) or [best[-1]]
        u.route = [*best, *rest[1:]]
        state.grant(tick, u, best[1], Action.BACK_OFF, Cause.DEADLOCK, detail, waiting_for)
        return True
