"""The scenario model and ``load_scenario``: one run's world, fleet, trips, map server and
events, validated and frozen.

``docs/scenarios.md`` documents the file format key by key. Every error is a
``ScenarioError`` naming the file, the line and the field (``moved_pod.yaml:23:
events[1].at: must be a number of seconds >= 0, got 'soon'``). The rules live with the
classes that own them, never restated here: the layout is built by
``Layout.from_dict`` (``scenarios.spec.layout``), the map server section by the server's
``load_settings`` (``scenarios.spec.server``), the unit sections by ``DriveLimits``,
``LidarConfig`` and ``PoseNoise``, recovery by ``RecoveryConfig``; trips are
``scenarios.spec.tasks``, events ``scenarios.spec.events``. This module joins them and
places the units.

Placement. Without ``units.starts``, unit ``u<k>`` (k from 1) starts at a free lane
junction, facing +x: the junctions ``(lane_x[i], lane_y[j])`` in row-major order
(bottom row first, left to right), keeping those farther than the stop clearance from
every obstacle, and taking the ``floor((k - 1) * n / count)``-th of those n: spread over
the floor, and the same for every seed.

Stop clearance: a unit must be able to stand at every start, station and storage
location, so each must be farther than ``max(units.drive.radius,
map_server.inflation.inscribed_radius) + map_server.resolution`` [m] from every obstacle
of the layout (the planner's inscribed radius plus a cell of rasterisation).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np

from fleet.boxworld import Warehouse
from fleet.casters import CASTER_CHOICES, CASTERS, DEFAULT_CASTER
from fleet.layout import Layout
from fleet.lidar import LidarConfig
from fleet.localization import PoseNoise
from fleet.sim import UnitSpec
from fleet.unit import DriveLimits
from mapserver.client.zones import ZoneLayout
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams
from mapserver.core.scan import Pose2D
from mapserver.core.sensor_model import Policy
from mapserver.service.settings import Settings
from mapserver.service.validation import Section, domain_section, number, reworded, text
from planner.lane_graph import LaneGraph
from planner.navigator import RecoveryConfig
from scenarios.spec.coordination import CoordinationFields, CoordinationSpec
from scenarios.spec.events import (
    BreakdownEvent,
    DropEvent,
    Event,
    EventFields,
    MoveEvent,
    PersonEvent,
    RemoveEvent,
    ScheduledChange,
    parse_events,
)
from scenarios.spec.layout import (
    LayoutFields,
    StoragePoint,
    check_clear_of,
    check_stops,
    first_offenders,
    layout_warehouse,
    parse_layout,
    parse_one_way,
    parse_storage,
)
from scenarios.spec.server import MapServerFields, MapServerSpec, parse_map_server
from scenarios.spec.tasks import Task, TasksFields, TaskSpec, parse_tasks, task_stream
from scenarios.spec.yaml_lines import Document, ScenarioError, parse_yaml

__all__ = [
    "BreakdownEvent",
    "DropEvent",
    "Event",
    "MapServerSpec",
    "MoveEvent",
    "PersonEvent",
    "RemoveEvent",
    "Scenario",
    "ScenarioError",
    "ScheduledChange",
    "StoragePoint",
    "Task",
    "TaskSpec",
    "UnitsSpec",
    "layout_warehouse",
    "load_scenario",
    "parse_scenario",
    "task_stream",
]

Point = tuple[float, float]

DEFAULT_DT_S = 0.1
MAX_DURATION_S = 86_400.0
MIN_DT_S = 0.001
MAX_UNITS = 2_000  # thousand_units.yaml runs 1,000


# ---------------------------------------------------------------------------- model
@dataclass(frozen=True)
class UnitsSpec:
    """The fleet: one start pose per unit (unit ``u<k>`` starts at ``starts[k - 1]``),
    their body and limits, LiDAR and localisation noise; ``placed``: the starts were
    placed at lane junctions (module docstring), not given; ``caster``: how the LiDARs'
    beams are cast (``fleet.casters.CASTERS``)."""

    starts: tuple[Pose2D, ...]
    drive: DriveLimits = field(default_factory=DriveLimits)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    pose_noise: PoseNoise = field(default_factory=PoseNoise)
    placed: bool = False
    caster: str = DEFAULT_CASTER

    @property
    def count(self) -> int:
        """Number of units."""
        return len(self.starts)

    @property
    def ids(self) -> tuple[str, ...]:
        """``u1``, ``u2``, ... in start order."""
        return tuple(f"u{k + 1}" for k in range(self.count))

    def specs(self) -> tuple[UnitSpec, ...]:
        """One ``fleet.sim.UnitSpec`` per unit, in id order."""
        return tuple(
            UnitSpec(uid, start, self.drive, self.lidar, self.pose_noise, self.caster)
            for uid, start in zip(self.ids, self.starts, strict=True)
        )


@dataclass(frozen=True)
class Scenario:
    """One validated scenario (``load_scenario``); see docs/scenarios.md for each field.

    duration: [s] sim time of a run; dt: [s] sim step; seed: the run's seed (sim, LiDAR
    noise and trips; not the layout). layout: the world at t = 0. one_way: (junction_a,
    junction_b) lanes driven only a -> b. events: sorted by ``at`` (ties in file order).
    coordination: how the fleet is coordinated (``scenarios.spec.coordination``). source:
    the file it was loaded from ("" if none).
    """

    name: str
    description: str
    duration: float
    dt: float
    seed: int
    layout: Layout
    units: UnitsSpec
    map_server: MapServerSpec
    storage: tuple[StoragePoint, ...] = ()
    one_way: tuple[tuple[str, str], ...] = ()
    tasks: TaskSpec = field(default_factory=TaskSpec)
    events: tuple[Event, ...] = ()
    recovery: RecoveryConfig = field(default_factory=RecoveryConfig)
    coordination: CoordinationSpec = field(default_factory=CoordinationSpec)
    source: str = ""

    @property
    def steps(self) -> int:
        """Number of sim steps of ``dt`` in ``duration``."""
        return max(1, round(self.duration / self.dt))

    def build_layout(self) -> Layout:
        """The world at t = 0 (for ``fleet.world.World``)."""
        return self.layout

    def build_warehouse(self) -> Warehouse:
        """The layout as a ``fleet.boxworld.Warehouse`` (``layout_warehouse``)."""
        return layout_warehouse(self.layout)

    def stops(self) -> dict[str, Point]:
        """Stations and storage locations by id: the lane graph's stops."""
        out = {s.id: (s.x, s.y) for s in self.layout.stations}
        out.update({s.id: (s.x, s.y) for s in self.storage})
        return out

    def build_lane_graph(self, **options: Any) -> LaneGraph:
        """``LaneGraph.from_warehouse`` of the layout with the stops and one-way lanes;
        ``options`` go to it (``segment_m``, ``cost_factor``, ...)."""
        return LaneGraph.from_warehouse(
            self.build_warehouse(), stations=self.stops(), one_way=self.one_way, **options
        )

    def unit_specs(self) -> tuple[UnitSpec, ...]:
        """The units for ``fleet.sim.FleetSim``."""
        return self.units.specs()

    def geometry(self) -> GridGeometry:
        """The map grid's geometry."""
        return self.map_server.grid.build()

    def inflation(self) -> InflationParams:
        """The map server's inflation (the ground truth must inflate the same way)."""
        return self.map_server.inflation.build()

    def zone_layout(self) -> ZoneLayout:
        """The floor's strips, one map server each (``map_server.zones``; one strip when
        1), with borders for the units' LiDAR reach and the costmap's inflation."""
        return ZoneLayout.strips(
            self.geometry(),
            self.map_server.zones,
            self.units.lidar.range_max,
            self.inflation().inflation_radius,
        )

    def server_overrides(self) -> dict[str, Any]:
        """``MapServerSpec.overrides``: what the runner passes to the embedded server."""
        return self.map_server.overrides()

    def server_settings(self, extra: Mapping[str, Any] | None = None) -> Settings:
        """``MapServerSpec.settings``."""
        return self.map_server.settings(extra)

    def task_stream(self, rng: np.random.Generator | None = None) -> Iterator[Task]:
        """``scenarios.spec.tasks.task_stream`` of this scenario."""
        return task_stream(self, rng)

    def world_schedule(self, dt: float | None = None) -> tuple[ScheduledChange, ...]:
        """Every world change of the events, by time (ties: event order, then the
        person's steps), with persons moved every ``dt`` [s] (default ``self.dt``)."""
        step = self.dt if dt is None else dt
        changes = [c for event in self.events for c in event.changes(step)]
        return tuple(sorted(changes, key=lambda c: c.time))

    def breakdowns(self) -> tuple[BreakdownEvent, ...]:
        """The breakdown events (the runner stops those units; the world is unchanged)."""
        return tuple(e for e in self.events if isinstance(e, BreakdownEvent))

    def with_policy(self, policy: Policy | str) -> Scenario:
        """This scenario under another map policy (``decay``, ``binary``, ``sticky``)."""
        return replace(self, map_server=replace(self.map_server, policy=Policy.parse(policy)))

    def with_seed(self, seed: int) -> Scenario:
        """This scenario with another run seed (the layout stays the same)."""
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
        return replace(self, seed=seed)


