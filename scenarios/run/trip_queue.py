"""Blocked work goes back: a trip that has had no route for ``return_after`` [s] is handed
back to the queue, held there until its goal is reachable or ``retry_after`` [s] have
passed, and its unit takes other work (issue 26: a tote dropped on a storage slot held
every trip to that slot, and the four units holding them stood frozen for two minutes).

The rule, in three parts; ``tasks.return_after`` and ``tasks.retry_after`` are the
scenario file's knobs (docs/scenarios.md):

1. **No route** (``ReturnWatch.cause``). A unit's trip has no route in a tick when the
   unit has not picked up yet (after the pickup it carries the load and keeps the trip),
   is not broken down and not dwelling, and either the lane coordinator has no route to
   its goal (state ``no_route``: cause ``no_route``) or the goal node's cell is inscribed
   or lethal in the costmap the units read (cause ``goal_blocked``: no unit can stand
   there, even while its lanes still read clear).
2. **Returned** (``ReturnWatch.due``). Once that has held at every tick for
   ``return_after`` [s] (a tick with a route starts the count again), the trip is
   returned at the first tick its unit stands at a node or drives to one (not while it
   turns back off a blocked lane); the unit parks there (``TaskAgent.give_back``), is
   idle, and the dispatcher may hand it other work in the same tick.
3. **Retried** (``TripQueue``). The returned trip goes to the back of the queue (behind
   every trip released by the time of its return) and its goal, the pickup node, is
   *held*: no trip to it, returned or new, is handed out until an unblocked lane leads
   into it (``goal_reachable``, the lane graph as the coordinator last read it) or
   ``retry_after`` [s] have passed since the last return there. A hold that times out
   lets one trip to the goal go and starts again, so a goal blocked for good costs one
   attempt of ``return_after`` per ``return_after + retry_after``, not one per unit or per
   trip. The unit that returned a trip is not given it back before ``retry_after`` has
   passed (its own position may have been what had no route).

Defaults. ``return_after`` 30 s: long enough for a passing block to be waited out (a
person crossing a lane takes seconds; the lane coordinator re-reads the lanes every
second and re-plans a unit with no route whenever they change; by 19 s the navigator's
recovery, ``planner.navigator``, has turned to look again three times and reached its
capped 8 s wait), and shorter than one trip (the shipped warehouses' ideal trips take 30
to 70 s, dropped_tote's 53 s on average), so a blocked trip costs its unit less than a
trip's work. Open-RMF's fleet adapters call ``reassign_dispatched_tasks()`` every
``reassign_task_interval`` (120 s in rmf_demos' fleet configs): a periodic re-allocation
of tasks that last minutes (0.5 m/s robots across a building), not a trigger on a block;
at these trips' scale 120 s would be most of a scenario. ``retry_after`` 60 s: once a
trip has come back from a goal that stays blocked, the goal is tried again about once in
90 s (a third of one unit's time at most), and a goal that clears is retried as soon as
its lanes read clear.

Determinism: units in the episode's order, trips in queue order; ``now`` is sim time.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Iterator
from typing import TYPE_CHECKING, Protocol

import numpy as np

from mapserver.core.costvalues import INSCRIBED, LETHAL

if TYPE_CHECKING:
    from mapserver.core.geometry import GridGeometry
    from planner.coordinator import UnitStatus
    from planner.lane_graph import LaneGraph
    from scenarios.spec.tasks import Task

DEFAULT_RETURN_AFTER_S = 30.0
"""[s] how long a trip may have no route before it is returned (module docstring)."""
DEFAULT_RETRY_AFTER_S = 60.0
"""[s] how long a returned trip's goal is held unless its lanes clear (module docstring)."""
NO_ROUTE = "no_route"
GOAL_BLOCKED = "goal_blocked"
CAUSES = (NO_ROUTE, GOAL_BLOCKED)
"""Why a trip was returned (``Attempt.cause``)."""


class Agent(Protocol):
    """What the rule reads of a ``TaskAgent``."""

    task: Task | None
    broken_until: float

    @property
    def carrying(self) -> bool: ...

    @property
    def dwell_until(self) -> float | None: ...


def goal_node(graph: LaneGraph, task: Task) -> str:
    """The node a trip's unit drives to first: its pickup's."""
    return graph.nearest_node(*task.pickup)


def goal_reachable(graph: LaneGraph, node: str) -> bool:
    """Does an unblocked lane lead into ``node`` (the lane graph as last read)?"""
    return any(not d["blocked"] for _, _, d in graph.graph.in_edges(node, data=True))


