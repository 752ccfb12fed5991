"""The PyBullet warehouse: one physics client with the floor, the obstacles and the units.

``World(layout)`` opens its own ``p.DIRECT`` client (never the global default: every
call passes ``physicsClientId``), so several worlds live side by side in one process;
``close()`` disconnects it. Everything is static (mass 0) and nothing is ever simulated
dynamically: units are moved by setting their pose, obstacles by the scenario.

Bodies (z up, the floor's top at z = 0), every one a closed triangle mesh
(``GEOM_FORCE_CONCAVE_TRIMESH``): Bullet casts rays against triangles exactly and fast,
while its convex box and cylinder ray casts (GJK) are 2.5 to 4 times slower and off by up
to ~1 cm at grazing angles. (Bullet counts a ray passing a triangle's edge within about
1e-4 of the triangle's size as a hit, so a beam grazing a box corner may hit it a few
millimetres early.)

- the floor: a thin slab under ``[0, width] x [0, height]``;
- each box obstacle: a box mesh from z = 0 to its height;
- each cylinder obstacle (a person): a ``PRISM_SIDES``-sided prism inscribed in the
  circle (at most ``r (1 - cos(pi / PRISM_SIDES))``, 0.3 mm at r = 0.25 m, inside it);
- each unit: the same kind of prism, its frame the floor point under its centre (as ROS
  ``base_footprint``), lifted ``UNIT_LIFT_M`` off the floor.

Contacts: Bullet's broadphase finds the bodies whose bounding boxes overlap a unit's,
then the exact planar footprints (``fleet.shapes``) decide: a unit touches an obstacle
when its centre is closer than its radius to the obstacle's footprint, another unit when
the centres are closer than the sum of the radii. (Bullet has no mesh-mesh test, and
the footprints are the true geometry the meshes stand for.)

Rays: ``cast_rays`` / ``ray_hits`` are Bullet's ``rayTestBatch``, the reference;
``footprints`` is the same solids as planar footprints in a uniform grid
(``fleet.footprint_index``), made at its first use and from then on kept in step with
every body added, moved or removed, for the ``grid`` LiDAR caster (``fleet.casters``).

Obstacles are added, moved and removed at run time by id; each change is logged with the
world's clock (``time``, advanced by the simulation with ``advance_to``), so
``obstacles_at(t)`` gives the true geometry at any past sim time: the ground truth.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from operator import attrgetter, itemgetter
from types import MappingProxyType
from typing import Any

import numpy as np

from fleet.bullet import load_pybullet
from fleet.footprint_index import FootprintIndex
from fleet.layout import Layout, Obstacle
from fleet.shapes import PRISM_SIDES, Box
from mapserver.core.scan import Pose2D

p = load_pybullet()  # SimulatorMissing without the sim extra

RAY_BATCH_MAX = p.MAX_RAY_INTERSECTION_BATCH_SIZE - 1
"""Rays per ``rayTestBatch`` call: 16383, the design's chunk, one below PyBullet's
``MAX_RAY_INTERSECTION_BATCH_SIZE`` (16384; a larger batch raises ``pybullet.error``)."""
UNIT_LIFT_M = 0.005
"""[m] gap between a unit's body and the floor."""
FLOOR_THICKNESS_M = 0.1
"""[m] of the floor slab under z = 0."""
UNIT_KIND = "unit"
"""``Contact.other_kind`` of a contact with another unit."""

# The 8 corners (unit cube, z from 0 to 1) and 12 outward-facing triangles of a box mesh.
_CUBE_VERTICES = [(sx, sy, sz) for sz in (0, 1) for sy in (-1, 1) for sx in (-1, 1)]
_CUBE_INDICES = [0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4,
                 2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5]  # fmt: skip
_HIT_FRACTION = itemgetter(2)


@dataclass(frozen=True)
class Change:
    """One obstacle change at sim ``time`` [s]: ``before`` None = added, ``after`` None =
    removed, both given = moved. ``revision``: the world's revision after it."""

    time: float
    revision: int
    id: str
    before: Obstacle | None
    after: Obstacle | None


_time_of = attrgetter("time")  # the keys the change log is searched by (in both orders)
_revision_of = attrgetter("revision")


