"""The congestion-free run of a scenario: the trips its fleet completes when no unit ever
waits for another.

The same trips (``Scenario.task_stream``), released at the same times, handed out by the
same dispatcher (``scenarios.run.dispatch.Dispatcher``, the scenario's ``dispatch`` rule)
to the same units, starting where the runner starts them, on the scenario's lane graph;
every trip then takes its ideal time (``scenarios.score.throughput.ideal_trip_s``: the
lane graph's shortest route, driven alone at the unit's ``DriveLimits``, plus the dwells)
from the node its unit stands at, and its unit stands at the trip's dropoff node after it.
The scenario's breakdowns stop a unit as they stop it in a run: a trip under way pauses
until the unit is repaired, and a unit broken down is not given a trip. Nothing else
happens: no other unit, obstacle, freeze or map read delays a trip.

Time runs from event to event (a release, a unit becoming free, a repair), not in sim
steps, so a trip is handed out the moment a unit and the trip are both ready (a run
dispatches at its next step, at most ``dt`` later).

``trips`` is how many trips end by ``sim_s``; trips under way then do not count. It is the
number a fleet's trips are measured against (``tests/benchmarks/fleet.py``, column
``free``): what the floor, the trips and the dispatcher allow, the same for every lane
coordinator. It is not a proof that no fleet could do more (a dispatcher that knew the
future could), but a fleet that beats it does so only where the navigator cuts a corner
the lane route goes round.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

from fleet.unit import DriveLimits
from planner.reservations import unit_order
from scenarios.run.dispatch import Dispatcher
from scenarios.run.trip_queue import TripQueue
from scenarios.score.metric_registry import feeds
from scenarios.score.throughput import ideal_trip_s
from scenarios.spec.scenario import Scenario

Span = tuple[float, float]
"""A breakdown: from, until [s] sim time."""


@dataclass(frozen=True)
class FreeRun:
    """What the congestion-free run did by ``sim_s`` [s]: ``trips`` completed, ``given``
    trips handed out (completed or under way at the end), ``ideal_s`` the completed
    trips' ideal times [s] in completion order."""

    sim_s: float
    trips: int
    given: int
    ideal_s: tuple[float, ...]


def paused_end(start: float, duration: float, spans: list[Span]) -> tuple[float, float]:
    """(start, end) [s] of ``duration`` [s] of work a unit is ready for at ``start``: put
    off to the end of a breakdown it starts in, stretched by each breakdown that begins
    while it is under way (``spans`` sorted by start)."""
    end = start + duration
    for a, b in spans:
        if a <= start < b:
            start, end = b, b + duration
        elif start < a < end:
            end += b - a
    return start, end


def breakdown_spans(scenario: Scenario) -> dict[str, list[Span]]:
    """Each unit's breakdowns (unit id -> [(from, until)] [s], sorted; every unit listed)."""
    spans: dict[str, list[Span]] = {s.unit_id: [] for s in scenario.unit_specs()}
    for b in scenario.breakdowns():
        spans.setdefault(b.unit_id, []).append((b.at, b.until))
    for unit_spans in spans.values():
        unit_spans.sort()
    return spans


def free_run(scenario: Scenario, sim_s: float | None = None) -> FreeRun:
    """The congestion-free run of ``scenario`` (module docstring) up to ``sim_s`` [s]
    (default: its duration), on its own lane graph (its ``layout.one_way`` included)."""
    end_s = float(scenario.duration if sim_s is None else sim_s)
    plan = scenario.coordination
    graph = scenario.build_lane_graph(segment_m=plan.segment_m)
    specs = {s.unit_id: s for s in scenario.unit_specs()}
    order = sorted(specs, key=unit_order)
    spans = breakdown_spans(scenario)
    node: dict[str, str] = {}
    position: dict[str, tuple[float, float]] = {}
    for spec in specs.values():  # in spec order, as the runner places them
        at = (spec.start.x, spec.start.y)
        start = graph.nearest_free_node(*at, set(node.values()))
        if start is None:
            raise ValueError(f"{scenario.name}: more units than lane graph nodes")
        node[spec.unit_id] = start
        position[spec.unit_id] = at
    free_at = dict.fromkeys(specs, 0.0)
    dispatcher = Dispatcher(
        scenario.task_stream(),
        graph,
        plan.dispatch,
        TripQueue(graph, scenario.tasks.retry_after),
    )
    events = [t.release for t in scenario.task_stream() if t.release <= end_s]
    events += [b for s in spans.values() for _, b in s if b <= end_s]
    heapq.heapify(events)
    heapq.heappush(events, 0.0)
    done: list[tuple[float, float]] = []  # (end, ideal) of each trip
    given = 0
    while events:
        now = heapq.heappop(events)
        while events and events[0] <= now + 1e-9:
            heapq.heappop(events)
        idle = {
            uid: node[uid]
            for uid in order
            if free_at[uid] <= now + 1e-9 and not any(a <= now < b for a, b in spans[uid])
        }
        for uid, task in dispatcher.match(now, idle):
            limits: DriveLimits = specs[uid].drive
            ideal = ideal_trip_s(graph, position[uid], node[uid], task, limits)
            if ideal is None:  # no route on the lane graph: the trip is never done
                continue
            given += 1
            _, finish = paused_end(now, ideal, spans[uid])
            free_at[uid] = finish
            node[uid] = graph.nearest_node(*task.dropoff)
            position[uid] = graph.position(node[uid])
            if finish <= end_s + 1e-9:
                done.append((finish, ideal))
                heapq.heappush(events, finish)
    done.sort()
    return FreeRun(end_s, len(done), given, tuple(ideal for _, ideal in done))


@feeds("trips_free_run", "trips_of_free_run")
def free_run_metrics(scenario: Scenario, sim_s: float, trips: int) -> dict[str, object]:
    """The run's ``metrics.json`` keys against its congestion-free run: how many trips that
    completes by ``sim_s`` [s] on the run's own floor, and the run's ``trips`` over it
    (None when it completes none)."""
    free = free_run(scenario, sim_s).trips
    return {
        "trips_free_run": free,
        "trips_of_free_run": round(trips / free, 4) if free else None,
    }
