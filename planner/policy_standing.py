"""Lane coordination: standing units are moved out of a waiting unit's way.

A unit whose way is held by a unit standing still (parked, or with no route) does not
wait for it forever: the standing unit is moved aside to a free neighbour off the
waiting unit's route, or pushed on along it (never back toward the waiting unit), or,
with no free neighbour, one of its own standing neighbours is moved first; an idle unit
moved aside parks where it is moved to. Failing that, the waiting unit takes a route
around every parked unit if one exists. Either is tried when the wait starts and every
``retry_s`` [s] (``planner.policy_grants`` calls ``clear_way`` for a unit it cannot
grant).
"""

from __future__ import annotations

from planner.coordination_state import CoordinationState, Tick, Unit
from planner.decisions import Action, Cause


def clear_way(state: CoordinationState, tick: Tick, w: Unit, standing: list[Unit]) -> bool:
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
        if move_aside(state, tick, p, behind, set(on_route), w.uid):
            moved = True
            continue
        for q_node in sorted(state.graph.graph.successors(p.route[0])):
            holder = state.table.holder(q_node)
            q = state.units[holder] if holder is not None else None
            if q is None or q_node in on_route or q is w or not q.standing:
                continue
            if move_aside(state, tick, q, set(on_route) | {p.route[0]}, set(), w.uid):
                moved = True
                break
    return moved


def move_aside(
    state: CoordinationState,
    tick: Tick,
    p: Unit,
    never: set[str],
    rather_not: set[str],
    for_uid: str,
) -> bool:
    """Grant standing unit ``p`` the edge to a free neighbour not in ``never``.

    Preference: not in ``rather_not``, not a crossing, not a moving or waiting unit's
    goal, then edge weight and node id.
    """
    node = p.route[0]
    edges = state.graph.graph.edges
    options = [
        m
        for m in state.graph.graph.successors(node)
        if m not in never
        and not edges[node, m]["blocked"]
        and not state.table.blockers(p.uid, node, m)
    ]
    if not options:
        return False
    goals = {u.goal for u in state.sorted if not u.standing}
    step = min(
        options,
        key=lambda m: (
            m in rather_not,
            m in state.crossings,
            m in goals,
            edges[node, m]["weight"],
            m,
        ),
    )
    if state.parked.get(node) == p.uid:
        del state.parked[node]
        p.goal = step
    p.route = [node, step]
    detail = f"standing at {node}, moving aside to {step} for {for_uid}"
    state.grant(tick, p, step, Action.BACK_OFF, Cause.CLEAR_WAY, detail, (for_uid,))
    return True
