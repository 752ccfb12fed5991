"""What a scenario run records: the input of ``metrics.json``, ``freezes.json``,
``trips.json``, ``collisions.json``, ``report.png`` and ``replay.mcap``.

Everything is stamped with sim time [s]; positions are in the map frame [m]. The runner
appends as it goes; writers only read.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING

import numpy as np

from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import PoseStd
from planner.freeze import PHANTOM, TRUE_BLOCK, Segment
from scenarios.replay.fused import FusedScans, ZonedFusedScans
from scenarios.score.incidents import CollisionIncident

if TYPE_CHECKING:
    from fleet.sim import CollisionEvent  # imports pybullet


@dataclass(frozen=True)
class UnitSample:
    """A unit at a tick: pose (x, y [m], yaw [rad]), commanded motion, frozen, its task."""

    stamp: float
    unit_id: str
    x: float
    y: float
    yaw: float
    moving: bool
    frozen: bool
    task: str | None


@dataclass(frozen=True)
class PlanSample:
    """A plan a unit made: its path [m], and the centres [m] of the cells its legs cross
    that were lethal (``stale_cells``) and inscribed (``inscribed_cells``) in ground
    truth at that time (``planner.plan_safety``)."""

    stamp: float
    unit_id: str
    path: tuple[tuple[float, float], ...]
    stale_cells: tuple[tuple[float, float], ...] = ()
    inscribed_cells: tuple[tuple[float, float], ...] = ()

    @property
    def stale_free(self) -> bool:
        """Does it drive through a truly lethal cell?"""
        return bool(self.stale_cells)

    @property
    def inscribed(self) -> bool:
        """Does it put the unit's body on an obstacle (a truly inscribed cell) without
        crossing a lethal one?"""
        return bool(self.inscribed_cells) and not self.stale_cells


@dataclass(frozen=True)
class EventRecord:
    """A scheduled world event: ``kind`` (move, drop, remove, person, breakdown), the
    object it concerns, where it happened [m] and a sentence for people."""

    stamp: float
    kind: str
    object_id: str
    x: float
    y: float
    detail: str


@dataclass(frozen=True)
class ObjectState:
    """A world object as a scene entity: id, kind, footprint (a box: centre x, y [m],
    size_x, size_y [m], yaw [rad]; a cylinder: size_x = size_y = diameter), height [m]."""

    object_id: str
    kind: str
    x: float
    y: float
    size_x: float
    size_y: float
    yaw: float
    height: float
    round: bool


@dataclass(frozen=True)
class ObjectsSample:
    """The world's objects at ``stamp`` (recorded whenever they changed)."""

    stamp: float
    objects: tuple[ObjectState, ...]


@dataclass(frozen=True)
class GridSample:
    """The shared map at ``stamp`` and ``version``: costs (uint8 Nav2) and occupancy
    (int8 OccupancyGrid), (height, width), row 0 at the origin's y."""

    stamp: float
    version: int
    costs: np.ndarray
    occupancy: np.ndarray


@dataclass(frozen=True)
class MapTruthSample:
    """The shared costmap against ground truth at a map read at ``stamp`` [s]
    (``scenarios.score.map_truth``): phantom and forgotten cells [cells], the share [1] of the
    reachable floor the map calls unknown."""

    stamp: float
    phantom_cells: int
    forgotten_cells: int
    unknown_share: float


@dataclass(frozen=True)
class CountersSample:
    """The run's counters at ``stamp`` [s], as they stood then (the replay's ``/metrics``):
    trips done, units frozen now, stale-free plans, the fleet's and the scenario's
    collision incidents, the scenario events and the inscribed plans so far (counts)."""

    stamp: float
    tasks_completed: int
    frozen_units: int
    stale_free_plans: int
    collisions: int
    scenario_collisions: int
    events: int
    inscribed_plans: int = 0


COUNTERS = tuple(f.name for f in fields(CountersSample) if f.name != "stamp")
"""The counters a ``CountersSample`` holds (its fields but ``stamp``), each a metric of
the metric registry (``scenarios.score.metric_registry``)."""


@dataclass(frozen=True)
class ScanSample:
    """A LiDAR scan as posted: the pose it was sent with and its ranges [m] (float32;
    inf = no return, NaN = invalid), and the ``pose_std`` it was sent with (None: none)."""

    stamp: float
    unit_id: str
    x: float
    y: float
    yaw: float
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    pose_std: PoseStd | None = None


@dataclass(frozen=True)
class BlockingCell:
    """A cell that blocked a frozen unit: where [m], whether it was truly occupied then
    (ground truth), its p_occ (None unknown), last_observed [s], the scans (unit,
    stamp) that last marked it and, for a cell that blocked by inflation (INSCRIBED), the
    LETHAL cells that inscribe it, each with its own evidence
    (``scenarios.score.inscribing``)."""

    x: float
    y: float
    truly_occupied: bool
    p_occ: float | None
    last_observed: float | None
    marked_by: tuple[tuple[str, float], ...]
    held_by: tuple[BlockingCell, ...] = ()


