"""A scenario's timed events: what changes in the world, and when.

Every event happens at ``at`` [s] of sim time (0 <= at <= the scenario's duration). One
key names the kind and the object::

    - {at: 40, move: pod-7, x: 33.0, y: 1.9, yaw: 0.0}   # an obstacle's centre goes to (x, y)
    - {at: 60, drop: tote-1, x: 20.0, y: 16.3, size: [0.6, 0.4], yaw: 0.0}   # a new tote
    - {at: 90, remove: tote-1}                           # an obstacle leaves the world
    - {at: 30, person: ann, path: [[20, 2], [20, 28]], speed: 1.2, radius: 0.25}
    - {at: 50, breakdown: u3, duration: 60}              # a unit stops where it is

- ``move``: any obstacle but a walking person; ``yaw`` [rad] optional (a box keeps its
  yaw if not given). The footprint must stay on the floor.
- ``drop``: a tote (``fleet.layout.Kind.TOTE``), a box of ``size`` [m] (one number: a
  square; ``[size_x, size_y]``; default ``DEFAULT_TOTE_M``), ``yaw`` [rad] (default 0),
  ``height`` [m] (default the tote height). Its id must be new.
- ``remove``: any obstacle but a walking person.
- ``person``: a cylinder of ``radius`` [m] (default 0.25, 0.05 to 2) and ``height`` [m]
  appears at the path's first point at ``at``, walks the polyline ``path`` at ``speed``
  [m/s] (default 1.2, 0.1 to 10) and leaves the world when it reaches the last point
  (``PersonEvent.end``). The path must stay on the floor and clear of walls and racks.
- ``breakdown``: unit ``u<k>`` stops where it is at ``at`` and stands still for
  ``duration`` [s] (omitted or null: to the end of the run), a body other units must
  drive around; then it carries on with its task.

Ids are checked in time order (ties in file order): a moved or removed object must be in
the layout or dropped by an earlier event, and not removed since; a dropped tote or a
person needs an id no obstacle, person or unit has at that time.

``ScheduledChange`` is what the runner hands to ``FleetSim.schedule``: the world change
of each event at its time; a walking person is one change per sim step (``dt``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, ClassVar

import numpy as np
from pydantic import Discriminator, Field

from fleet.layout import Kind, Layout, LayoutError, Obstacle
from fleet.shapes import Box, Cylinder
from mapserver.service.validation import Section, number, reworded, text, variant, variant_tag
from scenarios.spec.yaml_lines import Document, FieldPath

if TYPE_CHECKING:  # the world imports PyBullet; reading a scenario file does not
    from fleet.world import World

Point = tuple[float, float]

DEFAULT_TOTE_M = (0.6, 0.4)
"""[m] a dropped tote's footprint when the event gives no ``size``."""
PERSON_SPEED = 1.2  # [m/s] walking pace
PERSON_RADIUS = 0.25  # [m]
FIXED_KINDS = (Kind.WALL, Kind.RACK)
"""Kinds a person's path may not pass through."""


@dataclass(frozen=True)
class ScheduledChange:
    """A world change for ``FleetSim.schedule``: at ``time`` [s], ``apply(world)``, made by
    ``event``."""

    time: float
    event: Event
    apply: Callable[[World], None]


@dataclass(frozen=True)
class MoveEvent:
    """At ``at`` [s] obstacle ``object_id``'s centre goes to (x, y) [m], turned to ``yaw``
    [rad] if given."""

    at: float
    object_id: str
    x: float
    y: float
    yaw: float | None = None
    kind: ClassVar[str] = "move"

    def describe(self) -> str:
        """A sentence for people (replay log lines)."""
        return f"{self.object_id} moved to ({self.x:.2f}, {self.y:.2f})"

    def changes(self, dt: float) -> tuple[ScheduledChange, ...]:
        """The world change at ``at``."""
        return (ScheduledChange(self.at, self, self._apply),)

    def _apply(self, world: World) -> None:
        world.move(self.object_id, self.x, self.y, self.yaw)


