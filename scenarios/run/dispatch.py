"""Which idle unit gets which released trip.

Two rules, both deterministic:

- ``first``: a trip goes to whichever idle unit asks first (units ask in natural id
  order each tick), the oldest released trip first;
- ``nearest`` (the default): each released trip, oldest first, goes to the idle unit
  nearest its pickup over the lane graph (route length [m] by edge ``length``, lanes one
  way where they are; ties by unit id): the "nearest vehicle" dispatching rule of
  Egbelu and Tanchoco, *Characterization of automatic guided vehicle dispatching rules*,
  International Journal of Production Research 22(3), 1984. It shortens the empty drive
  to the pickup, which is pure overhead for the fleet.

A trip meant for one unit (``Task.unit``) only ever goes to that unit. A trip returned by
its unit (no route to its goal) waits in the queue by the rules of
``scenarios.run.trip_queue``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping

import networkx as nx

from planner.lane_graph import LaneGraph
from planner.reservations import unit_order
from scenarios.run.trip_queue import TripQueue
from scenarios.spec.coordination import DISPATCH_RULES as RULES
from scenarios.spec.tasks import Task

LOOK_AHEAD = 64
"""How many trips of the stream are read ahead of their release (not counting those to a
held goal)."""


class Dispatcher:
    """Hands released trips of ``stream`` to idle units on ``graph`` by ``rule``; ``queue``
    holds them meanwhile (default: ``TripQueue(graph)``)."""

    def __init__(
        self,
        stream: Iterator[Task],
        graph: LaneGraph,
        rule: str = "nearest",
        queue: TripQueue | None = None,
    ) -> None:
        if rule not in RULES:
            raise ValueError(f"dispatch rule must be one of {RULES}, got {rule!r}")
        self._stream = stream
        self._graph = graph
        self._reverse = graph.graph.reverse(copy=False)
        self.rule = rule
        self.queue = TripQueue(graph) if queue is None else queue
        self._exhausted = False
        self._to_node: dict[str, dict[str, float]] = {}  # pickup node -> node -> [m]

    def match(self, now: float, idle: Mapping[str, str]) -> list[tuple[str, Task]]:
        """Trips released by ``now`` [s] for the ``idle`` units (unit id -> the node its
        trip would start from): (unit id, trip) pairs, each unit and trip at most once."""
        self._read_ahead()
        free = sorted(idle, key=unit_order)
        pairs: list[tuple[str, Task]] = []
        for task in self.queue.released(now):
            if not free:
                break
            if not self.queue.ready(task, now):
                continue
            candidates = [
                u for u in free if task.unit in (None, u) and self.queue.allows(task, u, now)
            ]
            if not candidates:
                continue
            if self.rule == "first":
                uid = candidates[0]
            else:
                distance = self._distances(task)
                uid = min(candidates, key=lambda u: distance.get(idle[u], math.inf))
            free.remove(uid)
            self.queue.take(task, now)
            pairs.append((uid, task))
        return pairs

    def give_back(self, task: Task, unit_id: str, now: float) -> None:
        """``unit_id`` returns ``task`` at ``now`` [s] (``TripQueue.give_back``)."""
        self.queue.give_back(task, unit_id, now)

    def _read_ahead(self) -> None:
        while not self._exhausted and self.queue.waiting() < LOOK_AHEAD:
            task = next(self._stream, None)
            if task is None:
                self._exhausted = True
            else:
                self.queue.add(task)

    def _distances(self, task: Task) -> dict[str, float]:
        """[m] from every node to the trip's pickup node over the lane graph (cached)."""
        pickup = self._graph.nearest_node(*task.pickup)
        if pickup not in self._to_node:
            self._to_node[pickup] = nx.single_source_dijkstra_path_length(
                self._reverse, pickup, weight="length"
            )
        return self._to_node[pickup]
