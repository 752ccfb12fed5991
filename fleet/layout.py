"""A warehouse layout: the floor, its objects (with ids) and its pick stations.

The description the PyBullet world is built from and that scenarios edit. Pure data,
validated on construction; every error names the field and the offending value.

- ``Obstacle``: a solid object with an id: a wall, a rack, a pod, a pick station's booth,
  a tote, a pallet or a person; a ``Box`` or ``Cylinder`` footprint (``fleet.shapes``)
  and a height [m] (each kind has a default, ``DEFAULT_HEIGHT_M``).
- ``Station``: a pick station's dock point [m], where a unit stops to be served.
- ``Layout``: the floor ``[0, width] x [0, height]`` [m], obstacles, stations and the lane
  centre lines units drive on. Built from ``fleet.boxworld.warehouse_layout``
  (``Layout.from_warehouse``) or from a mapping (``Layout.from_dict``, the scenario
  files' form)::

      floor: {width: 30.0, height: 20.0}          # or: warehouse: {width_m: 30, ...}
      lanes: {x: [1.8, 28.2], y: [5.0, 9.5]}      # optional
      obstacles:
        - {id: rack-1, kind: rack, box: {x: 10, y: 7, size_x: 8, size_y: 1}}
        - {id: pod-1, kind: pod, box: {x: 4, y: 2, size_x: 1, size_y: 1, yaw: 0.3}}
        - {id: alice, kind: person, cylinder: {x: 6, y: 5, radius: 0.25}, height: 1.7}
      stations:
        - {id: pick-1, x: 2.0, y: 1.5}

  ``warehouse`` takes the keyword arguments of ``warehouse_layout`` and gives floor,
  walls, racks, pallets and lanes; ``obstacles``, ``stations`` and ``lanes`` are added to
  (lanes: replace) what it gives.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

from fleet.boxworld import Warehouse, warehouse_layout
from fleet.shapes import Box, Cylinder, Shape
from mapserver.core.errors import FieldError, FleetmapError


class LayoutError(FleetmapError, ValueError):
    """An invalid layout; ``field`` is the dotted path of the bad value (``obstacles[2].id``)."""

    def __init__(self, field: str, value: Any, reason: str) -> None:
        self.field = field
        self.value = value
        text = repr(value)
        text = text if len(text) <= 80 else text[:77] + "..."
        super().__init__(f"{field}: {reason}, got {text}")


class Kind(StrEnum):
    """What an obstacle is."""

    WALL = "wall"
    RACK = "rack"
    POD = "pod"  # a mobile shelf that units carry (Kiva style)
    STATION = "station"  # a pick station's booth
    TOTE = "tote"
    PALLET = "pallet"
    PERSON = "person"


DEFAULT_HEIGHT_M: Mapping[Kind, float] = {
    Kind.WALL: 3.0,
    Kind.RACK: 2.5,
    Kind.POD: 2.0,
    Kind.STATION: 1.0,
    Kind.TOTE: 0.35,  # above the default LiDAR plane (0.2 m), so a dropped tote is seen
    Kind.PALLET: 1.2,  # a loaded pallet
    Kind.PERSON: 1.75,
}
"""[m] the height of each kind of obstacle when a layout gives none."""


@dataclass(frozen=True)
class Obstacle:
    """A solid object: ``id`` (unique in its layout), ``kind``, footprint ``shape`` and
    ``height`` [m] above the floor (None: ``DEFAULT_HEIGHT_M[kind]``)."""

    id: str
    kind: Kind
    shape: Shape
    height: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not self.id.strip():
            raise FieldError("id", self.id, "must be a non-empty string")
        try:
            object.__setattr__(self, "kind", Kind(self.kind))
        except ValueError:
            raise FieldError(
                "kind", self.kind, f"must be one of {[k.value for k in Kind]}"
            ) from None
        if not isinstance(self.shape, Box | Cylinder):
            raise FieldError("shape", self.shape, "must be a Box or a Cylinder")
        if self.height is None:
            object.__setattr__(self, "height", DEFAULT_HEIGHT_M[self.kind])
        if isinstance(self.height, bool) or not (
            isinstance(self.height, int | float) and math.isfinite(self.height) and self.height > 0
        ):
            raise FieldError("height", self.height, "must be a positive number of metres")

    def moved(self, x: float, y: float, yaw: float | None = None) -> Obstacle:
        """This obstacle with its footprint centred at (x, y) [m], turned to yaw [rad] if given."""
        return replace(self, shape=self.shape.moved(x, y, yaw))


@dataclass(frozen=True)
class Station:
    """A pick station: ``id`` and the dock point (x, y) [m] where a unit stops."""

    id: str
    x: float
    y: float

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not self.id.strip():
            raise FieldError("id", self.id, "must be a non-empty string")
        for name in ("x", "y"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (
                isinstance(value, int | float) and math.isfinite(value)
            ):
                raise FieldError(name, value, "must be a finite number of metres")


@dataclass(frozen=True)
class Layout:
    """A warehouse floor ``[0, width] x [0, height]`` [m] and what stands on it.

    obstacles: every solid object, ids unique; each footprint within the floor.
    stations: dock points, ids unique, on the floor and outside every obstacle.
    lane_x, lane_y: [m] centre lines of the vertical and horizontal lanes (may be empty).
    """

    width: float
    height: float
    obstacles: tuple[Obstacle, ...] = ()
    stations: tuple[Station, ...] = ()
    lane_x: tuple[float, ...] = ()
    lane_y: tuple[float, ...] = ()
    _by_id: dict[str, Obstacle] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (
                isinstance(value, int | float) and math.isfinite(value) and value > 0
            ):
                raise LayoutError(name, value, "must be a positive number of metres")
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        object.__setattr__(self, "stations", tuple(self.stations))
        by_id: dict[str, Obstacle] = {}
        for i, obstacle in enumerate(self.obstacles):
            if not isinstance(obstacle, Obstacle):
                raise LayoutError(f"obstacles[{i}]", obstacle, "must be an Obstacle")
            if obstacle.id in by_id:
                raise LayoutError(f"obstacles[{i}].id", obstacle.id, "duplicates an earlier id")
            self.check_on_floor(obstacle, f"obstacles[{i}]")
            by_id[obstacle.id] = obstacle
        object.__setattr__(self, "_by_id", by_id)
        seen: set[str] = set()
        for i, station in enumerate(self.stations):
            if station.id in seen:
                raise LayoutError(f"stations[{i}].id", station.id, "duplicates an earlier id")
            seen.add(station.id)
            if not (0 <= station.x <= self.width and 0 <= station.y <= self.height):
                raise LayoutError(f"stations[{i}]", (station.x, station.y), "must be on the floor")
            for obstacle in self.obstacles:
                if obstacle.shape.contains(station.x, station.y):
                    raise LayoutError(
                        f"stations[{i}]",
                        (station.x, station.y),
                        f"must not lie inside obstacle {obstacle.id!r}",
                    )
        for name in ("lane_x", "lane_y"):
            lanes = tuple(float(v) for v in getattr(self, name))
            limit = self.width if name == "lane_x" else self.height
            if any(not 0 <= v <= limit for v in lanes):
                raise LayoutError(name, lanes, f"must lie within [0, {limit}] m")
            object.__setattr__(self, name, lanes)

    def check_on_floor(self, obstacle: Obstacle, where: str = "obstacle") -> None:
        """Raise LayoutError (field ``where``) when ``obstacle``'s footprint leaves the floor."""
        xmin, ymin, xmax, ymax = obstacle.shape.bounds()
        slack = 1e-9  # [m] boxes computed from the floor size may round a hair outside it
        if (
            xmin < -slack
            or ymin < -slack
            or xmax > self.width + slack
            or ymax > self.height + slack
        ):
            raise LayoutError(where, obstacle.shape, "must lie within the floor")

    def obstacle(self, obstacle_id: str) -> Obstacle:
        """The obstacle with this id; KeyError names it when there is none."""
        try:
            return self._by_id[obstacle_id]
        except KeyError:
            raise KeyError(f"obstacle id {obstacle_id!r} is not in the layout") from None

    @classmethod
    def from_warehouse(cls, warehouse: Warehouse) -> Layout:
        """A layout of ``fleet.boxworld`` warehouse boxes: ``wall-<i>``, ``rack-<i>``,
        ``pallet-<i>`` (numbered from 1 per kind, in the warehouse's order), and its lanes."""
        kinds = warehouse.kinds or ("rack",) * len(warehouse.world)
        counts: dict[str, int] = {}
        obstacles = []
        for kind, (xmin, ymin, xmax, ymax) in zip(kinds, warehouse.world.boxes, strict=True):
            counts[kind] = counts.get(kind, 0) + 1
            shape = Box.from_bounds(float(xmin), float(ymin), float(xmax), float(ymax))
            obstacles.append(Obstacle(f"{kind}-{counts[kind]}", Kind(kind), shape))
        return cls(
            width=warehouse.width,
            height=warehouse.height,
            obstacles=tuple(obstacles),
            lane_x=warehouse.lane_x,
            lane_y=warehouse.lane_y,
        )

    @classmethod
    def from_dict(cls, data: Any) -> Layout:
        """A layout from a mapping (module docstring); LayoutError names the bad field."""
        if not isinstance(data, Mapping):
            raise LayoutError("layout", data, "must be a mapping")
        unknown = sorted(set(data) - {"floor", "warehouse", "lanes", "obstacles", "stations"})
        if unknown:
            raise LayoutError(unknown[0], data[unknown[0]], "is not a layout field")
        if ("floor" in data) == ("warehouse" in data):
            raise LayoutError("floor", data.get("floor"), "give exactly one of floor, warehouse")
        if "warehouse" in data:
            kwargs = _mapping(data["warehouse"], "warehouse")
            try:
                base = cls.from_warehouse(warehouse_layout(**kwargs))
            except (TypeError, ValueError) as exc:
                raise LayoutError("warehouse", kwargs, str(exc)) from None
        else:
            floor = _mapping(data["floor"], "floor", required=("width", "height"))
            base = cls(width=floor["width"], height=floor["height"])
        lane_x, lane_y = base.lane_x, base.lane_y
        if "lanes" in data:
            lanes = _mapping(data["lanes"], "lanes", optional=("x", "y"))
            lane_x = _numbers(lanes.get("x", ()), "lanes.x")
            lane_y = _numbers(lanes.get("y", ()), "lanes.y")
        obstacles = list(base.obstacles)
        ids = {o.id for o in obstacles}
        for i, item in enumerate(_list(data.get("obstacles", []), "obstacles")):
            where = f"obstacles[{i}]"
            obstacle = _obstacle(item, where)
            if obstacle.id in ids:
                raise LayoutError(f"{where}.id", obstacle.id, "duplicates an earlier id")
            ids.add(obstacle.id)
            base.check_on_floor(obstacle, where)
            obstacles.append(obstacle)
        stations = tuple(
            _station(item, f"stations[{i}]")
            for i, item in enumerate(_list(data.get("stations", []), "stations"))
        )
        return cls(base.width, base.height, tuple(obstacles), stations, lane_x, lane_y)

    def to_dict(self) -> dict[str, Any]:
        """The ``from_dict`` form of this layout (``floor``, ``lanes``, every obstacle)."""
        out: dict[str, Any] = {
            "floor": {"width": self.width, "height": self.height},
            "lanes": {"x": list(self.lane_x), "y": list(self.lane_y)},
            "obstacles": [],
            "stations": [{"id": s.id, "x": s.x, "y": s.y} for s in self.stations],
        }
        for obstacle in self.obstacles:
            shape = obstacle.shape
            item: dict[str, Any] = {"id": obstacle.id, "kind": obstacle.kind.value}
            if isinstance(shape, Box):
                item["box"] = {
                    "x": shape.x,
                    "y": shape.y,
                    "size_x": shape.size_x,
                    "size_y": shape.size_y,
                    "yaw": shape.yaw,
                }
            else:
                item["cylinder"] = {"x": shape.x, "y": shape.y, "radius": shape.radius}
            item["height"] = obstacle.height
            out["obstacles"].append(item)
        return out