@dataclass(frozen=True)
class DropEvent:
    """At ``at`` [s] a tote ``object_id`` appears: a box centred at (x, y) [m] of
    ``size_x`` by ``size_y`` [m] turned by ``yaw`` [rad], ``height`` [m] (None: the
    tote default)."""

    at: float
    object_id: str
    x: float
    y: float
    size_x: float = DEFAULT_TOTE_M[0]
    size_y: float = DEFAULT_TOTE_M[1]
    yaw: float = 0.0
    height: float | None = None
    kind: ClassVar[str] = "drop"

    def obstacle(self) -> Obstacle:
        """The dropped tote."""
        shape = Box(self.x, self.y, self.size_x, self.size_y, self.yaw)
        return Obstacle(self.object_id, Kind.TOTE, shape, self.height)

    def describe(self) -> str:
        """A sentence for people."""
        return f"{self.object_id} dropped at ({self.x:.2f}, {self.y:.2f})"

    def changes(self, dt: float) -> tuple[ScheduledChange, ...]:
        """The world change at ``at``."""
        return (ScheduledChange(self.at, self, self._apply),)

    def _apply(self, world: World) -> None:
        world.add(self.obstacle())


@dataclass(frozen=True)
class RemoveEvent:
    """At ``at`` [s] obstacle ``object_id`` leaves the world."""

    at: float
    object_id: str
    kind: ClassVar[str] = "remove"

    def describe(self) -> str:
        """A sentence for people."""
        return f"{self.object_id} removed"

    def changes(self, dt: float) -> tuple[ScheduledChange, ...]:
        """The world change at ``at``."""
        return (ScheduledChange(self.at, self, self._apply),)

    def _apply(self, world: World) -> None:
        world.remove(self.object_id)


@dataclass(frozen=True)
class PersonEvent:
    """A person ``object_id`` (a cylinder of ``radius`` [m], ``height`` [m]) walks the
    polyline ``path`` [m] at ``speed`` [m/s] from ``at`` [s] to ``end`` [s], then leaves."""

    at: float
    object_id: str
    path: tuple[Point, ...]
    speed: float = PERSON_SPEED
    radius: float = PERSON_RADIUS
    height: float | None = None
    kind: ClassVar[str] = "person"

    @property
    def length(self) -> float:
        """[m] the length of the path."""
        return float(np.sum(np.hypot(*np.diff(np.asarray(self.path), axis=0).T)))

    @property
    def end(self) -> float:
        """[s] when the person reaches the last point and leaves."""
        return self.at + self.length / self.speed

    def position_at(self, t: float) -> Point | None:
        """(x, y) [m] at sim time ``t`` [s]; None before ``at`` and after ``end``."""
        if not self.at <= t <= self.end:
            return None
        xy = np.asarray(self.path)
        walked = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))))
        s = (t - self.at) * self.speed
        return (float(np.interp(s, walked, xy[:, 0])), float(np.interp(s, walked, xy[:, 1])))

    def obstacle(self, x: float, y: float) -> Obstacle:
        """The person standing at (x, y) [m]."""
        return Obstacle(self.object_id, Kind.PERSON, Cylinder(x, y, self.radius), self.height)

    def describe(self) -> str:
        """A sentence for people."""
        (x0, y0), (x1, y1) = self.path[0], self.path[-1]
        return (
            f"{self.object_id} walks from ({x0:.2f}, {y0:.2f}) to ({x1:.2f}, {y1:.2f}) "
            f"at {self.speed:g} m/s"
        )

    def changes(self, dt: float) -> tuple[ScheduledChange, ...]:
        """Appear at ``at``; a move at ``at + k dt`` for each k >= 1 before ``end``;
        leave at ``end``."""
        x0, y0 = self.path[0]
        out = [ScheduledChange(self.at, self, _Add(self.obstacle(x0, y0)))]
        end = self.end
        k = 1
        while self.at + k * dt < end - 1e-9:
            t = self.at + k * dt
            x, y = self.position_at(t) or self.path[-1]
            out.append(ScheduledChange(t, self, _Move(self.object_id, x, y)))
            k += 1
        out.append(ScheduledChange(end, self, _Remove(self.object_id)))
        return tuple(out)


@dataclass(frozen=True)
class BreakdownEvent:
    """At ``at`` [s] unit ``unit_id`` stops where it is for ``duration`` [s] (None: to
    the end of the run)."""

    at: float
    unit_id: str
    duration: float | None = None
    kind: ClassVar[str] = "breakdown"

    @property
    def until(self) -> float:
        """[s] when the unit drives again (inf: never)."""
        return math.inf if self.duration is None else self.at + self.duration

    def describe(self) -> str:
        """A sentence for people."""
        span = "for good" if self.duration is None else f"for {self.duration:g} s"
        return f"{self.unit_id} broke down {span}"

    def changes(self, dt: float) -> tuple[ScheduledChange, ...]:
        """None: a breakdown changes a unit, not the world (the runner stops it)."""
        return ()


