"""Freezes, as docs/files.md defines them, and how they are classified.

- A *freeze*: a unit with a task commands no motion for at least ``MIN_FREEZE_S`` (1 s)
  because no admissible path or lane was available. Standing still for any other reason
  (loading at a station, waiting for a granted lane to clear) is not a freeze.
- Its time is split into *segments* (``Segment``), each *phantom* or *true block*: a
  moment of the freeze is phantom when the same planner finds a way on the ground-truth
  costmap of that moment (the true geometry rasterised and inflated as the server does)
  and true block when it does not (the unit's goal lies in an obstacle, or its way is
  truly cut). Ground truth changes only with the world (a pod moved, a tote dropped, a
  person's step), so the planner runs once at the freeze's start and once after each
  world change during it (``TruthTimeline``), and each verdict holds until the next
  change: the split is exact to the sim step. A unit frozen at a pod that is moved away
  30 s later has 30 s of true block, then phantom seconds until it moves on (the map,
  not the world, holds it from then on); one frozen at a map's ghost before a tote is
  dropped on its way has phantom seconds, then true-block ones. "The same planner" is
  the one that froze the unit:

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

``FreezeDetector`` is fed one observation per unit per tick and reports each freeze once
it ends (or when the run ends), with the reason and the blocking cells its unit reported.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from mapserver.core.geometry import GridGeometry
from mapserver.core.queries import query_segments

if TYPE_CHECKING:
    from planner.lane_graph import LaneGraph

MIN_FREEZE_S = 1.0  # [s] docs/files.md
PHANTOM = "phantom"
TRUE_BLOCK = "true_block"
SEGMENT_KINDS = (PHANTOM, TRUE_BLOCK)

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


@dataclass(frozen=True)
class Segment:
    """A stretch of a freeze, ``start`` to ``end`` [s], of one ``kind`` (``PHANTOM`` or
    ``TRUE_BLOCK``), with its ``cause`` in words (what the planner found on ground truth,
    and the world change that began the stretch, if one did)."""

    start: float
    end: float
    kind: str
    cause: str

    @property
    def duration(self) -> float:
        """[s]"""
        return self.end - self.start


@dataclass
class Freeze:
    """A freeze of ``unit_id`` from ``start`` to ``end`` [s]; ``segments`` once classified.

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
    lanes: list[Lane] = field(default_factory=list)
    lane_block: LaneBlock | None = None
    segments: list[Segment] = field(default_factory=list)

    @property
    def duration(self) -> float:
        """[s]"""
        return self.end - self.start

    def seconds(self, kind: str) -> float:
        """[s] of the freeze classified ``kind`` (``PHANTOM`` or ``TRUE_BLOCK``)."""
        return sum(s.duration for s in self.segments if s.kind == kind)


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


@dataclass(frozen=True)
class TruthState:
    """Ground truth from ``time`` [s] until the next state: its ``costs`` (uint8 Nav2), the
    world change that made it (``change``, e.g. ``"pod-9 moved"``; ``""`` for the state a
    freeze starts in) and ``where(x, y)``: what covers a point [m] then, in words
    (``"lies in tote-1"``; None: open floor, or not known)."""

    time: float
    costs: np.ndarray
    change: str = ""
    where: Callable[[float, float], str | None] = lambda x, y: None


TruthTimeline = Callable[[float, float], Iterable[TruthState]]
"""``timeline(start, end)``: the truth at ``start`` [s], then one state after each world
change stamped in (start, end), in time order (``GroundTruth.states`` in the simulator)."""


def split(start: float, end: float, verdicts: Iterable[tuple[float, str, str]]) -> list[Segment]:
    """The segments of a freeze from ``start`` to ``end`` [s], given ``verdicts``: (time
    [s], kind, cause) in time order, the first at ``start``, each holding until the next.
    Consecutive verdicts of one kind and cause make one segment (the first one's cause);
    verdicts at or after ``end`` are dropped."""
    segments: list[Segment] = []
    for time, kind, cause in verdicts:
        if kind not in SEGMENT_KINDS:
            raise ValueError(f"kind must be one of {SEGMENT_KINDS}, got {kind!r}")
        if time >= end:
            break
        last = segments[-1] if segments else None
        if last is not None and last.kind == kind and _base(last.cause) == _base(cause):
            continue
        if last is not None:
            segments[-1] = Segment(last.start, time, last.kind, last.cause)
        segments.append(Segment(time, end, kind, cause))
    if segments and segments[0].start != start:
        raise ValueError(f"the first verdict must be at the start {start!r}, got {segments[0]}")
    return segments


def _base(cause: str) -> str:
    """A cause without the world change that began its segment."""
    return cause.split(" (", 1)[0]


def classify(
    freeze: Freeze,
    timeline: TruthTimeline,
    plan: Callable[[np.ndarray, tuple[float, float], tuple[float, float]], bool],
    lane_plan: LanePlan | None = None,
) -> list[Segment]:
    """Split ``freeze`` into phantom and true-block segments (module docstring): run the
    planner that froze the unit on each state of ``timeline(start, end)``. Sets and
    returns ``freeze.segments``.

    A path freeze: ``plan(truth_costs, position, goal)``. A lane freeze (``lane_block``
    set): ``lane_plan(truth_costs, lane_block, position)``, required for one. A freeze
    without a known position or goal is a true block throughout (never phantom).
    """
    block = freeze.lane_block
    if block is not None and lane_plan is None:
        raise ValueError(
            f"freeze of {freeze.unit_id} at {freeze.start} s is a lane freeze: "
            "classify it with lane_plan (TruthLanes), not the grid planner"
        )
    if block is None and (freeze.position is None or freeze.goal is None):
        unknown = [(freeze.start, TRUE_BLOCK, "its position or goal is not known")]
        freeze.segments = split(freeze.start, freeze.end, unknown)
        return freeze.segments
    verdicts = []
    for state in timeline(freeze.start, freeze.end):
        kind, cause = _verdict(freeze, state, plan, lane_plan)
        when = f" ({state.change} at {state.time:g} s)" if state.change else ""
        verdicts.append((state.time, kind, cause + when))
    freeze.segments = split(freeze.start, freeze.end, verdicts)
    return freeze.segments


def _verdict(
    freeze: Freeze, state: TruthState, plan, lane_plan: LanePlan | None
) -> tuple[str, str]:
    """(kind, cause) of the freeze's moment in ``state``."""
    block = freeze.lane_block
    if block is not None:
        assert lane_plan is not None
        if lane_plan(state.costs, block, freeze.position):
            return PHANTOM, "ground truth has a lane route"
        if len(block.origin) == 2:
            return TRUE_BLOCK, "its lane is truly blocked ahead, or no lane route on from it"
        return TRUE_BLOCK, "no lane route on ground truth"
    assert freeze.position is not None and freeze.goal is not None
    if plan(state.costs, freeze.position, freeze.goal):
        return PHANTOM, "ground truth has a path"
    return TRUE_BLOCK, _goal_cause(state, freeze.goal)


def _goal_cause(state: TruthState, goal: Point) -> str:
    """Why ground truth has no path: the goal's place, when the truth says what is there
    (``TruthState.where``), else no path."""
    where = state.where(*goal)
    return f"its goal {where}" if where else "no path on ground truth"


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