def _mapping(
    value: Any, where: str, required: tuple[str, ...] = (), optional: tuple[str, ...] = ()
) -> dict[str, Any]:
    """``value`` as a dict; with ``required`` or ``optional`` given, exactly those keys."""
    if not isinstance(value, Mapping):
        raise LayoutError(where, value, "must be a mapping")
    if required or optional:
        for key in required:
            if key not in value:
                raise LayoutError(f"{where}.{key}", None, "is required")
        for key in value:
            if key not in required and key not in optional:
                raise LayoutError(f"{where}.{key}", value[key], "is not a known field")
    return dict(value)


def _list(value: Any, where: str) -> list[Any]:
    if not isinstance(value, list | tuple):
        raise LayoutError(where, value, "must be a list")
    return list(value)


def _numbers(value: Any, where: str) -> tuple[float, ...]:
    items = _list(value, where)
    for i, v in enumerate(items):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise LayoutError(f"{where}[{i}]", v, "must be a finite number of metres")
    return tuple(float(v) for v in items)


def _build(where: str, build: Any, **kwargs: Any) -> Any:
    """``build(**kwargs)``; its FieldError becomes a LayoutError at ``where.field``."""
    try:
        return build(**kwargs)
    except FieldError as exc:
        raise LayoutError(f"{where}.{exc.field}", kwargs.get(exc.field), exc.reason) from None
    except ValueError as exc:
        raise LayoutError(where, kwargs, str(exc)) from None


def _obstacle(item: Any, where: str) -> Obstacle:
    data = _mapping(item, where)
    shapes = [key for key in ("box", "cylinder") if key in data]
    if len(shapes) != 1:
        raise LayoutError(where, item, "needs exactly one of box, cylinder")
    allowed = {"id", "kind", "height", shapes[0]}
    for key in data:
        if key not in allowed:
            raise LayoutError(f"{where}.{key}", data[key], "is not a known field")
    for key in ("id", "kind"):
        if key not in data:
            raise LayoutError(f"{where}.{key}", None, "is required")
    if shapes[0] == "box":
        fields = _mapping(
            data["box"], f"{where}.box", ("x", "y", "size_x", "size_y"), optional=("yaw",)
        )
        shape: Shape = _build(f"{where}.box", Box, **fields)
    else:
        fields = _mapping(data["cylinder"], f"{where}.cylinder", ("x", "y", "radius"))
        shape = _build(f"{where}.cylinder", Cylinder, **fields)
    return _build(
        where, Obstacle, id=data["id"], kind=data["kind"], shape=shape, height=data.get("height")
    )


def _station(item: Any, where: str) -> Station:
    data = _mapping(item, where, ("id", "x", "y"))
    return _build(where, Station, **data)