Event = MoveEvent | DropEvent | RemoveEvent | PersonEvent | BreakdownEvent
EVENT_KINDS: tuple[str, ...] = ("move", "drop", "remove", "person", "breakdown")


@dataclass(frozen=True)
class _Add:
    obstacle: Obstacle

    def __call__(self, world: World) -> None:
        world.add(self.obstacle)


@dataclass(frozen=True)
class _Move:
    object_id: str
    x: float
    y: float

    def __call__(self, world: World) -> None:
        world.move(self.object_id, self.x, self.y)


@dataclass(frozen=True)
class _Remove:
    object_id: str

    def __call__(self, world: World) -> None:
        world.remove(self.object_id)


# ---------------------------------------------------------------------------- the file
_Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
PointField = Annotated[
    list[Annotated[float, Field(allow_inf_nan=False)]],
    Field(min_length=2, max_length=2),
    reworded("must be a point [x, y] of two numbers of metres"),
]
"""``[x, y]`` [m]."""
Size = Annotated[
    _Positive | Annotated[list[_Positive], Field(min_length=2, max_length=2)],
    reworded("must be a positive number of metres or [size_x, size_y]"),
]
"""A tote's side [m] (a square) or ``[size_x, size_y]`` [m]."""
Height = number("metres", gt=0) | None
"""[m] None: the kind's default height."""


class _EventFields(Section):
    at: number("seconds", ge=0)


class MoveFields(_EventFields):
    """``{at, move: id, x, y, yaw}``."""

    move: text("an object id")
    x: number("metres")
    y: number("metres")
    yaw: number() | None = None


class DropFields(_EventFields):
    """``{at, drop: id, x, y, size, yaw, height}``."""

    drop: text("an object id")
    x: number("metres")
    y: number("metres")
    size: Size = DEFAULT_TOTE_M
    yaw: number() = 0.0
    height: Height = None


class RemoveFields(_EventFields):
    """``{at, remove: id}``."""

    remove: text("an object id")


class PersonFields(_EventFields):
    """``{at, person: id, path, speed, radius, height}``."""

    person: text("an object id")
    path: list[PointField]
    speed: number("metres per second", ge=0.1, le=10.0) = PERSON_SPEED
    radius: number("metres", ge=0.05, le=2.0) = PERSON_RADIUS
    height: Height = None


class BreakdownFields(_EventFields):
    """``{at, breakdown: unit id, duration}``; duration None: to the end of the run."""

    breakdown: text("a unit id")
    duration: number("seconds", gt=0) | None = None


def _kind(item: Any) -> str | None:
    """The tag of the one kind key in ``item`` (None: not exactly one)."""
    kinds = [k for k in EVENT_KINDS if k in item] if isinstance(item, dict) else []
    return variant_tag(kinds[0]) if len(kinds) == 1 else None


EventFields = Annotated[
    variant(MoveFields, "move")
    | variant(DropFields, "drop")
    | variant(RemoveFields, "remove")
    | variant(PersonFields, "person")
    | variant(BreakdownFields, "breakdown"),
    Discriminator(
        _kind,
        custom_error_type="event_kind",
        custom_error_message="must be a mapping with at and exactly one of "
        + ", ".join(EVENT_KINDS),
    ),
]
"""One event of the file: its kind is told by the one kind key it holds."""


def parse_events(
    doc: Document,
    path: FieldPath,
    items: list[Any] | None,
    *,
    layout: Layout,
    unit_ids: Sequence[str],
    duration: float,
) -> tuple[Event, ...]:
    """The validated ``events`` at ``path``, sorted by time (ties in file order), checked
    as the module docstring says; ScenarioError names the bad field."""
    parsed = [
        (_event(doc, (*path, i), item, duration), (*path, i)) for i, item in enumerate(items or ())
    ]
    parsed.sort(key=lambda pair: pair[0].at)  # stable: ties keep file order
    _check_ids(doc, parsed, layout, tuple(unit_ids))
    return tuple(event for event, _ in parsed)


