"""The ``layout`` section of a scenario: the warehouse, its stops and lanes.

- ``parse_layout``: ``fleet.layout.Layout.from_dict`` of the section (the ``warehouse``
  keys renamed to ``warehouse_layout``'s arguments and bounded, so a typo cannot build a
  500 km warehouse); its ``LayoutError`` becomes a ScenarioError at the field it names.
- ``parse_storage``: the storage locations: the ``storage`` points, else one per pod at
  the pod's *lane point* (``lane_point``: the nearest point to its centre on the lane
  grid, the lane centre lines between the outermost junctions).
- ``check_stops``: stations and storage locations (the lane graph's stops) have distinct
  ids that are not lane node ids, stand clear of every obstacle (``check_clear``), and
  are accepted, with the ``one_way`` lanes, by ``LaneGraph.from_warehouse``, whose error
  is placed at the stop or pair it names.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fleet.boxworld import BoxWorld, Warehouse
from fleet.layout import Kind, Layout, LayoutError
from planner.lane_graph import LaneGraph, one_way_loops
from scenarios.spec.yaml_lines import Document, FieldPath, Fields, field_path

Point = tuple[float, float]

MAX_FLOOR_M = 500.0
LAYOUT_KEYS = ("warehouse", "floor", "lanes", "obstacles", "stations", "storage", "one_way")
ONE_WAY_LOOPS = "loops"
"""``layout.one_way: loops``: every lane one way, Kiva-style (``one_way_loops``)."""
WAREHOUSE_FIELDS: Mapping[str, tuple[str, dict[str, Any]]] = {
    # scenario key: (warehouse_layout argument, its bounds here)
    "width": ("width_m", {"unit": "metres", "low": 0, "low_open": True, "high": MAX_FLOOR_M}),
    "height": ("height_m", {"unit": "metres", "low": 0, "low_open": True, "high": MAX_FLOOR_M}),
    "seed": ("seed", {"integer": True, "low": 0}),
    "aisle": ("aisle_m", {"unit": "metres", "low": 1.0, "high": 50.0}),
    "rack_depth": ("rack_depth_m", {"unit": "metres", "low": 0.2, "high": 50.0}),
    "cross_aisle_every": ("cross_aisle_every_m", {"unit": "metres", "low": 5.0, "high": 500.0}),
}
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


def parse_layout(doc: Document, lf: Fields) -> Layout:
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
        path = ("layout", *field_path(exc.field))
        raise doc.error(path, str(exc)[len(exc.field) + 2 :]) from None
    for name, size in (("width", layout.width), ("height", layout.height)):
        if size > MAX_FLOOR_M:
            raise doc.error(lf.at("floor") + (name,), f"must be at most {MAX_FLOOR_M:g} m", size)
    for axis, lanes in (("x", layout.lane_x), ("y", layout.lane_y)):
        if any(b <= a for a, b in zip(lanes, lanes[1:], strict=False)):
            raise doc.error(lf.at("lanes") + (axis,), "must be strictly increasing", list(lanes))
    return layout


def parse_storage(
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


def check_clear(
    doc: Document, where: FieldPath, layout: Layout, point: Point, clearance: float
) -> None:
    """``point`` (x, y) [m] lies on the floor, farther than ``clearance`` [m] from every
    obstacle; else a ScenarioError at ``where`` naming the nearest offender."""
    x, y = point
    if not (0 <= x <= layout.width and 0 <= y <= layout.height):
        raise doc.error(where, "must lie on the floor", point)
    for obstacle in layout.obstacles:
        gap = float(obstacle.shape.distance(x, y))
        if gap <= clearance:
            raise doc.error(
                where,
                f"({x:.2f}, {y:.2f}) is {gap:.2f} m from {obstacle.kind.value} "
                f"{obstacle.id!r}; a unit standing there needs more than {clearance:g} m "
                "(the larger of the unit's radius and the inscribed radius, plus one cell)",
            )


def parse_one_way(doc: Document, lf: Fields, layout: Layout) -> tuple[tuple[str, str], ...]:
    """The ``one_way`` pairs ``[junction_a, junction_b]`` (checked by ``check_lanes``), or
    ``loops``: Kiva-style one-way highways over the whole lane grid (``one_way_loops``)."""
    if lf.get("one_way") == ONE_WAY_LOOPS:
        n_x, n_y = len(layout.lane_x), len(layout.lane_y)
        try:
            return one_way_loops(n_x, n_y)
        except ValueError as exc:
            raise doc.error(lf.at("one_way"), str(exc), ONE_WAY_LOOPS) from None
    if isinstance(lf.get("one_way"), str):
        raise doc.error(
            lf.at("one_way"), f"must be {ONE_WAY_LOOPS!r} or a list of pairs", lf.get("one_way")
        )
    pairs = []
    for where, item in lf.items("one_way"):
        if not (
            isinstance(item, list) and len(item) == 2 and all(isinstance(v, str) for v in item)
        ):
            raise doc.error(where, "must be a pair [junction_a, junction_b] of junction ids", item)
        pairs.append((item[0], item[1]))
    return tuple(pairs)


def check_lanes(
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


def check_stops(
    doc: Document,
    lf: Fields,
    layout: Layout,
    storage: tuple[StoragePoint, ...],
    storage_paths: list[FieldPath],
    one_way: tuple[tuple[str, str], ...],
    clearance: float,
) -> None:
    """The stops' ids, clearances and lanes (module docstring); ``clearance`` [m]."""
    stop_paths = {s.id: lf.at("stations") + (i,) for i, s in enumerate(layout.stations)}
    for point, where in zip(storage, storage_paths, strict=True):
        if point.id in stop_paths:
            raise doc.error(where, "has the id of a station", point.id)
        stop_paths[point.id] = where
    stops = {s.id: (s.x, s.y) for s in (*layout.stations, *storage)}
    for sid, where in stop_paths.items():
        if LANE_NODE_ID.fullmatch(sid):
            raise doc.error(where, "is a lane graph node id (j<i>_<j>, w...); pick another", sid)
        check_clear(doc, where, layout, stops[sid], clearance)
    check_lanes(doc, lf, layout, stops, stop_paths, one_way)
