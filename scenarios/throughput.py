"""Throughput of a run: trips per unit-hour, congestion-free ("ideal") trip times, and
where the units' time went (driving, or standing still and why). See docs/throughput.md.

Ideal trip time [s] (``ideal_trip_s``). The trip's route is the lane graph's shortest
route by edge ``length`` [m] (networkx over ``LaneGraph.graph``, blocked flags and costmap
penalties ignored: no congestion, no obstacles; one-way lanes respected) from the node the
trip starts from, via the pickup node (``nearest_node(*task.pickup)``), to the dropoff
node (``nearest_node(*task.dropoff)``); the unit's position at assignment is put in front
when it is more than ``at_node_m`` from that node (the runner passes the lane
coordinator's ``arrive_tol``: a unit that close to a node has arrived there). The route
is a polyline driven by one unit alone at its ``DriveLimits``:

- the polyline is cut into straight runs at every corner turning by more than
  ``CORNER_RAD``, and at the pickup (where the unit stops to dwell);
- each run of length ``L`` [m] is driven from rest to rest, trapezoidal speed profile
  (``run_s``): ``L / v + v / a`` if ``L >= v^2 / a``, else triangular ``2 sqrt(L / a)``
  (``v`` max_speed [m/s], ``a`` max_accel [m/s^2]);
- at each corner, the pickup included, the unit turns in place by the corner's angle
  ``|theta|`` [rad] (a turn back is pi) at max_turn_rate: ``|theta| / max_turn_rate`` [s];
  the heading it starts with is not counted;
- plus ``task.dwell`` [s] at the pickup and again at the dropoff.

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
from fleet.unit import DriveLimits
from planner.lane_graph import LaneGraph
from scenarios.agents import AgentState
from scenarios.record import TripRecord
from scenarios.tasks import Task

Point = tuple[float, float]

CORNER_RAD = 1e-6
"""[rad] a polyline vertex turning by more than this is a corner (stop, turn in place)."""
AT_NODE_M = 0.1
"""[m] default ``at_node_m``: a unit this close to its start node stands on it (the lane
coordinator's default ``arrive_tol``)."""
WAIT_CAUSES = ("traffic", "freeze", "dwell", "breakdown", "turn")
"""The keys of ``wait_s``; ``turn`` is one beyond the four of CONTRACT section 3."""


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


def run_s(length: float, limits: DriveLimits) -> float:
    """[s] to drive ``length`` [m] straight from rest to rest at ``limits`` (trapezoidal
    speed profile, triangular when too short to reach max_speed)."""
    v, a = limits.max_speed, limits.max_accel
    if length >= v * v / a:
        return length / v + v / a
    return 2.0 * math.sqrt(max(length, 0.0) / a)


def drive_s(legs: Sequence[Sequence[Point]], limits: DriveLimits) -> float:
    """[s] to drive ``legs`` (polylines [m], each ending at a stop, each starting where
    the one before ends) alone at ``limits``: straight runs between corners and stops,
    plus the turns in place at corners and between legs (module docstring)."""
    total, run, heading = 0.0, 0.0, None
    for leg in legs:
        for (x0, y0), (x1, y1) in pairwise(leg):
            length = math.hypot(x1 - x0, y1 - y0)
            if length == 0.0:
                continue
            bearing = math.atan2(y1 - y0, x1 - x0)
            turn = 0.0 if heading is None else abs(wrap_angle(bearing - heading))
            if turn > CORNER_RAD:
                total += run_s(run, limits) + turn / limits.max_turn_rate
                run = 0.0
            heading, run = bearing, run + length
        total += run_s(run, limits)  # stop at the leg's end
        run = 0.0
    return total


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
    if now < agent.broken_until:
        return "breakdown"
    if agent.dwell_until is not None and now < agent.dwell_until:
        return "dwell"
    if state.blocked_reason is not None:
        return "freeze"
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
        self._open: dict[str, tuple[float, float | None]] = {}  # task id -> assigned, ideal
        self._task_ticks = self._task_moving_ticks = self._moving_ticks = 0
        self._moving_speed = 0.0  # [m/s] summed over moving unit-ticks

    def assigned(
        self, position: Point, node: str, task: Task, now: float, limits: DriveLimits
    ) -> None:
        """A unit at ``position`` [m] is given ``task`` at ``now`` [s], starting from
        ``node``, with drive ``limits``."""
        ideal = ideal_trip_s(self.graph, position, node, task, limits, self.at_node_m)
        self._open[task.task_id] = (now, ideal)

    def observe(
        self, unit_id: str, now: float, agent: Agent, state: AgentState, drive: Drive
    ) -> None:
        """Unit ``unit_id`` after its agent's step at ``now`` [s]: ``state`` (a completed
        task is recorded) and ``drive`` (its speed over the sim step that led here)."""
        if state.task_done is not None:
            assigned, ideal = self._open.pop(state.task_done.task_id)
            self.trips.append(TripRecord(state.task_done.task_id, unit_id, assigned, now, ideal))
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

    def metrics(self, units: int, sim_seconds: float) -> dict[str, object]:
        """The throughput keys of ``metrics.json`` for ``units`` units over ``sim_seconds``
        [s] (docs/throughput.md); None where a mean has nothing to average."""
        unit_s = units * sim_seconds
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
        }


def _ratio(num: float, den: float, decimals: int) -> float | None:
    """``num / den`` rounded; None when ``den`` is 0."""
    return round(num / den, decimals) if den else None