class ReturnWatch:
    """Per unit, since when its trip has had no route (parts 1 and 2 of the module
    docstring); ``return_after`` [s] (None: trips are never returned)."""

    def __init__(
        self, return_after: float | None, graph: LaneGraph, geometry: GridGeometry
    ) -> None:
        self.return_after = return_after
        self.graph = graph
        self.geometry = geometry
        self._since: dict[str, float] = {}

    def cause(
        self, now: float, agent: Agent, status: UnitStatus | None, costs: np.ndarray
    ) -> str | None:
        """Why ``agent``'s trip has no route at ``now`` [s] (``CAUSES``), None if it has one
        or the rule does not apply; ``status``: its unit's ``LaneCoordinator.status``."""
        if agent.task is None or status is None or agent.carrying or now < agent.broken_until:
            return None
        if agent.dwell_until is not None:
            return None
        if status.state == "no_route":
            return NO_ROUTE
        col, row = self.geometry.world_to_cell(*self.graph.position(status.goal))
        if 0 <= row < costs.shape[0] and 0 <= col < costs.shape[1]:
            if costs[row, col] in (INSCRIBED, LETHAL):
                return GOAL_BLOCKED
        return None

    def due(
        self,
        now: float,
        unit_id: str,
        agent: Agent,
        status: UnitStatus | None,
        costs: np.ndarray,
    ) -> str | None:
        """The cause when ``unit_id``'s trip is to be returned now, else None."""
        cause = None if self.return_after is None else self.cause(now, agent, status, costs)
        if cause is None:
            self._since.pop(unit_id, None)
            return None
        since = self._since.setdefault(unit_id, now)
        assert status is not None  # a cause needs one
        if now - since < self.return_after - 1e-9 or (status.node or status.target) is None:
            return None
        del self._since[unit_id]
        return cause


class TripQueue:
    """Trips waiting for a unit, oldest first: new ones by release, returned ones by the
    time of their return; goals held after a return (part 3 of the module docstring).

    graph: the run's lane graph (goals and their lanes); retry_after [s].
    """

    def __init__(self, graph: LaneGraph, retry_after: float = DEFAULT_RETRY_AFTER_S) -> None:
        self.graph = graph
        self.retry_after = float(retry_after)
        self._queue: list[tuple[float, int, Task]] = []  # (in line since, arrival, trip)
        self._count = itertools.count()
        self._held: dict[str, float] = {}  # goal node -> held until [s]
        self._returned_by: dict[str, tuple[str, float]] = {}  # task id -> unit, at [s]
        self._goal: dict[str, str] = {}  # task id -> goal node

    def __len__(self) -> int:
        return len(self._queue)

    def add(self, task: Task) -> None:
        """A new trip of the stream, in line from its release."""
        self._insert(task.release, task)

    def give_back(self, task: Task, unit_id: str, now: float) -> None:
        """``unit_id`` returns ``task`` at ``now`` [s]: back of the line, its goal held."""
        self._insert(now, task)
        self._held[self.goal(task)] = now + self.retry_after
        self._returned_by[task.task_id] = (unit_id, now)

    def released(self, now: float) -> Iterator[Task]:
        """The trips released by ``now`` [s], in line order (a snapshot: ``take`` may be
        called meanwhile)."""
        return iter([task for since, _, task in self._queue if task.release <= now])

    def ready(self, task: Task, now: float) -> bool:
        """May ``task`` be handed out at ``now`` [s]: its goal is not held, reachable, or
        its hold has timed out?"""
        goal = self.goal(task)
        until = self._held.get(goal)
        if until is None:
            return True
        if goal_reachable(self.graph, goal):
            del self._held[goal]
            return True
        return now >= until - 1e-9

    def allows(self, task: Task, unit_id: str, now: float) -> bool:
        """May ``unit_id`` take ``task`` at ``now`` [s] (not the unit that just returned it)?"""
        returned = self._returned_by.get(task.task_id)
        return returned is None or returned[0] != unit_id or now >= returned[1] + self.retry_after

    def take(self, task: Task, now: float) -> None:
        """``task`` is handed out at ``now`` [s]; a timed-out hold on its goal starts again."""
        self._queue = [e for e in self._queue if e[2].task_id != task.task_id]
        goal = self.goal(task)
        if goal in self._held:
            self._held[goal] = now + self.retry_after

    def waiting(self) -> int:
        """How many queued trips go to goals not held now."""
        return sum(1 for _, _, task in self._queue if self.goal(task) not in self._held)

    def goal(self, task: Task) -> str:
        """``goal_node`` of ``task`` (cached)."""
        node = self._goal.get(task.task_id)
        if node is None:
            node = self._goal[task.task_id] = goal_node(self.graph, task)
        return node

    def _insert(self, since: float, task: Task) -> None:
        bisect.insort(self._queue, (since, next(self._count), task), key=lambda e: e[:2])
