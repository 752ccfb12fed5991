"""The scenario model and ``load_scenario``: one run's world, fleet, trips, map server and
events, validated and frozen.

``docs/scenarios.md`` documents the file format key by key. Every error is a
``ScenarioError`` naming the file, the line and the field (``moved_pod.yaml:23:
events[1].at: must be a number of seconds >= 0, got 'soon'``). The rules live with the
classes that own them, never restated here: the layout is built by
``fleet.layout.Layout.from_dict``; the unit sections by ``DriveLimits``, ``LidarConfig``
and ``PoseNoise``; the map server section by ``mapserver.settings.load_settings``; lanes,
stops and one-way lanes by ``planner.lane_graph.LaneGraph.from_warehouse``; recovery by
``RecoveryConfig``. This module adds only what joins them: the units' starts, storage
locations, stop clearances, the trips (``scenarios.tasks``) and the events
(``scenarios.spec_events``).

Placement. Without ``units.starts``, unit ``u<k>`` (k from 1) starts at a free lane
junction, facing +x: the junctions ``(lane_x[i], lane_y[j])`` in row-major order
(bottom row first, left to right), keeping those farther than the stop clearance from
every obstacle, and taking the ``floor((k - 1) * n / count)``-th of those n: spread over
the floor, and the same for every seed.

Stop clearance: a unit must be able to stand at every start, station and storage
location, so each must be farther than ``max(units.drive.radius,
map_server.inflation.inscribed_radius) + map_server.resolution`` [m] from every obstacle
of the layout (the planner's inscribed radius plus a cell of rasterisation).

Storage locations: the ``layout.storage`` points, else one per pod (an obstacle of kind
``pod``), id the pod's id, at the pod's *lane point*: the nearest point to the pod's
centre on the lane grid (the lane centre lines between the outermost junctions). Storage
locations and stations are the lane graph's stops (``Scenario.stops``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fleet.boxworld import BoxWorld, Warehouse
from fleet.layout import Kind, Layout, LayoutError
from fleet.lidar import LidarConfig
from fleet.localization import PoseNoise
from fleet.sim import UnitSpec
from fleet.unit import DriveLimits
from mapserver.geometry import GridGeometry
from mapserver.inflation import InflationParams
from mapserver.scan import Pose2D
from mapserver.sensor_model import Policy
from mapserver.settings import (
    DecaySettings,
    GridSettings,
    InflationSettings,
    SensorModelSettings,
    Settings,
    SettingsError,
    load_settings,
)
from planner.lane_graph import LaneGraph
from planner.navigator import RecoveryConfig
from scenarios.spec_events import (
    BreakdownEvent,
    DropEvent,
    Event,
    MoveEvent,
    PersonEvent,
    RemoveEvent,
    ScheduledChange,
    parse_events,
)
from scenarios.spec_yaml import (
    Document,
    FieldPath,
    Fields,
    ScenarioError,
    build_dataclass,
    parse_yaml,
)
from scenarios.tasks import Task, TaskSpec, parse_tasks, task_stream

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
DEFAULT_RESOLUTION_M = 0.1
MAX_DURATION_S = 86_400.0
MIN_DT_S = 0.001
MAX_FLOOR_M = 500.0
MAX_UNITS = 500
MAX_GRID_CELLS = 25_000_000
"""Largest map grid a scenario may ask for (the server keeps ~20 bytes per cell)."""

TOP_KEYS = (
    "name",
    "description",
    "duration",
    "dt",
    "seed",
    "layout",
    "units",
    "tasks",
    "map_server",
    "events",
    "recovery",
)
LAYOUT_KEYS = ("warehouse", "floor", "lanes", "obstacles", "stations", "storage", "one_way")
UNIT_KEYS = ("count", "starts", "drive", "lidar", "pose_noise")
TASK_KEYS = ("count", "rate_per_unit", "dwell")
MAP_SERVER_KEYS = (
    "policy",
    "resolution",
    "sensor_model",
    "decay",
    "inflation",
    "max_clearing_range",
)
MAP_SERVER_SECTIONS = {
    "sensor_model": SensorModelSettings,
    "decay": DecaySettings,
    "inflation": InflationSettings,
}
WAREHOUSE_FIELDS: Mapping[str, tuple[str, dict[str, Any]]] = {
    # scenario key: (warehouse_layout argument, its bounds here)
    "width": ("width_m", {"unit": "metres", "low": 0, "low_open": True, "high": MAX_FLOOR_M}),
    "height": ("height_m", {"unit": "metres", "low": 0, "low_open": True, "high": MAX_FLOOR_M}),
    "seed": ("seed", {"integer": True, "low": 0}),
    "aisle": ("aisle_m", {"unit": "metres", "low": 1.0, "high": 50.0}),
    "rack_depth": ("rack_depth_m", {"unit": "metres", "low": 0.2, "high": 50.0}),
    "cross_aisle_every": ("cross_aisle_every_m", {"unit": "metres", "low": 5.0, "high": 500.0}),
}
_LANE_NODE_ID = re.compile(r"[jw]\d+_\d+([hv]\d+)?")
"""Ids the lane graph gives its junctions and waypoints; stops may not take them."""


# ---------------------------------------------------------------------------- model
@dataclass(frozen=True)
class StoragePoint:
    """A storage location: ``id`` and the lane point (x, y) [m] where a unit stops to
    pick; ``pod``: the pod it serves (None for a ``layout.storage`` point)."""

    id: str
    x: float
    y: float
    pod: str | None = None


@dataclass(frozen=True)
class UnitsSpec:
    """The fleet: one start pose per unit (unit ``u<k>`` starts at ``starts[k - 1]``),
    their body and limits, LiDAR and localisation noise; ``placed``: the starts were
    placed at lane junctions (module docstring), not given."""

    starts: tuple[Pose2D, ...]
    drive: DriveLimits = field(default_factory=DriveLimits)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    pose_noise: PoseNoise = field(default_factory=PoseNoise)
    placed: bool = False

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
            UnitSpec(uid, start, self.drive, self.lidar, self.pose_noise)
            for uid, start in zip(self.ids, self.starts, strict=True)
        )


@dataclass(frozen=True)
class MapServerSpec:
    """The map server a run uses: every value the scenario pins (defaults filled in).

    grid: the whole floor at the scenario's resolution, origin (0, 0).
    """

    policy: Policy
    grid: GridSettings
    sensor_model: SensorModelSettings
    decay: DecaySettings
    inflation: InflationSettings
    max_clearing_range: float | None = None

    def overrides(self) -> dict[str, Any]:
        """Settings overrides for ``load_settings`` (nested mappings): the policy, grid,
        sensor model, decay, inflation and clearing range, complete, so neither the
        environment nor a config file can change a run."""
        out: dict[str, Any] = {
            "policy": self.policy.value,
            "grid": self.grid.model_dump(),
            "sensor_model": self.sensor_model.model_dump(),
            "decay": self.decay.model_dump(),
            "inflation": self.inflation.model_dump(),
        }
        if self.max_clearing_range is not None:
            out["max_clearing_range"] = self.max_clearing_range
        return out

    def settings(self, extra: Mapping[str, Any] | None = None) -> Settings:
        """Server ``Settings`` with these values, plus ``extra`` overrides (``data_dir``,
        ``port``, ... as ``load_settings`` takes them)."""
        return load_settings(None, {**self.overrides(), **(extra or {})})


@dataclass(frozen=True)
class Scenario:
    """One validated scenario (``load_scenario``); see docs/scenarios.md for each field.

    duration: [s] sim time of a run; dt: [s] sim step; seed: the run's seed (sim, LiDAR
    noise and trips; not the layout). layout: the world at t = 0. one_way: (junction_a,
    junction_b) lanes driven only a -> b. events: sorted by ``at`` (ties in file order).
    source: the file it was loaded from ("" if none).
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

    def server_overrides(self) -> dict[str, Any]:
        """``MapServerSpec.overrides``: what the runner passes to the embedded server."""
        return self.map_server.overrides()

    def server_settings(self, extra: Mapping[str, Any] | None = None) -> Settings:
        """``MapServerSpec.settings``."""
        return self.map_server.settings(extra)

    def task_stream(self, rng: np.random.Generator | None = None) -> Iterator[Task]:
        """``scenarios.tasks.task_stream`` of this scenario."""
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