@dataclass(frozen=True)
class Contact:
    """Unit ``unit_id`` touches ``other_id`` (an obstacle id, or a unit id when
    ``other_kind`` is ``UNIT_KIND``)."""

    unit_id: str
    other_id: str
    other_kind: str


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """PyBullet's (x, y, z, w) quaternion of a turn by yaw [rad] about +z."""
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


class World:
    """A PyBullet warehouse built from ``layout``.

    ray_threads: ``numThreads`` of ``rayTestBatch`` (1: the calling thread; 0: Bullet
        decides; n: n threads). Results do not depend on it.
    """

    def __init__(self, layout: Layout, *, ray_threads: int = 1) -> None:
        if isinstance(ray_threads, bool) or not isinstance(ray_threads, int) or ray_threads < 0:
            raise ValueError(f"ray_threads must be an integer >= 0, got {ray_threads!r}")
        self.layout = layout
        self.ray_threads = ray_threads
        self._client = p.connect(p.DIRECT)
        if self._client < 0:
            raise RuntimeError("PyBullet could not open a DIRECT physics client")
        self._shapes: dict[tuple[Any, ...], int] = {}  # collision shapes by size, reused
        self._body: dict[str, int] = {}  # obstacle or unit id -> body id
        self._owner: dict[int, str] = {}  # body id -> obstacle or unit id
        self._obstacles: dict[str, Obstacle] = {}
        self._units: dict[str, Pose2D] = {}
        self._unit_radius: dict[str, float] = {}
        self._unit_height: dict[str, float] = {}
        self._changes: list[Change] = []
        self._revision = 0
        self._reset_revision = 0
        self._footprints: FootprintIndex | None = None
        self.time = 0.0
        self._floor = self._make_floor()
        for obstacle in layout.obstacles:
            self._create(obstacle)

    # ------------------------------------------------------------------ lifecycle
    @property
    def client_id(self) -> int:
        """This world's PyBullet physics client id."""
        return self._client

    def close(self) -> None:
        """Disconnect the physics client (idempotent)."""
        if self._client >= 0:
            p.disconnect(physicsClientId=self._client)
            self._client = -1

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def reset(self) -> None:
        """Back to the layout: its obstacles, an empty change log, ``time`` 0.

        Unit bodies stay where they are (their owner re-places them). ``revision`` still
        grows, and ``changes_since`` an older revision returns None.
        """
        for obstacle_id in list(self._obstacles):
            self._destroy(obstacle_id)
        for obstacle in self.layout.obstacles:
            self._create(obstacle)
        self._changes.clear()
        self._revision += 1
        self._reset_revision = self._revision
        self.time = 0.0

    def advance_to(self, time: float) -> None:
        """Set the world's clock to ``time`` [s] (never backwards); later changes carry it."""
        if not time >= self.time:
            raise ValueError(f"time must not go back from {self.time} s, got {time!r}")
        self.time = float(time)

    # ------------------------------------------------------------------ obstacles
    @property
    def obstacles(self) -> Mapping[str, Obstacle]:
        """The obstacles now, by id (a live read-only view)."""
        return MappingProxyType(self._obstacles)

    @property
    def revision(self) -> int:
        """Grows by one on every obstacle change and on ``reset``."""
        return self._revision

    def obstacle(self, obstacle_id: str) -> Obstacle:
        """The obstacle with this id now; KeyError names it when there is none."""
        try:
            return self._obstacles[obstacle_id]
        except KeyError:
            raise KeyError(f"no obstacle with id {obstacle_id!r} in the world") from None

    def add(self, obstacle: Obstacle) -> None:
        """Add ``obstacle`` now; its id must be new (among obstacles and units)."""
        if obstacle.id in self._body:
            raise ValueError(f"id {obstacle.id!r} is already in the world")
        self.layout.check_on_floor(obstacle, f"obstacle {obstacle.id!r}")
        self._create(obstacle)
        self._log(obstacle.id, None, obstacle)

    def move(self, obstacle_id: str, x: float, y: float, yaw: float | None = None) -> None:
        """Move an obstacle's centre to (x, y) [m], turned to ``yaw`` [rad] when given."""
        before = self.obstacle(obstacle_id)
        after = before.moved(x, y, yaw)
        self.layout.check_on_floor(after, f"obstacle {obstacle_id!r}")
        yaw_now = after.shape.yaw if isinstance(after.shape, Box) else 0.0
        p.resetBasePositionAndOrientation(
            self._body[obstacle_id],
            (after.shape.x, after.shape.y, 0.0),
            yaw_quaternion(yaw_now),
            physicsClientId=self._client,
        )
        self._obstacles[obstacle_id] = after
        if self._footprints is not None:
            self._footprints.put_obstacle(obstacle_id, after.shape, after.height)
        self._log(obstacle_id, before, after)

    def remove(self, obstacle_id: str) -> None:
        """Remove an obstacle now."""
        before = self.obstacle(obstacle_id)
        self._destroy(obstacle_id)
        self._log(obstacle_id, before, None)

    def changes_since(self, revision: int) -> list[Change] | None:
        """The changes after ``revision``, oldest first; None when a ``reset`` came since."""
        if revision < self._reset_revision:
            return None
        return self._changes[bisect_right(self._changes, revision, key=_revision_of) :]

    def revision_at(self, time: float) -> int:
        """The revision of the obstacles at sim ``time`` [s]: that of the last change stamped
        at or before it (since the last reset); equal revisions, equal obstacles."""
        # the log is in time order (``advance_to`` never goes back) and in revision order
        last = bisect_right(self._changes, time, key=_time_of)
        return self._changes[last - 1].revision if last else self._reset_revision

    def obstacles_at(self, time: float) -> dict[str, Obstacle]:
        """The obstacles at sim ``time`` [s]: the layout's, then every change stamped at or
        before ``time`` (since the last reset)."""
        state = {o.id: o for o in self.layout.obstacles}
        for change in self._changes:
            if change.time > time:
                break
            if change.after is None:
                state.pop(change.id, None)
            else:
                state[change.id] = change.after
        return state

    # ------------------------------------------------------------------ units
    def add_unit(self, unit_id: str, radius: float, height: float, pose: Pose2D) -> None:
        """A unit's body: a cylinder of ``radius`` and ``height`` [m] at ``pose``."""
        if unit_id in self._body:
            raise ValueError(f"id {unit_id!r} is already in the world")
        shape = self._prism_shape(radius, height, UNIT_LIFT_M)
        body = p.createMultiBody(0, shape, physicsClientId=self._client)
        self._body[unit_id] = body
        self._owner[body] = unit_id
        self._units[unit_id] = pose
        self._unit_radius[unit_id] = float(radius)
        self._unit_height[unit_id] = float(height)
        if self._footprints is not None:
            self._footprints.put_unit(unit_id, radius, UNIT_LIFT_M, UNIT_LIFT_M + height)
        self.set_unit_pose(unit_id, pose)

    def set_unit_pose(self, unit_id: str, pose: Pose2D) -> None:
        """Put unit ``unit_id``'s body at ``pose`` (x, y [m], yaw [rad])."""
        if unit_id not in self._units:
            raise KeyError(f"no unit with id {unit_id!r} in the world")
        p.resetBasePositionAndOrientation(
            self._body[unit_id],
            (pose.x, pose.y, 0.0),
            yaw_quaternion(pose.yaw),
            physicsClientId=self._client,
        )
        self._units[unit_id] = pose
        if self._footprints is not None:
            self._footprints.move_unit(unit_id, pose.x, pose.y, pose.yaw)

    def body_id(self, object_id: str) -> int:
        """The PyBullet body id of obstacle or unit ``object_id`` (ids are reused after a
        removal: do not keep one across changes)."""
        try:
            return self._body[object_id]
        except KeyError:
            raise KeyError(f"no obstacle or unit with id {object_id!r} in the world") from None

    def unit_pose(self, unit_id: str) -> Pose2D:
        """Unit ``unit_id``'s true pose."""
        return self._units[unit_id]

    def contacts(self, unit_id: str) -> list[Contact]:
        """Every obstacle and unit that unit ``unit_id`` overlaps now, sorted by id
        (module docstring: Bullet's broadphase, then the exact footprints)."""
        body = self._body[unit_id]
        pose = self._units[unit_id]
        lo, hi = p.getAABB(body, physicsClientId=self._client)
        found = p.getOverlappingObjects(lo, hi, physicsClientId=self._client) or ()
        out = []
        for other in sorted({self._owner.get(b) for b, _ in found} - {None, unit_id}):
            if self.gap(unit_id, other, pose.x, pose.y) < 0:
                obstacle = self._obstacles.get(other)
                kind = obstacle.kind.value if obstacle is not None else UNIT_KIND
                out.append(Contact(unit_id, other, kind))
        return out

    def gap(
        self,
        unit_id: str,
        other_id: str,
        x: float,
        y: float,
        other_xy: tuple[float, float] | None = None,
    ) -> float:
        """[m] clearance between unit ``unit_id`` were it centred at (x, y) [m] and the
        obstacle or unit ``other_id`` where it is now (a unit: at ``other_xy`` [m] when
        given); negative when they overlap."""
        radius = self._unit_radius[unit_id]
        obstacle = self._obstacles.get(other_id)
        if obstacle is not None:
            return float(obstacle.shape.distance(x, y)) - radius
        ox, oy = other_xy if other_xy is not None else self._xy(other_id)
        return math.hypot(ox - x, oy - y) - radius - self._unit_radius[other_id]

    def _xy(self, unit_id: str) -> tuple[float, float]:
        pose = self._units[unit_id]
        return (pose.x, pose.y)

    # ------------------------------------------------------------------ rays
    @property
    def footprints(self) -> FootprintIndex:
        """Every obstacle and unit as a planar footprint in a grid (``fleet.footprint_index``,
        for the ``grid`` LiDAR caster), built at the first call and kept in step with
        every change after it."""
        if self._footprints is None:
            index = FootprintIndex(self.layout.width, self.layout.height)
            for obstacle in self._obstacles.values():
                index.put_obstacle(obstacle.id, obstacle.shape, obstacle.height)
            for unit_id, pose in self._units.items():
                top = UNIT_LIFT_M + self._unit_height[unit_id]
                index.put_unit(unit_id, self._unit_radius[unit_id], UNIT_LIFT_M, top)
                index.move_unit(unit_id, pose.x, pose.y, pose.yaw)
            self._footprints = index
        return self._footprints

    def cast_rays(
        self,
        ray_from: Sequence[Sequence[float]],
        ray_to: Sequence[Sequence[float]],
        frame_unit: str | None = None,
    ) -> np.ndarray:
        """Hit fraction of each ray ``ray_from[i] -> ray_to[i]`` ([x, y, z] m), +inf on a miss.

        frame_unit: the rays are given in this unit's body frame (x ahead, z up from the
            floor); Bullet moves them with the body. None: the ``map`` frame.
        The distance to the first surface hit is ``fraction * |ray_to - ray_from|``. Bullet
        reports a miss as fraction 1, so a surface exactly at a ray's end reads as a miss.
        Rays go to ``rayTestBatch`` in chunks of at most ``RAY_BATCH_MAX``.
        """
        out = np.empty(len(ray_from), dtype=np.float64)
        for start, stop, hits in self._ray_batches(ray_from, ray_to, frame_unit):
            out[start:stop] = np.fromiter(map(_HIT_FRACTION, hits), np.float64, stop - start)
        out[out >= 1.0] = np.inf
        return out

    def ray_hits(
        self,
        ray_from: Sequence[Sequence[float]],
        ray_to: Sequence[Sequence[float]],
        frame_unit: str | None = None,
    ) -> tuple[np.ndarray, list[str | None]]:
        """``cast_rays`` and, for each ray, the id of the obstacle or unit it hits first
        (None: nothing, or the floor)."""
        fractions = np.empty(len(ray_from), dtype=np.float64)
        owners: list[str | None] = []
        for start, stop, hits in self._ray_batches(ray_from, ray_to, frame_unit):
            fractions[start:stop] = [hit[2] for hit in hits]
            owners += [self._owner.get(hit[0]) for hit in hits]
        fractions[fractions >= 1.0] = np.inf
        return fractions, owners

    def _ray_batches(
        self,
        ray_from: Sequence[Sequence[float]],
        ray_to: Sequence[Sequence[float]],
        frame_unit: str | None,
    ) -> Iterator[tuple[int, int, Sequence[Sequence[Any]]]]:
        """(start, stop, ``rayTestBatch``'s hits of rays ``start:stop``) per chunk."""
        n = len(ray_from)
        if len(ray_to) != n:
            raise ValueError(f"ray_to must hold one end per ray ({n}), got {len(ray_to)}")
        kwargs: dict[str, Any] = {"numThreads": self.ray_threads, "physicsClientId": self._client}
        if frame_unit is not None:
            kwargs["parentObjectUniqueId"] = self._body[frame_unit]
            kwargs["parentLinkIndex"] = -1
        for start in range(0, n, RAY_BATCH_MAX):
            stop = min(n, start + RAY_BATCH_MAX)
            whole = start == 0 and stop == n
            yield (
                start,
                stop,
                p.rayTestBatch(
                    ray_from if whole else ray_from[start:stop],
                    ray_to if whole else ray_to[start:stop],
                    **kwargs,
                ),
            )

    # ------------------------------------------------------------------ internals
    def _log(self, obstacle_id: str, before: Obstacle | None, after: Obstacle | None) -> None:
        self._revision += 1
        self._changes.append(Change(self.time, self._revision, obstacle_id, before, after))

    def _make_floor(self) -> int:
        floor = Box.from_bounds(0.0, 0.0, self.layout.width, self.layout.height)
        shape = self._box_shape(floor, FLOOR_THICKNESS_M)
        return p.createMultiBody(
            0,
            shape,
            basePosition=(floor.x, floor.y, -FLOOR_THICKNESS_M),
            physicsClientId=self._client,
        )

    def _mesh(self, key: tuple[Any, ...], vertices: list[tuple[float, float, float]],
              indices: list[int]) -> int:  # fmt: skip
        """A triangle-mesh collision shape, created once per ``key`` and shared."""
        if key not in self._shapes:
            self._shapes[key] = p.createCollisionShape(
                p.GEOM_MESH,
                vertices=vertices,
                indices=indices,
                flags=p.GEOM_FORCE_CONCAVE_TRIMESH,
                physicsClientId=self._client,
            )
        return self._shapes[key]

    def _box_shape(self, box: Box, height: float) -> int:
        """A closed box mesh ``size_x x size_y x height`` [m], z from 0 up."""
        hx, hy = box.size_x / 2, box.size_y / 2
        vertices = [(sx * hx, sy * hy, sz * height) for sx, sy, sz in _CUBE_VERTICES]
        key = ("box", round(box.size_x, 9), round(box.size_y, 9), round(height, 9))
        return self._mesh(key, vertices, _CUBE_INDICES)

    def _prism_shape(self, radius: float, height: float, lift: float = 0.0) -> int:
        """A closed ``PRISM_SIDES``-gon prism inscribed in a cylinder of ``radius`` [m],
        z from ``lift`` to ``lift + height`` [m]."""
        n = PRISM_SIDES
        ring = [(radius * math.cos(2 * math.pi * k / n), radius * math.sin(2 * math.pi * k / n))
                for k in range(n)]  # fmt: skip
        vertices = [(x, y, z) for z in (lift, lift + height) for x, y in ring]
        indices = []
        for k in range(n):  # sides, two triangles each, facing out
            a, b = k, (k + 1) % n
            indices += [a, b, n + b, a, n + b, n + a]
        for k in range(1, n - 1):  # bottom and top caps as fans
            indices += [0, k + 1, k, n, n + k, n + k + 1]
        key = ("prism", round(radius, 9), round(height, 9), round(lift, 9))
        return self._mesh(key, vertices, indices)

    def _create(self, obstacle: Obstacle) -> None:
        shape = obstacle.shape
        if isinstance(shape, Box):
            collision, yaw = self._box_shape(shape, obstacle.height), shape.yaw
        else:
            collision, yaw = self._prism_shape(shape.radius, obstacle.height), 0.0
        body = p.createMultiBody(
            0,
            collision,
            basePosition=(shape.x, shape.y, 0.0),
            baseOrientation=yaw_quaternion(yaw),
            physicsClientId=self._client,
        )
        self._body[obstacle.id] = body
        self._owner[body] = obstacle.id
        self._obstacles[obstacle.id] = obstacle
        if self._footprints is not None:
            self._footprints.put_obstacle(obstacle.id, shape, obstacle.height)

    def _destroy(self, obstacle_id: str) -> None:
        body = self._body.pop(obstacle_id)
        del self._owner[body]
        del self._obstacles[obstacle_id]
        p.removeBody(body, physicsClientId=self._client)
        if self._footprints is not None:
            self._footprints.remove_obstacle(obstacle_id)