@dataclass(frozen=True)
class RecoveryStep:
    """A recovery action a unit took: stamp [s], action, cause."""

    stamp: float
    action: str
    cause: str


@dataclass(frozen=True)
class FreezeRecord:
    """A freeze (docs/files.md): unit, start [s], duration [s], its phantom and true-block
    segments (``planner.freeze.Segment``, in time order), the blocking cells with their
    evidence, the recovery actions taken meanwhile, and for a lane freeze the blocked
    lanes (node-id pairs, sorted) that held the unit (``scenarios.score.lane_evidence``;
    empty for a path freeze)."""

    unit_id: str
    start: float
    duration: float
    segments: tuple[Segment, ...]
    reason: str
    x: float
    y: float
    blocking: tuple[BlockingCell, ...]
    recovery: tuple[RecoveryStep, ...]
    lanes: tuple[tuple[str, str], ...] = ()

    def seconds(self, kind: str, until: float | None = None) -> float:
        """[s] of the freeze's segments of ``kind`` (``PHANTOM``, ``TRUE_BLOCK``), up to
        sim time ``until`` [s] (None: all)."""
        end = float("inf") if until is None else until
        return sum(max(0.0, min(s.end, end) - s.start) for s in self.segments if s.kind == kind)

    @property
    def phantom(self) -> bool:
        """Has it phantom seconds (the map, not the world, held the unit for a while)?"""
        return any(s.kind == PHANTOM for s in self.segments)

    @property
    def true_block(self) -> bool:
        """Has it true-block seconds (ground truth blocked the unit's way for a while)?"""
        return any(s.kind == TRUE_BLOCK for s in self.segments)


@dataclass(frozen=True)
class Attempt:
    """One unit's go at a trip: ``unit_id`` from ``start`` to ``end`` [s] (None: still at
    it when the run ended); ``outcome`` ``completed``, ``returned`` (to the queue, with its
    ``cause``, ``scenarios.run.trip_queue.CAUSES``) or ``open`` (unfinished at the end)."""

    unit_id: str
    start: float
    end: float | None
    outcome: str
    cause: str | None = None

    @property
    def seconds(self) -> float:
        """[s] it lasted (0 while open)."""
        return 0.0 if self.end is None else self.end - self.start


@dataclass(frozen=True)
class TripRecord:
    """A completed trip: task ``task_id`` driven by ``unit_id``, ``assigned`` and ``done``
    [s] sim time, ``ideal_s`` [s] its congestion-free time (``scenarios.score.throughput``; None
    when the lane graph has no route for it), all of the attempt that completed it;
    ``returned``: the attempts before it, each returned to the queue."""

    task_id: str
    unit_id: str
    assigned: float
    done: float
    ideal_s: float | None
    returned: tuple[Attempt, ...] = ()

    @property
    def actual_s(self) -> float:
        """[s] from assignment to completion."""
        return self.done - self.assigned

    @property
    def attempts(self) -> tuple[Attempt, ...]:
        """Every attempt, the completing one last."""
        return (*self.returned, Attempt(self.unit_id, self.assigned, self.done, "completed"))


@dataclass(frozen=True)
class UnfinishedTrip:
    """A trip returned to the queue at least once and not completed by the end of the run:
    its attempts in order (the last one ``open`` if a unit was at it when the run ended)."""

    task_id: str
    attempts: tuple[Attempt, ...]


@dataclass
class RunRecord:
    """A whole run: identity, the map's geometry, the units' body (radius, height [m];
    None: the fleet's default ``DriveLimits``), the streams above (``collisions``: every
    contact begun; ``incidents``: them grouped, ``scenarios.score.incidents``), and what
    the run's own map server fused (``fused``; None for a run against an outside
    server)."""

    scenario: str
    policy: str
    seed: int
    geometry: GridGeometry
    units: list[UnitSample] = field(default_factory=list)
    plans: list[PlanSample] = field(default_factory=list)
    events: list[EventRecord] = field(default_factory=list)
    objects: list[ObjectsSample] = field(default_factory=list)
    grids: list[GridSample] = field(default_factory=list)
    map_truth: list[MapTruthSample] = field(default_factory=list)
    counters: list[CountersSample] = field(default_factory=list)
    scans: list[ScanSample] = field(default_factory=list)
    freezes: list[FreezeRecord] = field(default_factory=list)
    trips: list[TripRecord] = field(default_factory=list)
    unfinished_trips: list[UnfinishedTrip] = field(default_factory=list)
    collisions: list[CollisionEvent] = field(default_factory=list)
    incidents: list[CollisionIncident] = field(default_factory=list)
    time_to_clear: dict[str, float | None] = field(default_factory=dict)
    metrics: dict[str, object] = field(default_factory=dict)
    unit_radius: float | None = None
    unit_height: float | None = None
    fused: FusedScans | ZonedFusedScans | None = None