# ---------------------------------------------------------------------------- the file
DriveFields = domain_section(DriveLimits, "DriveFields", "``units.drive``: ``DriveLimits``.")


class LidarFields(domain_section(LidarConfig, "LidarConfigFields", "``LidarConfig``'s fields.")):
    """``units.lidar``: ``LidarConfig``, and ``caster``, how its beams are cast
    (``fleet.casters``)."""

    caster: Annotated[Literal[CASTERS], reworded(CASTER_CHOICES)] = DEFAULT_CASTER

    def build(self) -> LidarConfig:
        """The ``LidarConfig`` (``caster`` is the sim's, not the sensor's)."""
        return LidarConfig(**self.model_dump(exclude={"caster"}))


PoseNoiseFields = domain_section(PoseNoise, "PoseNoiseFields", "``units.pose_noise``.")
RecoveryFields = domain_section(RecoveryConfig, "RecoveryFields", "``recovery``.")


class StartFields(Section):
    """A unit's start pose: (x, y) [m], yaw [rad]."""

    x: number("metres")
    y: number("metres")
    yaw: number("radians") = 0.0


class UnitsFields(Section):
    """The ``units`` section: ``count`` units placed at lane junctions, or ``starts``."""

    count: number(integer=True, ge=1, le=MAX_UNITS) | None = None
    starts: list[StartFields] | None = None
    drive: DriveFields = DriveFields()
    lidar: LidarFields = LidarFields()
    pose_noise: PoseNoiseFields = PoseNoiseFields()