def layout_warehouse(layout: Layout) -> Warehouse:
    """``layout`` as a ``Warehouse``: every obstacle's bounding box, kinds, and lanes."""
    boxes = np.array([o.shape.bounds() for o in layout.obstacles], dtype=np.float64)
    return Warehouse(
        world=BoxWorld(boxes.reshape(-1, 4)),
        width=layout.width,
        height=layout.height,
        lane_x=layout.lane_x,
        lane_y=layout.lane_y,
        kinds=tuple(o.kind.value for o in layout.obstacles),
    )


# ---------------------------------------------------------------------------- loading
def load_scenario(path: str | Path, overrides: Mapping[str, Any] | None = None) -> Scenario:
    """The scenario in the YAML file ``path``; ``overrides`` set dotted keys first
    (``{"map_server.policy": "sticky"}``, a sweep's parameters). ScenarioError names
    the file, line and field of the first problem."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(source, None, "scenario", f"cannot read the file ({exc})") from None
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
    top = Fields(doc, (), doc.data, TOP_KEYS, required=("duration", "layout", "units"))
    name = top.text("name", default_name, what="a scenario name")
    description = top.get("description") or ""
    if not isinstance(description, str):
        raise doc.error(top.at("description"), "must be a string", description)
    duration = top.number("duration", unit="seconds", low=0, low_open=True, high=MAX_DURATION_S)
    dt = top.number("dt", DEFAULT_DT_S, unit="seconds", low=MIN_DT_S)
    if dt > duration:
        raise doc.error(top.at("dt"), f"must be at most the duration ({duration:g} s)", dt)
    seed = top.integer("seed", 0, low=0)

    uf = top.fields("units", UNIT_KEYS)
    drive = build_dataclass(doc, uf.at("drive"), uf.get("drive"), DriveLimits)
    lidar = build_dataclass(doc, uf.at("lidar"), uf.get("lidar"), LidarConfig)
    noise = build_dataclass(doc, uf.at("pose_noise"), uf.get("pose_noise"), PoseNoise)
    if dt > lidar.period * (1 + 1e-9):
        raise doc.error(
            top.at("dt"),
            f"must be at most one LiDAR period (1 / units.lidar.rate_hz = {lidar.period:g} s)",
            dt,
        )

    lf = top.fields("layout", LAYOUT_KEYS)
    layout = _layout(doc, lf)
    map_server = _map_server(doc, top.fields("map_server", MAP_SERVER_KEYS), layout, drive)
    clearance = (
        max(drive.radius, map_server.inflation.inscribed_radius) + map_server.grid.resolution
    )
    storage, storage_paths = _storage(doc, lf, layout)
    stop_paths = {s.id: lf.at("stations") + (i,) for i, s in enumerate(layout.stations)}
    for point, where in zip(storage, storage_paths, strict=True):
        if point.id in stop_paths:
            raise doc.error(where, "has the id of a station", point.id)
        stop_paths[point.id] = where
    stops = {s.id: (s.x, s.y) for s in (*layout.stations, *storage)}
    for sid, where in stop_paths.items():
        if _LANE_NODE_ID.fullmatch(sid):
            raise doc.error(where, "is a lane graph node id (j<i>_<j>, w...); pick another", sid)
        _check_clear(doc, where, layout, [stops[sid]], clearance)
    one_way = _one_way(doc, lf)
    _check_lanes(doc, lf, layout, stops, stop_paths, one_way)

    units = _units(doc, uf, layout, drive, lidar, noise, clearance)
    tasks = parse_tasks(top.fields("tasks", TASK_KEYS), units.count, duration)
    if tasks.enabled and not (storage and layout.stations):
        raise doc.error(
            top.at("tasks"),
            "trips need at least one storage location (layout.storage, or pods) and one "
            "station (layout.stations)",
        )
    recovery = build_dataclass(doc, top.at("recovery"), top.get("recovery"), RecoveryConfig)
    events = parse_events(
        doc,
        top.at("events"),
        top.get("events"),
        layout=layout,
        unit_ids=units.ids,
        duration=duration,
    )
    return Scenario(
        name=name,
        description=description.strip(),
        duration=duration,
        dt=dt,
        seed=seed,
        layout=layout,
        units=units,
        map_server=map_server,
        storage=storage,
        one_way=one_way,
        tasks=tasks,
        events=events,
        recovery=recovery,
        source=doc.source,
    )


# ---------------------------------------------------------------------------- layout
def _layout(doc: Document, lf: Fields) -> Layout:
    """``Layout.from_dict`` of the layout section (warehouse keys renamed, bounded)."""
    data = {k: v for k, v in lf.data.items() if k not in ("storage", "one_way")}
    if "warehouse" in lf:
        wf = lf.fields("warehouse", WAREHOUSE_FIELDS)
        data["warehouse"] = {
            name: wf.number(key, **bounds)
            for key, (name, bounds) in WAREHOUSE_FIELDS.items()
            if key in wf
        }
    try:
        layout = Layout.from_dict(data)
    except LayoutError as exc:
        path = ("layout", *_field_path(exc.field))
        raise doc.error(path, str(exc)[len(exc.field) + 2 :]) from None
    for name, size in (("width", layout.width), ("height", layout.height)):
        if size > MAX_FLOOR_M:
            raise doc.error(lf.at("floor") + (name,), f"must be at most {MAX_FLOOR_M:g} m", size)
    for axis, lanes in (("x", layout.lane_x), ("y", layout.lane_y)):
        if any(b <= a for a, b in zip(lanes, lanes[1:], strict=False)):
            raise doc.error(lf.at("lanes") + (axis,), "must be strictly increasing", list(lanes))
    return layout


def _field_path(name: str) -> FieldPath:
    """``obstacles[2].box.x`` -> ``("obstacles", 2, "box", "x")``."""
    return tuple(
        int(index) if index else key for key, index in re.findall(r"([^.\[\]]+)|\[(\d+)\]", name)
    )


def _storage(
    doc: Document, lf: Fields, layout: Layout
) -> tuple[tuple[StoragePoint, ...], list[FieldPath]]:
    """The storage locations and the field path of each (module docstring)."""
    if "storage" in lf:
        points, paths = [], []
        for where, item in lf.items("storage"):
            sf = Fields(doc, where, item, ("id", "x", "y"), ("id", "x", "y"))
            x, y = sf.number("x", unit="metres"), sf.number("y", unit="metres")
            points.append(StoragePoint(sf.text("id", what="a storage id"), x, y))
            paths.append(where)
        ids = [p.id for p in points]
        for i, pid in enumerate(ids):
            if pid in ids[:i]:
                raise doc.error((*paths[i], "id"), "duplicates an earlier storage id", pid)
        return tuple(points), paths
    raw = lf.get("obstacles") or []
    points, paths = [], []
    for obstacle in layout.obstacles:
        if obstacle.kind is not Kind.POD:
            continue
        index = next(i for i, item in enumerate(raw) if item.get("id") == obstacle.id)
        where = lf.at("obstacles") + (index,)
        point = _lane_point(layout, obstacle.shape.x, obstacle.shape.y)
        if point is None:
            raise doc.error(where, "is a pod (a storage location) but the layout has no lanes")
        points.append(StoragePoint(obstacle.id, point[0], point[1], pod=obstacle.id))
        paths.append(where)
    return tuple(points), paths


def _lane_point(layout: Layout, x: float, y: float) -> Point | None:
    """The nearest point to (x, y) [m] on the lane grid (None without lanes both ways)."""
    xs, ys = layout.lane_x, layout.lane_y
    if not (xs and ys):
        return None
    candidates = [(lx, min(max(y, ys[0]), ys[-1])) for lx in xs]
    candidates += [(min(max(x, xs[0]), xs[-1]), ly) for ly in ys]
    return min(candidates, key=lambda p: math.hypot(p[0] - x, p[1] - y))


def _check_clear(
    doc: Document, where: FieldPath, layout: Layout, points: list[Point], clearance: float
) -> None:
    """Every point lies on the floor, farther than ``clearance`` [m] from every obstacle."""
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    for x, y in xy:
        if not (0 <= x <= layout.width and 0 <= y <= layout.height):
            raise doc.error(where, "must lie on the floor", (float(x), float(y)))
    for obstacle in layout.obstacles:
        gaps = obstacle.shape.distance(xy[:, 0], xy[:, 1])
        k = int(np.argmin(gaps))
        if gaps[k] <= clearance:
            x, y = xy[k]
            raise doc.error(
                where,
                f"({x:.2f}, {y:.2f}) is {gaps[k]:.2f} m from {obstacle.kind.value} "
                f"{obstacle.id!r}; a unit standing there needs more than {clearance:g} m "
                "(the larger of the unit's radius and the inscribed radius, plus one cell)",
            )


def _one_way(doc: Document, lf: Fields) -> tuple[tuple[str, str], ...]:
    pairs = []
    for where, item in lf.items("one_way"):
        if not (
            isinstance(item, list) and len(item) == 2 and all(isinstance(v, str) for v in item)
        ):
            raise doc.error(where, "must be a pair [junction_a, junction_b] of junction ids", item)
        pairs.append((item[0], item[1]))
    return tuple(pairs)


def _check_lanes(
    doc: Document,
    lf: Fields,
    layout: Layout,
    stops: Mapping[str, Point],
    stop_paths: Mapping[str, FieldPath],
    one_way: tuple[tuple[str, str], ...],
) -> None:
    """The lane graph accepts the stops and one-way lanes; its error goes to the field."""
    try:
        LaneGraph.from_warehouse(layout_warehouse(layout), stations=stops, one_way=one_way)
    except ValueError as exc:
        message = str(exc)
        where: FieldPath = lf.path
        for sid, path in stop_paths.items():
            if repr(sid) in message:
                where = path
        for i, (a, b) in enumerate(one_way):
            lane = tuple(sorted((a, b)))
            if f"({a!r}, {b!r})" in message or f"lane {lane!r} both" in message:
                where = lf.at("one_way") + (i,)
        raise doc.error(where, message) from None


# ---------------------------------------------------------------------------- units
def _units(
    doc: Document,
    uf: Fields,
    layout: Layout,
    drive: DriveLimits,
    lidar: LidarConfig,
    noise: PoseNoise,
    clearance: float,
) -> UnitsSpec:
    if "count" not in uf and "starts" not in uf:
        raise doc.error(uf.at("count"), "is required (or give starts)")
    count = uf.integer("count", None, low=1, high=MAX_UNITS)
    if "starts" not in uf:
        return UnitsSpec(_place(doc, uf, layout, count, clearance), drive, lidar, noise, True)
    starts = []
    for where, item in uf.items("starts"):
        sf = Fields(doc, where, item, ("x", "y", "yaw"), ("x", "y"))
        x, y = sf.number("x", unit="metres"), sf.number("y", unit="metres")
        starts.append(Pose2D(x, y, sf.number("yaw", 0.0, unit="radians")))
        _check_clear(doc, where, layout, [(x, y)], clearance)
        for k, other in enumerate(starts[:-1]):
            if math.hypot(other.x - x, other.y - y) <= 2 * drive.radius:
                raise doc.error(where, f"overlaps the start of u{k + 1}", (x, y))
    if not starts or len(starts) > MAX_UNITS:
        raise doc.error(uf.at("starts"), f"must hold 1 to {MAX_UNITS} poses", len(starts))
    if count is not None and count != len(starts):
        raise doc.error(uf.at("starts"), f"must hold units.count = {count} poses", len(starts))
    return UnitsSpec(tuple(starts), drive, lidar, noise, False)


def _place(
    doc: Document, uf: Fields, layout: Layout, count: int, clearance: float
) -> tuple[Pose2D, ...]:
    """Starts at free lane junctions, spread evenly (module docstring)."""
    junctions = np.array([(x, y) for y in layout.lane_y for x in layout.lane_x]).reshape(-1, 2)
    free = np.ones(len(junctions), dtype=bool)
    for obstacle in layout.obstacles:
        free &= obstacle.shape.distance(junctions[:, 0], junctions[:, 1]) > clearance
    spots = junctions[free]
    if len(spots) < count:
        raise doc.error(
            uf.at("count"),
            f"needs a free lane junction per unit and the layout has {len(spots)}; give "
            "units.starts",
            count,
        )
    picks = [spots[(k * len(spots)) // count] for k in range(count)]
    return tuple(Pose2D(float(x), float(y), 0.0) for x, y in picks)


# ---------------------------------------------------------------------------- map server
def _map_server(doc: Document, f: Fields, layout: Layout, drive: DriveLimits) -> MapServerSpec:
    """The map server section, checked by building the server's own Settings."""
    resolution = f.number("resolution", DEFAULT_RESOLUTION_M, unit="metres", low=0.01, high=1.0)
    width = math.ceil(layout.width / resolution - 1e-9)
    height = math.ceil(layout.height / resolution - 1e-9)
    if width * height > MAX_GRID_CELLS:
        raise doc.error(
            f.at("resolution"),
            f"gives a {width} x {height} grid, more than {MAX_GRID_CELLS} cells",
            resolution,
        )
    overrides: dict[str, Any] = {
        "policy": f.get("policy", Policy.DECAY.value),
        "grid": {"width": width, "height": height, "resolution": resolution},
        "max_clearing_range": f.get("max_clearing_range"),
    }
    for name, section in MAP_SERVER_SECTIONS.items():
        values = section().model_dump()
        if name == "inflation":  # Nav2 derives it from the footprint: so do we
            values["inscribed_radius"] = drive.radius
        values.update(f.fields(name, section.model_fields).data)
        overrides[name] = values
    try:
        settings = load_settings(None, overrides)
    except SettingsError as exc:
        name, _, detail = exc.problems[0].partition(": ")
        path = _field_path(name)
        if not path or path[0] not in MAP_SERVER_KEYS:
            where = f.at("resolution") if path[:1] == ("grid",) else f.path
            raise doc.error(where, exc.problems[0]) from None
        raise doc.error((*f.path, *path), detail) from None
    return MapServerSpec(
        policy=settings.policy,
        grid=settings.grid,
        sensor_model=settings.sensor_model,
        decay=settings.decay,
        inflation=settings.inflation,
        max_clearing_range=settings.max_clearing_range,
    )
