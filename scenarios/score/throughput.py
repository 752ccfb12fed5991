"""Throughput of a run: trips per unit-hour, congestion-free ("ideal") trip times, and
where the units' time went (driving, or standing still and why). See docs/throughput.md.

Ideal trip time [s] (``ideal_trip_s``). The trip's route is the lane graph's shortest
route by edge ``length`` [m] (networkx over ``LaneGraph.graph``, blocked flags and costmap
penalties ignored: no congestion, no obstacles; one-way lanes respected) from the node the
trip starts from, via the pickup node (``nearest_node(*task.pickup)``), to the dropoff
node (``nearest_node(*task.dropoff)``); the unit's position at assignment is put in front
when it is more than ``at_node_m`` from that node (the runner passes the lane
coordinator's ``arrive_tol``: a unit that close to a node has arrived there). The route
is a polyline driven by one unit alone at its ``DriveLimits`` (``v`` max_speed [m/s],
``a`` max_accel [m/s^2], ``w`` max_turn_rate [rad/s]) the way this drive drives
(``fleet.unit``):

- each leg (to the pickup, then to the dropoff) from rest to rest, as fast as ``v`` and
  ``a`` allow (``leg_s``: a speed cap at every corner, a forward pass for speeding up
  and a backward pass for braking, trapezoids between; a straight leg of length ``L`` is
  ``L / v + v / a``, or ``2 sqrt(L / a)`` when too short to reach ``v``);
- a corner turning by ``theta`` is passed at the drive's ``corner_speed(theta)``; one
  sharper than ``rotate_to_heading`` at ``corner_speed(theta / 2)`` (the navigator's
  line-of-sight shortcut cuts it into two half bends); one sharper than twice that is a
  stop with a turn on the spot, ``theta / w``;
- at the pickup the unit turns on the spot from the way it came to the way it leaves
  (a turn back is pi): ``|theta| / w`` [s]; the heading it starts with is not counted;
- plus ``task.dwell`` [s] at the pickup and again at the dropoff.

The lane route's length is kept: where the floor is open enough for the navigator to
cut across it, a unit can still beat the ideal.

Returned trips (``scenarios.run.trip_queue``). A trip handed back to the queue ends its
attempt (``returned``); the ideal time, ``actual_s``, ``trip_time_ratio`` and
``fleet_efficiency`` count the attempt that completed the trip alone, its ideal from where
that attempt started. The returned attempts' time is ``returned_s`` [unit-s], beside
``trips_returned`` (attempts returned) and ``trips_retried`` (attempts at a trip returned
before).

Standing still, by cause (``standing_cause``), for a unit with a task and speed 0 over a
tick: ``breakdown`` (broken down), ``dwell`` (dwelling at a stop), ``freeze`` (no
admissible path or lane this tick), ``turn`` (turning in place), else ``traffic``
(waiting for a lane or node, starting up).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import pairwise
from typing import Protocol

import networkx as nx

from fleet.shapes import wrap_angle
from fleet.unit import DriveLimits, corner_speed
from planner.lane_graph import LaneGraph
from planner.reservations import unit_order
from scenarios.run.agents import AgentState, activity
from scenarios.run.record import Attempt, TripRecord, UnfinishedTrip
from scenarios.score.metric_registry import REGISTRY, feeds
from scenarios.spec.tasks import Task

Point = tuple[float, float]

AT_NODE_M = 0.1
"""[m] default ``at_node_m``: a unit this close to its start node stands on it (the lane
coordinator's default ``arrive_tol``)."""
WAIT_CAUSES = REGISTRY.parts("wait_s")
"""The keys of ``wait_s``, as the metric registry declares them (traffic, freeze, dwell,
breakdown, turn: ``turn`` is one beyond the four of docs/files.md)."""
STANDING_CAUSES = {"broken_down": "breakdown", "dwelling": "dwell", "frozen": "freeze"}
"""The wait cause of each ``activity`` that is one (``scenarios.run.agents.activity``)."""


class Agent(Protocol):
    """What the tracker reads of a ``TaskAgent``: until when [s] it is broken down, and
    until when it dwells at a stop (None: not dwelling)."""

    broken_until: float
    dwell_until: float | None


class Drive(Protocol):
    """What the tracker reads of a ``DriveUnit`` after a sim step: ``speed`` [m/s] and
    ``turn_rate`` [rad/s]."""

    speed: float
    turn_rate: float


def segment_s(length: float, v0: float, v1: float, limits: DriveLimits) -> float:
    """[s] to drive ``length`` [m] straight, entering at ``v0`` and leaving at ``v1``
    [m/s] (both reachable within it), as fast as max_speed and max_accel allow."""
    v, a = limits.max_speed, limits.max_accel
    peak = min(v, math.sqrt(max(a * length + (v0 * v0 + v1 * v1) / 2, 0.0)))
    ramps = (2 * peak * peak - v0 * v0 - v1 * v1) / (2 * a)  # [m] speeding up and braking
    cruise = max(length - ramps, 0.0) / peak if peak > 0 else 0.0
    return (peak - v0) / a + (peak - v1) / a + cruise


def leg_s(leg: Sequence[Point], limits: DriveLimits) -> float:
    """[s] to drive polyline ``leg`` [m] from rest to rest (module docstring): corners
    passed at the drive's ``corner_speed``, a corner sharper than ``rotate_to_heading``
    as the two half bends the navigator's shortcut makes of it, and one it cannot cut
    so (over twice ``rotate_to_heading``) stopped at and turned on the spot."""
    points = [p for k, p in enumerate(leg) if k == 0 or p != leg[k - 1]]
    lengths = [math.dist(p, q) for p, q in pairwise(points)]
    caps, turns_s = [0.0], 0.0
    for p, q, r in zip(points, points[1:], points[2:], strict=False):
        turn = abs(wrap_angle(_bearing(q, r) - _bearing(p, q)))
        if turn <= limits.rotate_to_heading:
            caps.append(corner_speed(limits, turn))
        elif turn / 2 <= limits.rotate_to_heading:
            caps.append(corner_speed(limits, turn / 2))
        else:
            caps.append(0.0)
            turns_s += turn / limits.max_turn_rate
    caps.append(0.0)
    a = limits.max_accel
    for k in range(1, len(caps)):  # speeding up from the corner before
        caps[k] = min(caps[k], math.sqrt(caps[k - 1] ** 2 + 2 * a * lengths[k - 1]))
    for k in range(len(caps) - 2, -1, -1):  # braking for the corner after
        caps[k] = min(caps[k], math.sqrt(caps[k + 1] ** 2 + 2 * a * lengths[k]))
    driving = sum(segment_s(s, caps[k], caps[k + 1], limits) for k, s in enumerate(lengths))
    return driving + turns_s


def drive_s(legs: Sequence[Sequence[Point]], limits: DriveLimits) -> float:
    """[s] to drive ``legs`` (polylines [m], each ending at a stop, each starting where
    the one before ends) alone at ``limits``, plus the turn on the spot between one leg's
    last stretch and the next one's first (module docstring)."""
    total, heading = 0.0, None
    for leg in legs:
        points = [p for k, p in enumerate(leg) if k == 0 or p != leg[k - 1]]
        if len(points) < 2:
            continue
        if heading is not None:  # turn on the spot at the stop between the legs
            total += abs(wrap_angle(_bearing(points[0], points[1]) - heading)) / (
                limits.max_turn_rate
            )
        total += leg_s(points, limits)
        heading = _bearing(points[-2], points[-1])
    return total


def _bearing(p: Point, q: Point) -> float:
    return math.atan2(q[1] - p[1], q[0] - p[0])


def trip_legs(
    graph: LaneGraph, start: Point, node: str, task: Task, at_node_m: float = AT_NODE_M
) -> list[list[Point]] | None:
    """The ideal route [m] of ``task`` for a unit at ``start`` given it at ``node``: the
    leg to the pickup node and the leg on to the dropoff node, ``start`` in front if it is
    more than ``at_node_m`` [m] from ``node``; None when the lane graph has no route."""
    pickup = graph.nearest_node(*task.pickup)
    dropoff = graph.nearest_node(*task.dropoff)
    try:
        legs = [
            [graph.position(n) for n in nx.shortest_path(graph.graph, a, b, weight="length")]
            for a, b in ((node, pickup), (pickup, dropoff))
        ]
    except nx.NetworkXNoPath:
        return None
    if math.dist(start, legs[0][0]) > at_node_m:
        legs[0].insert(0, (float(start[0]), float(start[1])))
    return legs


def ideal_trip_s(
    graph: LaneGraph,
    start: Point,
    node: str,
    task: Task,
    limits: DriveLimits,
    at_node_m: float = AT_NODE_M,
) -> float | None:
    """[s] the congestion-free time of ``task`` for a unit at ``start`` [m] given it at
    ``node`` (module docstring, ``trip_legs``); None with no route."""
    legs = trip_legs(graph, start, node, task, at_node_m)
    return None if legs is None else drive_s(legs, limits) + 2.0 * task.dwell


def standing_cause(now: float, agent: Agent, state: AgentState, drive: Drive) -> str:
    """Why a unit with a task stands still at ``now`` [s] (one of ``WAIT_CAUSES``)."""
    cause = STANDING_CAUSES.get(activity(now, agent, state))
    if cause is not None:
        return cause
    if abs(drive.turn_rate) > 0:
        return "turn"
    return "traffic"


class ThroughputTracker:
    """Collects a run's trips and unit-ticks; ``metrics`` gives the throughput keys.

    graph: the run's lane graph; dt: [s] the sim step, the time one unit-tick stands for;
    at_node_m: [m] how close to its start node a unit stands on it (``trip_legs``).
    """

    def __init__(self, graph: LaneGraph, dt: float, at_node_m: float = AT_NODE_M) -> None:
        self.graph = graph
        self.dt = float(dt)
        self.at_node_m = float(at_node_m)
        self.trips: list[TripRecord] = []
        self.wait_s = dict.fromkeys(WAIT_CAUSES, 0.0)
        self.retried = 0
        self._open: dict[str, tuple[str, float, float | None]] = {}  # task -> unit, start, ideal
        self._returned: dict[str, list[Attempt]] = {}  # task id -> its returned attempts
        self._task_ticks = self._task_moving_ticks = self._moving_ticks = 0
        self._moving_speed = 0.0  # [m/s] summed over moving unit-ticks

    def assigned(
        self,
        position: Point,
        node: str,
        task: Task,
        now: float,
        limits: DriveLimits,
        unit_id: str = "",
    ) -> None:
        """Unit ``unit_id`` at ``position`` [m] is given ``task`` at ``now`` [s], starting
        from ``node``, with drive ``limits``."""
        ideal = ideal_trip_s(self.graph, position, node, task, limits, self.at_node_m)
        self._open[task.task_id] = (unit_id, now, ideal)
        if task.task_id in self._returned:
            self.retried += 1

    def returned(self, task: Task, now: float, cause: str) -> None:
        """``task``'s attempt ends at ``now`` [s]: returned to the queue for ``cause``."""
        unit_id, start, _ = self._open.pop(task.task_id)
        attempt = Attempt(unit_id, start, now, "returned", cause)
        self._returned.setdefault(task.task_id, []).append(attempt)

    def observe(
        self, unit_id: str, now: float, agent: Agent, state: AgentState, drive: Drive
    ) -> None:
        """Unit ``unit_id`` after its agent's step at ``now`` [s]: ``state`` (a completed
        task is recorded) and ``drive`` (its speed over the sim step that led here)."""
        if state.task_done is not None:
            task_id = state.task_done.task_id
            _, assigned, ideal = self._open.pop(task_id)
            returned = tuple(self._returned.pop(task_id, ()))
            self.trips.append(TripRecord(task_id, unit_id, assigned, now, ideal, returned))
        if drive.speed > 0:
            self._moving_ticks += 1
            self._moving_speed += drive.speed
        if not state.has_task:
            return
        self._task_ticks += 1
        if drive.speed > 0:
            self._task_moving_ticks += 1
        else:
            self.wait_s[standing_cause(now, agent, state, drive)] += self.dt

    def unfinished(self) -> list[UnfinishedTrip]:
        """The trips returned at least once and not completed, by their first attempt's
        start (then task id); an attempt still under way is ``open``."""
        trips = []
        for task_id, attempts in self._returned.items():
            tail = self._open.get(task_id)
            last = () if tail is None else (Attempt(tail[0], tail[1], None, "open"),)
            trips.append(UnfinishedTrip(task_id, (*attempts, *last)))
        return sorted(trips, key=lambda t: (t.attempts[0].start, unit_order(t.task_id)))

    def returned_attempts(self) -> list[Attempt]:
        """Every returned attempt: of completed trips, then of unfinished ones."""
        done = [a for t in self.trips for a in t.returned]
        return done + [a for attempts in self._returned.values() for a in attempts]

    @feeds(
        "trips_per_unit_hour", "ideal_trip_s", "trip_time_ratio", "fleet_efficiency",
        "moving_share", "mean_speed_moving", "wait_s", "trips_returned", "trips_retried",
        "returned_s",
    )  # fmt: skip
    def metrics(self, units: int, sim_seconds: float) -> dict[str, object]:
        """The throughput keys of ``metrics.json`` for ``units`` units over ``sim_seconds``
        [s] (docs/throughput.md); None where a mean has nothing to average."""
        unit_s = units * sim_seconds
        returned = self.returned_attempts()
        ideal = [t.ideal_s for t in self.trips if t.ideal_s is not None]
        ratios = [t.actual_s / t.ideal_s for t in self.trips if t.ideal_s]
        return {
            "trips_per_unit_hour": _ratio(len(self.trips) * 3600.0, unit_s, 3),
            "ideal_trip_s": _ratio(sum(ideal), len(ideal), 3),
            "trip_time_ratio": _ratio(sum(ratios), len(ratios), 4),
            "fleet_efficiency": _ratio(sum(ideal), unit_s, 4),
            "moving_share": _ratio(self._task_moving_ticks, self._task_ticks, 4),
            "mean_speed_moving": _ratio(self._moving_speed, self._moving_ticks, 4),
            "wait_s": {cause: round(s, 3) for cause, s in self.wait_s.items()},
            "trips_returned": len(returned),
            "trips_retried": self.retried,
            "returned_s": round(sum((a.seconds for a in returned), 0.0), 3),
        }


def _ratio(num: float, den: float, decimals: int) -> float | None:
    """``num / den`` rounded; None when ``den`` is 0."""
    return round(num / den, decimals) if den else None
