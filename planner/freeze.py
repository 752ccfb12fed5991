"""Freezes, as docs/files.md defines them, and how they are classified.

- A *freeze*: a unit with a task commands no motion for at least ``MIN_FREEZE_S`` (1 s)
  because no admissible path or lane was available. Standing still for any other reason
  (loading at a station, waiting for a granted lane to clear) is not a freeze.
- A *phantom* freeze: during the freeze, the same planner finds a path on the
  ground-truth costmap (the true geometry rasterised and inflated as the server does).
  Otherwise the freeze is a *true block*. "The same planner" is the one that froze the
  unit:

  - a *path freeze* (the navigator found no admissible path): the grid planner, from
    the unit's position to its goal point (``classify``'s ``plan``);
  - a *lane freeze* (the lane coordinator has no lane for it: no route to its goal node,
    or stranded on a lane that became blocked; ``UnitObservation.lane_block``): the
    coordinator's router on the lane graph with every lane re-read from the
    ground-truth costmap (``TruthLanes``): from the unit's node to its goal node, or,
    stranded on edge (tail, head), on along that edge (truly clear ahead of the unit)
    and from its head to the goal node. The grid planner would be the wrong judge: it
    goes round an obstacle that blocks a lane line in truth (a true block the map got
    right) and fails on a goal point off the lane that the router never plans to.
- A *stale-free plan*: a plan whose path crosses a cell that is lethal in ground truth.

``FreezeDetector`` is fed one observation per unit per tick and reports each freeze once
it ends (or when the run ends), with the reason and the blocking cells its unit reported.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from mapserver.core.costvalues import LETHAL
from mapserver.core.geometry import GridGeometry
from mapserver.core.queries import query_segments

if TYPE_CHECKING:
    from planner.lane_graph import LaneGraph

MIN_FREEZE_S = 1.0  # [s] docs/files.md

Point = tuple[float, float]
Lane = tuple[str, str]


@dataclass(frozen=True)
class LaneBlock:
    """Why the lane coordinator holds a unit (a lane freeze).

    origin: where its route would start: ``(node,)`` for a unit at a node with no route to
    its goal, ``(tail, head)`` the edge it is stranded on. goal: its goal node. lanes:
    the blocked lanes that explain it (``scenarios.score.lane_evidence``); points: their first
    blocked cells (x, y) [m], the cells' evidence is read for.
    """

    origin: tuple[str, ...]
    goal: str
    lanes: tuple[Lane, ...] = ()
    points: tuple[Point, ...] = ()


@dataclass(frozen=True)
class UnitObservation:
    """One unit at one tick: does it have a task, does it command motion, and if not
    because nothing admissible was found, why (``blocked_reason``) and which cells
    (world points [m]) blocked it; ``lane_block`` when the lane coordinator blocked it
    (a lane freeze; None: the navigator, a path freeze)."""

    unit_id: str
    stamp: float
    has_task: bool
    moving: bool
    blocked_reason: str | None = None
    blocking_points: tuple[tuple[float, float], ...] = ()
    goal: tuple[float, float] | None = None
    position: tuple[float, float] | None = None
    lane_block: LaneBlock | None = None


@dataclass
class Freeze:
    """A freeze of ``unit_id`` from ``start`` to ``end`` [s]; ``phantom`` once classified.

    blocking_points, lanes: every blocking cell and blocked lane its observations named,
    in order, each once. lane_block: the first observation's (None: a path freeze; the
    kind of a freeze, like its ``reason``, is that of its first tick).
    """

    unit_id: str
    start: float
    end: float
    reason: str
    position: tuple[float, float] | None
    goal: tuple[float, float] | None
    blocking_points: list[tuple[float, float]] = field(default_factory=list)
    phantom: bool | None = None
    lanes: list[Lane] = field(default_factory=list)
    lane_block: LaneBlock | None = None

    @property
    def duration(self) -> float:
        """[s]"""
        return self.end - self.start


class FreezeDetector:
    """Tracks, per unit, the run of ticks in which it is blocked with a task."""

    def __init__(self, min_freeze_s: float = MIN_FREEZE_S) -> None:
        if not min_freeze_s > 0:
            raise ValueError(f"min_freeze_s must be positive, got {min_freeze_s!r}")
        self.min_freeze_s = min_freeze_s
        self._open: dict[str, Freeze] = {}
        self.freezes: list[Freeze] = []

    def observe(self, obs: UnitObservation) -> Freeze | None:
        """Feed one observation; returns a freeze that just ended (>= the minimum)."""
        blocked = obs.has_task and not obs.moving and obs.blocked_reason is not None
        current = self._open.get(obs.unit_id)
        if blocked:
            if current is None:
                current = self._open[obs.unit_id] = Freeze(
                    obs.unit_id, obs.stamp, obs.stamp, obs.blocked_reason, obs.position,
                    obs.goal, lane_block=obs.lane_block,
                )  # fmt: skip
            current.end = obs.stamp
            for point in obs.blocking_points:
                if point not in current.blocking_points:
                    current.blocking_points.append(point)
            for lane in obs.lane_block.lanes if obs.lane_block is not None else ():
                if lane not in current.lanes:
                    current.lanes.append(lane)
            return None
        if current is None:
            return None
        del self._open[obs.unit_id]
        current.end = obs.stamp
        return self._keep(current)

    def open_since(self, unit_id: str) -> float | None:
        """[s] when ``unit_id``'s current run of blocked ticks began (None: not blocked)."""
        current = self._open.get(unit_id)
        return None if current is None else current.start

    def finish(self, stamp: float) -> list[Freeze]:
        """End every open run at ``stamp`` [s] (the run's end); returns the freezes."""
        ended = []
        for unit_id in sorted(self._open):
            current = self._open.pop(unit_id)
            current.end = stamp
            kept = self._keep(current)
            if kept is not None:
                ended.append(kept)
        return ended

    def _keep(self, freeze: Freeze) -> Freeze | None:
        if freeze.duration < self.min_freeze_s:
            return None
        self.freezes.append(freeze)
        return freeze


