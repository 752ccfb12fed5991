"""The ``layout`` section of a scenario: the warehouse, its stops and lanes.

- ``parse_layout``: ``fleet.layout.Layout.from_dict`` of the section (the ``warehouse``
  keys renamed to ``warehouse_layout``'s arguments and bounded, so a typo cannot build a
  500 km warehouse); its ``LayoutError`` becomes a ScenarioError at the field it names.
- ``parse_storage``: the storage locations: the ``storage`` points, else one per pod at
  the pod's *lane point* (``lane_point``: the nearest point to its centre on the lane
  grid, the lane centre lines between the outermost junctions).
- ``check_stops``: stations and storage locations (the lane graph's stops) have distinct
  ids that are not lane node ids, stand clear of every obstacle (``check_clear_of``), and
  are accepted, with the ``one_way`` lanes, by ``LaneGraph.from_warehouse``, whose error
  is placed at the stop or pair it names.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Discriminator, Field

from fleet.boxworld import BoxWorld, Warehouse
from fleet.layout import Kind, Layout, LayoutError, Obstacle
from mapserver.service.validation import Section, number, reworded, text, variant, variant_tag
from planner.lane_graph import LaneGraph, one_way_aisles, one_way_loops
from scenarios.spec.yaml_lines import Document, FieldPath, field_path

Point = tuple[float, float]

MAX_FLOOR_M = 500.0
ONE_WAY_PATTERNS = {"loops": one_way_loops, "aisles": one_way_aisles}
"""``layout.one_way`` by name: the pattern's pairs for an ``n_x`` x ``n_y`` junction grid
(``loops``: every lane one way, Kiva-style, ``one_way_loops``; ``aisles``: the rows one
way, alternating, the columns two-way, ``one_way_aisles``)."""
LANE_NODE_ID = re.compile(r"[jw]\d+_\d+([hv]\d+)?")
"""Ids the lane graph gives its junctions and waypoints; stops may not take them."""


@dataclass(frozen=True)
class StoragePoint:
    """A storage location: ``id`` and the lane point (x, y) [m] where a unit stops to
    pick; ``pod``: the pod it serves (None for a ``layout.storage`` point)."""

    id: str
    x: float
    y: float
    pod: str | None = None


# ---------------------------------------------------------------------------- the file
_Metres = number("metres", gt=0, le=MAX_FLOOR_M)


class WarehouseFields(Section):
    """``layout.warehouse``: ``warehouse_layout``'s arguments [m], bounded so that a typo
    cannot build a 500 km warehouse (absent: its defaults)."""

    width: _Metres | None = None
    height: _Metres | None = None
    seed: number(integer=True, ge=0) | None = None
    aisle: number("metres", ge=1.0, le=50.0) | None = None
    rack_depth: number("metres", ge=0.2, le=50.0) | None = None
    cross_aisle_every: number("metres", ge=5.0, le=500.0) | None = None

    def arguments(self) -> dict[str, Any]:
        """The given values as ``warehouse_layout`` arguments (``width_m``, ...)."""
        given = self.model_dump(exclude_none=True)
        return {k if k == "seed" else f"{k}_m": v for k, v in given.items()}


class StorageFields(Section):
    """A ``layout.storage`` point: id and (x, y) [m]."""

    id: text("a storage id")
    x: number("metres")
    y: number("metres")


OneWayPair = Annotated[
    list[str],
    Field(min_length=2, max_length=2),
    reworded("must be a pair [junction_a, junction_b] of junction ids"),
]
OneWay = Annotated[
    variant(
        Annotated[
            Literal[tuple(ONE_WAY_PATTERNS)],
            reworded("must be 'loops', 'aisles' or a list of pairs"),
        ],
        "pattern",
    )
    | variant(list[OneWayPair], "pairs"),
    Discriminator(
        lambda v: variant_tag("pattern" if isinstance(v, str) else "pairs"),
    ),
]
"""``loops``, ``aisles`` or a list of ``[junction_a, junction_b]`` lanes driven only a -> b."""


class LayoutFields(Section):
    """The ``layout`` section. ``floor``, ``warehouse``, ``lanes``, ``obstacles`` and
    ``stations`` are checked by ``fleet.layout.Layout.from_dict`` (docs/scenarios.md)."""

    warehouse: WarehouseFields = WarehouseFields()
    floor: Any = None
    lanes: Any = None
    obstacles: Any = None
    stations: Any = None
    storage: list[StorageFields] | None = None
    one_way: OneWay | None = None


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


def parse_layout(doc: Document, lf: LayoutFields) -> Layout:
    """``Layout.from_dict`` of the layout section (warehouse keys renamed, bounded)."""
    given = lf.model_fields_set - {"storage", "one_way"}
    data = {k: getattr(lf, k) for k in given}
    if "warehouse" in given:
        data["warehouse"] = lf.warehouse.arguments()
    try:
        layout = Layout.from_dict(data)
    except LayoutError as exc:
        path = ("layout", *field_path(exc.field))
        raise doc.error(path, str(exc)[len(exc.field) + 2 :]) from None
    for name, size in (("width", layout.width), ("height", layout.height)):
        if size > MAX_FLOOR_M:
            raise doc.error(("layout", "floor", name), f"must be at most {MAX_FLOOR_M:g} m", size)
    for axis, lanes in (("x", layout.lane_x), ("y", layout.lane_y)):
        if any(b <= a for a, b in zip(lanes, lanes[1:], strict=False)):
            raise doc.error(("layout", "lanes", axis), "must be strictly increasing", list(lanes))
    return layout


def parse_storage(
    doc: Document, lf: LayoutFields, layout: Layout
) -> tuple[tuple[StoragePoint, ...], list[FieldPath]]:
    """The storage locations and the field path of each (module docstring)."""
    if "storage" in lf.model_fields_set:
        points = [StoragePoint(p.id, p.x, p.y) for p in lf.storage or ()]
        paths: list[FieldPath] = [("layout", "storage", i) for i in range(len(points))]
        ids = [p.id for p in points]
        for i, pid in enumerate(ids):
            if pid in ids[:i]:
                raise doc.error((*paths[i], "id"), "duplicates an earlier storage id", pid)
        return tuple(points), paths
    raw = lf.obstacles or []
    points, paths = [], []
    for obstacle in layout.obstacles:
        if obstacle.kind is not Kind.POD:
            continue
        index = next(i for i, item in enumerate(raw) if item.get("id") == obstacle.id)
        where = ("layout", "obstacles", index)
        point = lane_point(layout, obstacle.shape.x, obstacle.shape.y)
        if point is None:
            raise doc.error(where, "is a pod (a storage location) but the layout has no lanes")
        points.append(StoragePoint(obstacle.id, point[0], point[1], pod=obstacle.id))
        paths.append(where)
    return tuple(points), paths


def lane_point(layout: Layout, x: float, y: float) -> Point | None:
    """The nearest point to (x, y) [m] on the lane grid (None without lanes both ways)."""
    xs, ys = layout.lane_x, layout.lane_y
    if not (xs and ys):
        return None
    candidates = [(lx, min(max(y, ys[0]), ys[-1])) for lx in xs]
    candidates += [(min(max(x, xs[0]), xs[-1]), ly) for ly in ys]
    return min(candidates, key=lambda p: math.hypot(p[0] - x, p[1] - y))


def first_offenders(
    layout: Layout, points: Sequence[Point], clearance: float
) -> list[tuple[Obstacle, float] | None]:
    """For each of ``points`` (x, y) [m], the first obstacle of the layout (in its order)
    within ``clearance`` [m] of it and that gap [m], or None when it stands clear. One
    vectorised distance per obstacle over all points, so a thousand stops against
    thousands of obstacles take a fraction of a second, not half a minute."""
    found: list[tuple[Obstacle, float] | None] = [None] * len(points)
    if not points:
        return found
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    open_ = np.ones(len(xy), dtype=bool)  # no offender found yet
    for obstacle in layout.obstacles:
        gaps = np.asarray(obstacle.shape.distance(xy[:, 0], xy[:, 1]), dtype=np.float64)
        hit = open_ & (gaps <= clearance)
        for i in np.flatnonzero(hit):
            found[i] = (obstacle, float(gaps[i]))
        open_ &= ~hit
    return found


def check_clear_of(
    doc: Document,
    where: FieldPath,
    layout: Layout,
    point: Point,
    clearance: float,
    offender: tuple[Obstacle, float] | None,
) -> None:
    """``point`` (x, y) [m] lies on the floor and ``offender`` (``first_offenders``: the
    first obstacle within ``clearance`` [m] of it, and the gap) is None; else a
    ScenarioError at ``where`` naming the offender."""
    x, y = point
    if not (0 <= x <= layout.width and 0 <= y <= layout.height):
        raise doc.error(where, "must lie on the floor", point)
    if offender is not None:
        obstacle, gap = offender
        raise doc.error(
            where,
            f"({x:.2f}, {y:.2f}) is {gap:.2f} m from {obstacle.kind.value} "
            f"{obstacle.id!r}; a unit standing there needs more than {clearance:g} m "
            "(the larger of the unit's radius and the inscribed radius, plus one cell)",
        )


def parse_one_way(doc: Document, lf: LayoutFields, layout: Layout) -> tuple[tuple[str, str], ...]:
    """The ``one_way`` pairs ``[junction_a, junction_b]`` (checked by ``check_lanes``), or
    a pattern over the whole lane grid (``ONE_WAY_PATTERNS``: ``loops``, Kiva-style
    one-way highways; ``aisles``, the rows one way and the columns two-way)."""
    if isinstance(lf.one_way, str):
        try:
            return ONE_WAY_PATTERNS[lf.one_way](len(layout.lane_x), len(layout.lane_y))
        except ValueError as exc:
            raise doc.error(("layout", "one_way"), str(exc), lf.one_way) from None
    return tuple((a, b) for a, b in lf.one_way or ())


def check_lanes(
    doc: Document,
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
        where: FieldPath = ("layout",)
        for sid, path in stop_paths.items():
            if repr(sid) in message:
                where = path
        for i, (a, b) in enumerate(one_way):
            lane = tuple(sorted((a, b)))
            if f"({a!r}, {b!r})" in message or f"lane {lane!r} both" in message:
                where = ("layout", "one_way", i)
        raise doc.error(where, message) from None


def check_stops(
    doc: Document,
    layout: Layout,
    storage: tuple[StoragePoint, ...],
    storage_paths: list[FieldPath],
    one_way: tuple[tuple[str, str], ...],
    clearance: float,
) -> None:
    """The stops' ids, clearances and lanes (module docstring); ``clearance`` [m]."""
    stop_paths: dict[str, FieldPath] = {
        s.id: ("layout", "stations", i) for i, s in enumerate(layout.stations)
    }
    for point, where in zip(storage, storage_paths, strict=True):
        if point.id in stop_paths:
            raise doc.error(where, "has the id of a station", point.id)
        stop_paths[point.id] = where
    stops = {s.id: (s.x, s.y) for s in (*layout.stations, *storage)}
    offenders = dict(
        zip(stops, first_offenders(layout, list(stops.values()), clearance), strict=True)
    )
    for sid, where in stop_paths.items():
        if LANE_NODE_ID.fullmatch(sid):
            raise doc.error(where, "is a lane graph node id (j<i>_<j>, w...); pick another", sid)
        check_clear_of(doc, where, layout, stops[sid], clearance, offenders[sid])
    check_lanes(doc, layout, stops, stop_paths, one_way)
