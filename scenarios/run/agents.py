"""A unit's task loop: pick trips over the lane graph, granted by the lane coordinator,
driven by the unit's navigator on the shared costmap.

Per tick the runner calls ``LaneCoordinator.tick`` once for every unit, then each
agent's ``step``. An agent with a task drives toward the node the coordinator granted it
(``UnitStatus.target``), planning locally on the costmap (``UnitNavigator``); at each stop
of its trip (pickup, then dropoff) it dwells, then asks for the next leg. Why a unit
stands still is reported (``AgentState``), so freezes can be told from traffic:

- no admissible path on the costmap to the granted node: ``no path ...`` (a freeze);
- no lane to its goal, or stranded on a lane that became blocked: ``no lane ...`` (a
  freeze);
- waiting for a lane or node another unit holds: traffic, not a freeze;
- dwelling at a stop, broken down, or without a task: not a freeze.

``activity`` names what a unit does in a tick in the words of the map server's unit
states (``mapserver.api.schemas.Activity``), for the live viewer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.coordinator import LaneCoordinator
from planner.freeze import LaneBlock
from planner.lane_graph import LaneGraph
from planner.navigator import Command, UnitNavigator
from scenarios.score.lane_evidence import lane_block
from scenarios.spec.tasks import Task

Point = tuple[float, float]


@dataclass(frozen=True)
class AgentState:
    """What the agent did this tick: the drive command, whether it has a task, and the
    reason it stands still when nothing admissible was found (None otherwise), the
    points that blocked it, and ``lane_block`` when the lane coordinator holds it (a lane
    freeze: ``blocking`` are then its lanes' first blocked cells)."""

    command: Command
    has_task: bool
    blocked_reason: str | None
    blocking: tuple[Point, ...]
    goal: Point | None
    task_done: Task | None = None
    lane_block: LaneBlock | None = None


class TaskAgent:
    """One unit's trips (see the module docstring).

    replan_s: [s] how often the navigator replans while driving a granted edge.
    """

    def __init__(
        self,
        unit_id: str,
        graph: LaneGraph,
        coordinator: LaneCoordinator,
        navigator: UnitNavigator,
        priority: float = 0.0,
        replan_s: float = 0.5,
    ) -> None:
        self.unit_id = unit_id
        self.graph = graph
        self.coordinator = coordinator
        self.navigator = navigator
        self.priority = priority
        self.replan_s = replan_s
        self.task: Task | None = None
        self._leg = 0  # 0: to pickup, 1: to dropoff
        self._dwell_until: float | None = None
        self._target: str | None = None
        self._last_plan = -math.inf
        self._command = Command("idle")
        self.broken_until = -math.inf

    def assign(self, task: Task, now: float, node: str) -> None:
        """Start ``task`` from ``node`` (where the unit stands)."""
        self.task = task
        self._leg = 0
        self._dwell_until = None
        self._request(node, task.pickup, now)

    def give_back(self, now: float, node: str) -> Task:
        """Drop the trip (it goes back to the queue, ``scenarios.run.trip_queue``) and park
        at ``node``, where the unit stands or drives to; returns the trip."""
        task, self.task = self.task, None
        if task is None:
            raise ValueError(f"unit {self.unit_id!r} has no trip to give back")
        self._leg, self._dwell_until = 0, None
        self.coordinator.request(self.unit_id, node, node, self.priority, now)
        self._target = None
        return task

    @property
    def carrying(self) -> bool:
        """Has the unit picked its trip's load up (it drives to the dropoff)?"""
        return self.task is not None and self._leg == 1

    def _request(self, node: str, point: Point, now: float) -> None:
        goal = self.graph.nearest_node(*point)
        self.coordinator.request(self.unit_id, node, goal, self.priority, now)
        self._target = None

    @property
    def goal(self) -> Point | None:
        if self.task is None:
            return None
        return self.task.pickup if self._leg == 0 else self.task.dropoff

    def step(self, now: float, position: Point, costs: np.ndarray) -> AgentState:
        """This tick's command for the unit at ``position`` [m] on ``costs``."""
        if now < self.broken_until:
            return AgentState(Command("stop"), self.task is not None, None, (), self.goal)
        if self.task is None:  # parked; the coordinator may still move it aside
            status = self.coordinator.status(self.unit_id)
            if status.target is None:
                return AgentState(Command("idle"), False, None, (), None)
            return self._drive(now, position, costs, status.target, has_task=False)
        if self._dwell_until is not None:
            if now < self._dwell_until:
                return AgentState(Command("stop"), True, None, (), self.goal)
            return self._next_leg(now)
        status = self.coordinator.status(self.unit_id)
        if status.state == "idle":  # parked at this leg's goal node
            self._dwell_until = now + self.task.dwell
            return AgentState(Command("stop"), True, None, (), self.goal)
        if status.state in ("no_route", "stranded"):
            reason = f"no lane to {_fmt(self.goal)}" if status.state == "no_route" else (
                "stranded on a blocked lane")  # fmt: skip
            block = lane_block(self.coordinator, self.graph, self.unit_id)
            points = block.points if block is not None else ()
            return AgentState(Command("stop"), True, reason, points, self.goal, lane_block=block)
        if status.target is None:  # waiting for traffic
            return AgentState(Command("stop"), True, None, (), self.goal)
        return self._drive(now, position, costs, status.target, has_task=True)

    def _drive(
        self, now: float, position: Point, costs: np.ndarray, target: str, has_task: bool
    ) -> AgentState:
        """Plan (every ``replan_s``) and drive toward the granted node ``target``."""
        if target != self._target:
            self._target = target
            self.navigator.set_route([self.graph.position(target)], now, "lane granted")
            self._last_plan = -math.inf
        if now - self._last_plan >= self.replan_s or self._command.kind != "follow":
            self._command = self.navigator.step(now, position, costs)
            self._last_plan = now
        command = self._command
        blocked = command.reason if command.kind in ("stop", "rotate") and has_task else None
        return AgentState(command, has_task, blocked, command.blocking, self.goal)

    def _next_leg(self, now: float) -> AgentState:
        status = self.coordinator.status(self.unit_id)
        node = status.node or status.target  # moved aside meanwhile: where it drives to
        if node is None:  # stranded on a lane: ask again next tick
            return AgentState(Command("stop"), True, None, (), self.goal)
        self._dwell_until = None
        if self._leg == 0 and self.task is not None:
            self._leg = 1
            self._request(node, self.task.dropoff, now)
            return AgentState(Command("stop"), True, None, (), self.goal)
        done, self.task = self.task, None
        return AgentState(Command("idle"), False, None, (), None, task_done=done)

    @property
    def dwell_until(self) -> float | None:
        """[s] when the dwell at this leg's stop ends (None: not dwelling)."""
        return self._dwell_until

    @property
    def last_plan_made(self) -> float:
        """[s] when the navigator last planned."""
        return self._last_plan


def activity(now: float, agent: TaskAgent, state: AgentState) -> str:
    """What the unit of ``agent`` does at ``now`` [s], its ``state`` this tick: broken
    down (``broken_down``) beats dwelling at a stop (``dwelling``), which beats standing
    with no admissible path or lane (``frozen``); else ``moving`` when its command drives
    or turns it, ``waiting`` (for traffic) when it stands with a task, ``idle`` without."""
    if now < agent.broken_until:
        return "broken_down"
    if agent.dwell_until is not None and now < agent.dwell_until:
        return "dwelling"
    if state.blocked_reason is not None:
        return "frozen"
    if state.command.kind in ("follow", "rotate"):
        return "moving"
    return "waiting" if state.has_task else "idle"


def _fmt(point: Point | None) -> str:
    return "?" if point is None else f"({point[0]:.2f}, {point[1]:.2f})"