LanePlan = Callable[[np.ndarray, LaneBlock, Point | None], bool]
"""``lane_plan(truth_costs, lane_block, position)``: would the lane router let the unit
through on these costs (``TruthLanes``)?"""


def classify(
    freeze: Freeze,
    truth_costs_at: Callable[[float], np.ndarray],
    plan: Callable[[np.ndarray, tuple[float, float], tuple[float, float]], bool],
    samples: int = 3,
    lane_plan: LanePlan | None = None,
) -> bool:
    """Phantom or not: does the planner that froze the unit succeed on the ground truth at
    some moment of the freeze (``samples`` evenly spaced stamps, start and end included)?

    A path freeze: ``plan(truth_costs, position, goal)``. A lane freeze (``lane_block``
    set): ``lane_plan(truth_costs, lane_block, position)``, required for one.
    """
    block = freeze.lane_block
    if block is not None:
        if lane_plan is None:
            raise ValueError(
                f"freeze of {freeze.unit_id} at {freeze.start} s is a lane freeze: "
                "classify it with lane_plan (TruthLanes), not the grid planner"
            )

        def through(costs: np.ndarray) -> bool:
            return lane_plan(costs, block, freeze.position)

    elif freeze.position is None or freeze.goal is None:
        freeze.phantom = False
        return False
    else:
        start, goal = freeze.position, freeze.goal

        def through(costs: np.ndarray) -> bool:
            return plan(costs, start, goal)

    stamps = np.linspace(freeze.start, freeze.end, max(samples, 2))
    freeze.phantom = any(through(truth_costs_at(t)) for t in stamps)
    return freeze.phantom


class TruthLanes:
    """The lane coordinator's router judged on the ground truth (a ``LanePlan``).

    Keeps its own copy of ``graph`` (the live one is never touched); each call re-reads
    every lane of the copy from ``truth_costs`` (``LaneGraph.refresh`` through
    ``mapserver.core.queries.query_segments``, the server's segment rule: a lane is blocked
    when a cell on it is lethal or inscribed) and asks the router (unblocked lanes,
    one-way lanes one way) whether the unit gets through:

    - origin ``(node,)``: a route from the node to the goal node;
    - origin ``(tail, head)``, stranded on that edge: the edge is clear ahead of the unit
      (unblocked in truth, or its blocked stretch ends behind the unit's ``position``,
      the coordinator's own carry-on rule) and there is a route from head to goal.
    """

    def __init__(self, graph: LaneGraph, geometry: GridGeometry) -> None:
        self.graph = copy.deepcopy(graph)
        self.geometry = geometry
        self._costs: np.ndarray | None = None

    def query_segments(self, segments: Sequence[Sequence[float]]) -> list:
        """``SegmentQuerier`` on the costs of the current call."""
        assert self._costs is not None
        return query_segments(self.geometry, self._costs, segments)

    def __call__(self, truth_costs: np.ndarray, block: LaneBlock, position: Point | None) -> bool:
        self._costs = truth_costs
        try:
            self.graph.refresh(self)
        finally:
            self._costs = None
        if len(block.origin) == 1:
            return self.graph.shortest_route(block.origin[0], block.goal) is not None
        tail, head = block.origin
        if not self._clear_ahead(tail, head, position):
            return False
        return self.graph.shortest_route(head, block.goal) is not None

    def _clear_ahead(self, tail: str, head: str, position: Point | None) -> bool:
        """Edge (tail, head) clear ahead of ``position`` in truth (the coordinator's rule:
        a unit beyond the far end of the blocked stretch carries on)."""
        edges = self.graph.graph.edges
        if (tail, head) in edges:
            d = edges[tail, head]
            far = d["block_span"][1] if d["blocked"] else None
        else:  # reversing a one-way lane: mirror the span of its only edge
            d = edges[head, tail]
            far = d["length"] - d["block_span"][0] if d["blocked"] else None
        if far is None:
            return True
        if position is None:  # never reported: still at the lane's start
            return False
        (tx, ty), (hx, hy) = self.graph.position(tail), self.graph.position(head)
        s = ((position[0] - tx) * (hx - tx) + (position[1] - ty) * (hy - ty)) / d["length"]
        return s > far


def stale_free_cells(
    path: Sequence[tuple[float, float]], truth_costs: np.ndarray, geometry: GridGeometry
) -> list[tuple[float, float]]:
    """The points of ``path`` [m] that lie on cells LETHAL in ground truth (empty: the plan
    is not stale-free)."""
    if not path:
        return []
    cols, rows, inside = geometry.points_to_cells(np.asarray(path, dtype=np.float64))
    hits = np.zeros(len(path), dtype=bool)
    hits[inside] = truth_costs[rows[inside], cols[inside]] == LETHAL
    return [tuple(p) for p, hit in zip(path, hits.tolist(), strict=True) if hit]