class ScenarioFile(Section):
    """A scenario file as written (docs/scenarios.md): types and bounds of each field;
    ``load_scenario`` checks the rest (ids, the floor, stops, lanes)."""

    name: text("a scenario name") | None = None
    description: str | None = None
    duration: number("seconds", gt=0, le=MAX_DURATION_S)
    dt: number("seconds", ge=MIN_DT_S) = DEFAULT_DT_S
    seed: number(integer=True, ge=0) = 0
    layout: LayoutFields
    units: UnitsFields
    tasks: TasksFields = TasksFields()
    map_server: MapServerFields = MapServerFields()
    events: list[EventFields] | None = None
    recovery: RecoveryFields = RecoveryFields()
    coordination: CoordinationFields = CoordinationFields()


TOP_KEYS = tuple(ScenarioFile.model_fields)


# ---------------------------------------------------------------------------- loading
def load_scenario(path: str | Path, overrides: Mapping[str, Any] | None = None) -> Scenario:
    """The scenario in the YAML file ``path``; ``overrides`` set dotted keys first
    (``{"map_server.policy": "sticky"}``, a sweep's parameters). ScenarioError names
    the file, line and field of the first problem."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        fix = " (give a scenario YAML: scenarios/*.yaml, docs/scenarios.md)"
        fix = fix if isinstance(exc, FileNotFoundError) else f" ({exc})"
        raise ScenarioError(source, None, "scenario", f"cannot read the file{fix}") from None
    return parse_scenario(text, source, overrides, default_name=Path(path).stem)


def parse_scenario(
    text: str,
    source: str = "<scenario>",
    overrides: Mapping[str, Any] | None = None,
    default_name: str = "scenario",
) -> Scenario:
    """The scenario in YAML ``text`` (``load_scenario`` without the file); ``source``
    names it in errors, ``default_name`` is its name when it gives none."""
    doc = parse_yaml(text, source)
    if overrides:
        doc = doc.with_overrides(overrides)
    return _scenario(doc, default_name)


def _scenario(doc: Document, default_name: str) -> Scenario:
    if not isinstance(doc.data, dict):
        raise doc.error((), "must be a mapping of scenario fields", doc.data)
    top = doc.validate(ScenarioFile)
    if top.dt > top.duration:
        raise doc.error(("dt",), f"must be at most the duration ({top.duration:g} s)", top.dt)
    drive, lidar = top.units.drive.build(), top.units.lidar.build()
    if top.dt > lidar.period * (1 + 1e-9):
        raise doc.error(
            ("dt",),
            f"must be at most one LiDAR period (1 / units.lidar.rate_hz = {lidar.period:g} s)",
            top.dt,
        )
    layout = parse_layout(doc, top.layout)
    map_server = parse_map_server(doc, top.map_server, layout, drive)
    clearance = (
        max(drive.radius, map_server.inflation.inscribed_radius) + map_server.grid.resolution
    )
    storage, storage_paths = parse_storage(doc, top.layout, layout)
    one_way = parse_one_way(doc, top.layout, layout)
    check_stops(doc, layout, storage, storage_paths, one_way, clearance)

    starts = _starts(doc, top.units, layout, drive, clearance)
    units = UnitsSpec(
        starts,
        drive,
        lidar,
        top.units.pose_noise.build(),
        top.units.starts is None,
        top.units.lidar.caster,
    )
    tasks = parse_tasks(doc, top.tasks, units.count, top.duration)
    if tasks.enabled and not (storage and layout.stations):
        raise doc.error(
            ("tasks",),
            "trips need at least one storage location (layout.storage, or pods) and one "
            "station (layout.stations)",
        )
    events = parse_events(
        doc,
        ("events",),
        top.events,
        layout=layout,
        unit_ids=units.ids,
        duration=top.duration,
    )
    return Scenario(
        name=top.name or default_name,
        description=(top.description or "").strip(),
        duration=top.duration,
        dt=top.dt,
        seed=top.seed,
        layout=layout,
        units=units,
        map_server=map_server,
        storage=storage,
        one_way=one_way,
        tasks=tasks,
        events=events,
        recovery=top.recovery.build(),
        coordination=top.coordination.build(),
        source=doc.source,
    )


# ---------------------------------------------------------------------------- units
def _starts(
    doc: Document, uf: UnitsFields, layout: Layout, drive: DriveLimits, clearance: float
) -> tuple[Pose2D, ...]:
    """The units' starts: given (checked clear of obstacles and of each other,
    ``clearance`` [m]) or placed (``_place``)."""
    where = ("units",)
    if uf.starts is None:
        if uf.count is None:
            raise doc.error((*where, "count"), "is required (or give starts)")
        return _place(doc, layout, uf.count, clearance)
    starts: list[Pose2D] = []
    offenders = first_offenders(layout, [(item.x, item.y) for item in uf.starts], clearance)
    for i, item in enumerate(uf.starts):
        at = (*where, "starts", i)
        starts.append(Pose2D(item.x, item.y, item.yaw))
        check_clear_of(doc, at, layout, (item.x, item.y), clearance, offenders[i])
        for k, other in enumerate(starts[:-1]):
            if math.hypot(other.x - item.x, other.y - item.y) <= 2 * drive.radius:
                raise doc.error(at, f"overlaps the start of u{k + 1}", (item.x, item.y))
    if not starts or len(starts) > MAX_UNITS:
        raise doc.error((*where, "starts"), f"must hold 1 to {MAX_UNITS} poses", len(starts))
    if uf.count is not None and uf.count != len(starts):
        raise doc.error(
            (*where, "starts"), f"must hold units.count = {uf.count} poses", len(starts)
        )
    return tuple(starts)


def _place(doc: Document, layout: Layout, count: int, clearance: float) -> tuple[Pose2D, ...]:
    """Starts at free lane junctions, spread evenly (module docstring)."""
    junctions = np.array([(x, y) for y in layout.lane_y for x in layout.lane_x]).reshape(-1, 2)
    free = np.ones(len(junctions), dtype=bool)
    for obstacle in layout.obstacles:
        free &= obstacle.shape.distance(junctions[:, 0], junctions[:, 1]) > clearance
    spots = junctions[free]
    if len(spots) < count:
        raise doc.error(
            ("units", "count"),
            f"needs a free lane junction per unit and the layout has {len(spots)}; give "
            "units.starts",
            count,
        )
    picks = [spots[(k * len(spots)) // count] for k in range(count)]
    return tuple(Pose2D(float(x), float(y), 0.0) for x, y in picks)