def _event(doc: Document, where: FieldPath, f: Any, duration: float) -> Event:
    """One validated event as its Event."""
    if f.at > duration:
        raise doc.error((*where, "at"), f"must be at most the duration ({duration:g} s)", f.at)
    if isinstance(f, MoveFields):
        return MoveEvent(f.at, f.move, f.x, f.y, f.yaw)
    if isinstance(f, DropFields):
        size_x, size_y = (f.size, f.size) if isinstance(f.size, float) else f.size
        return DropEvent(f.at, f.drop, f.x, f.y, size_x, size_y, f.yaw, f.height)
    if isinstance(f, RemoveFields):
        return RemoveEvent(f.at, f.remove)
    if isinstance(f, PersonFields):
        points = tuple((p[0], p[1]) for p in f.path)
        if len(points) < 2:
            raise doc.error((*where, "path"), "must hold at least two points [x, y]", points)
        event = PersonEvent(f.at, f.person, points, f.speed, f.radius, f.height)
        if not event.length > 0:
            raise doc.error((*where, "path"), "must have a positive length", points)
        return event
    return BreakdownEvent(f.at, f.breakdown, f.duration)


def _check_ids(
    doc: Document, parsed: list[tuple[Event, FieldPath]], layout: Layout, units: tuple[str, ...]
) -> None:
    """Follow the objects through the events in time order (module docstring)."""
    objects = {o.id: o for o in layout.obstacles}
    walking: dict[str, float] = {}  # person id -> when it leaves
    broken: dict[str, float] = {}  # unit id -> until
    for event, where in parsed:
        for pid, end in list(walking.items()):
            if end <= event.at:
                del walking[pid]
        key = (*where, event.kind)
        if isinstance(event, BreakdownEvent):
            if event.unit_id not in units:
                raise doc.error(key, f"is not a unit (units are {', '.join(units)})", event.unit_id)
            if broken.get(event.unit_id, -math.inf) > event.at:
                raise doc.error(key, "is still broken down from an earlier event", event.unit_id)
            broken[event.unit_id] = event.until
            continue
        oid = event.object_id
        if isinstance(event, MoveEvent | RemoveEvent):
            if oid in walking:
                raise doc.error(key, "is a walking person: its path moves it", oid)
            if oid not in objects:
                raise doc.error(
                    key, "is not in the layout or dropped by an earlier event (still there)", oid
                )
            if isinstance(event, RemoveEvent):
                del objects[oid]
                continue
            moved = objects[oid].moved(event.x, event.y, event.yaw)
            _on_floor(doc, where, layout, moved, (event.x, event.y))
            objects[oid] = moved
            continue
        if oid in objects or oid in walking or oid in units:
            raise doc.error(key, "is already the id of an obstacle, person or unit", oid)
        if isinstance(event, DropEvent):
            tote = event.obstacle()
            _on_floor(doc, where, layout, tote, (event.x, event.y))
            objects[oid] = tote
        else:
            _check_walk(doc, (*where, "path"), layout, event)
            walking[oid] = event.end


def _on_floor(
    doc: Document, path: FieldPath, layout: Layout, obstacle: Obstacle, value: Any
) -> None:
    try:
        layout.check_on_floor(obstacle)
    except LayoutError:
        raise doc.error(
            path,
            f"puts {obstacle.id!r} off the floor [0, {layout.width:g}] x [0, {layout.height:g}] m",
            value,
        ) from None


def _check_walk(doc: Document, path: FieldPath, layout: Layout, person: PersonEvent) -> None:
    """The person's path stays on the floor and never overlaps a wall or a rack."""
    xy = np.asarray(person.path)
    r = person.radius
    (xmin, ymin), (xmax, ymax) = xy.min(axis=0), xy.max(axis=0)
    sweep = Obstacle(
        person.object_id, Kind.PERSON, Box.from_bounds(xmin - r, ymin - r, xmax + r, ymax + r)
    )
    _on_floor(doc, path, layout, sweep, person.path)
    samples = [xy[:1]]
    for a, b in zip(xy[:-1], xy[1:], strict=True):
        n = max(1, math.ceil(float(np.hypot(*(b - a))) / (r / 2)))
        samples.append(a + (b - a) * (np.arange(1, n + 1)[:, None] / n))
    pts = np.concatenate(samples)
    for obstacle in layout.obstacles:
        if obstacle.kind not in FIXED_KINDS:
            continue
        inside = obstacle.shape.distance(pts[:, 0], pts[:, 1]) < r
        if inside.any():
            x, y = pts[int(np.argmax(inside))]
            raise doc.error(
                path,
                f"walks through {obstacle.kind.value} {obstacle.id!r} near ({x:.2f}, {y:.2f})",
                person.path,
            )
