"""The fleet simulation: the sim clock and the step loop.

``FleetSim(world, units, seed)`` puts one drive unit per ``UnitSpec`` in the world and
runs them, Gymnasium style: ``reset(seed=...)`` then ``step(dt)`` again and again. Time is
the sim clock (``time`` [s], from 0), never the wall clock. One step of ``dt``:

1. the clock advances to ``t = time + dt`` (the world's too);
2. the world changes scheduled for times up to ``t`` (``schedule``) are made, stamped
   ``t``, so this step's scans and the ground truth at ``t`` both show them (a change
   made on the world directly between steps is stamped with the last step's time,
   whose scans did not see it);
3. every unit moves under its controller (``fleet.unit``) and its body is put there;
4. contacts with obstacles or other units are checked; a unit whose step began a contact
   is put back to where along that step it first touched (bisection on the exact
   footprints, ``World.gap``, with the other units moving along their own steps),
   halted (bumper stop, path dropped) and reported in a ``CollisionEvent`` per object
   touched, with its ``cause`` (below); a unit put back may now be touched by another
   (one following it closely), so the check repeats until no contact begins; the
   contacts every unit still holds at the step's end are reported too
   (``StepResult.contacts``: a unit put back is just clear, one that something was
   moved onto is not);
5. every LiDAR whose next scan is due (slots ``k / rate_hz`` s for k = 0, 1, ...; slot 0
   is taken at the first step; at most one scan per step, so keep ``dt <= 1 / rate_hz``)
   scans from the unit's true pose; the scan carries the localiser's pose estimate and
   honest ``pose_std``, stamped ``t``;
6. the poster, if any, sends this step's scans as one batch (``fleet.poster``); its error
   (the server down, a refused scan) propagates from ``step``, after the step's moves.

Collision cause, per object touched. ``"fleet"``: at the step's start the unit was clear
of the other thing, so the step's driving made the contact: the unit drove into an
obstacle, or into another unit, or a unit drove into it (both units report that contact,
both ``"fleet"``, whichever of them moved). ``"scenario"``: at the step's start the unit
already overlapped the other thing (an obstacle as it is after this step's world
changes; a unit at its own step start), so something other than the fleet's driving put
them together: an object dropped or moved onto the unit, a person walking into it, a
body placed there between steps. This is the bisection's own test at fraction 0; a
unit with a ``"scenario"`` contact is halted but not put back (there is no earlier clear
moment in the step to go back to).

Determinism: all randomness comes from ``numpy.random.SeedSequence(seed)``, one child per
unit (in ``units`` order) split into the LiDAR's and the localiser's generators; the same
world, units and seed give the same scans, step for step.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

from fleet.casters import DEFAULT_CASTER, check_caster
from fleet.lidar import Lidar, LidarConfig
from fleet.localization import Localizer, PoseNoise
from fleet.poster import ScanPoster
from fleet.shapes import wrap_angle
from fleet.unit import DriveLimits, DriveUnit
from mapserver.client import ScanAck
from mapserver.core.scan import Pose2D, Scan

if TYPE_CHECKING:  # the world imports PyBullet; a scenario's unit specs do not need it
    from fleet.world import World

SCHEDULE_TOLERANCE = 1e-9
"""Fraction of a LiDAR period (or of a second, for world changes) by which a step may fall
short of a scheduled time and still take it (sums of float steps drift by far less)."""
CONTACT_BISECTIONS = 30
"""Halvings of a step that put a colliding unit back where it first touched (2^-30 of
a step: well below a micrometre)."""
CONTACT_ROUNDS = 8
"""Rounds of contact checks per step (a unit put back can be run into by the unit behind
it; ``FleetSim._collisions``); the last one reports without putting back."""

COLLISION_CAUSES = ("fleet", "scenario")
"""``CollisionEvent.cause``: the fleet's driving made the contact, or the scenario moved
something onto the unit (module docstring)."""

WorldChange = Callable[["World"], None]
"""A scheduled change: called with the world at the step that reaches its time."""


@dataclass(frozen=True)
class UnitSpec:
    """One unit: ``unit_id``, its ``start`` pose, body and limits, LiDAR, localisation noise,
    and the caster of its LiDAR's beams (``fleet.casters.CASTERS``)."""

    unit_id: str
    start: Pose2D
    drive: DriveLimits = field(default_factory=DriveLimits)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    pose_noise: PoseNoise = field(default_factory=PoseNoise)
    caster: str = DEFAULT_CASTER

    def __post_init__(self) -> None:
        check_caster(self.caster)


@dataclass(frozen=True)
class CollisionEvent:
    """At sim ``time`` [s] unit ``unit_id``, at true (x, y) [m], began touching ``other_id``
    (an obstacle of kind ``other_kind``, or a unit: ``other_kind == "unit"``); ``cause``
    ``"fleet"`` or ``"scenario"`` (``COLLISION_CAUSES``, module docstring)."""

    time: float
    unit_id: str
    other_id: str
    other_kind: str
    x: float
    y: float
    cause: str = "fleet"


@dataclass(frozen=True)
class StepResult:
    """What one step produced: the sim ``time`` [s] after it, the scans taken, the
    collisions that began, the acks the poster returned (this step's scans', or with
    a pipelined poster the earlier steps' acks received meanwhile; empty without one),
    and the contacts held at the step's end: (unit id, other id) pairs, units in spec
    order, others by id."""

    time: float
    scans: tuple[Scan, ...]
    collisions: tuple[CollisionEvent, ...]
    acks: tuple[ScanAck, ...]
    contacts: tuple[tuple[str, str], ...] = ()


@dataclass
class SimUnit:
    """A unit in the sim: its spec, drive, LiDAR, localiser and schedule."""

    spec: UnitSpec
    drive: DriveUnit
    lidar: Lidar
    localizer: Localizer
    next_scan: float = 0.0  # [s] sim time of its next scan slot
    touching: frozenset[str] = frozenset()  # ids it is in contact with


class FleetSim:
    """Drive units with LiDARs in ``world``; ``poster`` (optional) sends their scans.

    units: one spec per unit, ids unique (and distinct from obstacle ids).
    seed: the seed of every random draw (module docstring).
    """

    def __init__(
        self,
        world: World,
        units: Sequence[UnitSpec],
        seed: int = 0,
        poster: ScanPoster | None = None,
    ) -> None:
        ids = [spec.unit_id for spec in units]
        duplicates = sorted({i for i in ids if ids.count(i) > 1})
        if duplicates:
            raise ValueError(f"unit ids must be unique, got duplicates {duplicates}")
        self.world = world
        self.specs = tuple(units)
        self.poster = poster
        for spec in self.specs:
            world.add_unit(spec.unit_id, spec.drive.radius, spec.drive.height, spec.start)
        self._units: dict[str, SimUnit] = {}
        self._schedule: list[tuple[float, int, WorldChange]] = []
        self._scheduled = itertools.count()  # ties at one time keep their order
        self.time = 0.0
        self.seed = seed
        self._start(seed)

    @property
    def units(self) -> Mapping[str, SimUnit]:
        """The units by id, in spec order (read-only)."""
        return MappingProxyType(self._units)

    def unit(self, unit_id: str) -> DriveUnit:
        """Unit ``unit_id``'s drive (give it a path with ``follow``)."""
        try:
            return self._units[unit_id].drive
        except KeyError:
            raise KeyError(f"no unit with id {unit_id!r} in the sim") from None

    def schedule(self, time: float, change: WorldChange) -> None:
        """Make ``change`` (e.g. ``lambda w: w.remove("pod-3")``) at the first step that
        reaches ``time`` [s]; changes due at one step run in time order, then in the order
        they were scheduled. ``reset`` drops the changes not yet made."""
        if not math.isfinite(time):
            raise ValueError(f"time must be a finite number of seconds, got {time!r}")
        self._schedule.append((float(time), next(self._scheduled), change))
        self._schedule.sort(key=lambda item: (item[0], item[1]))

    def reset(self, seed: int | None = None) -> None:
        """Start again: the world back to its layout, units at their starts, clock 0, no
        scheduled changes, generators from ``seed`` (None: the last seed, replaying the same
        episode)."""
        self.world.reset()
        self._schedule.clear()
        self._start(self.seed if seed is None else seed)

    def step(self, dt: float) -> StepResult:
        """Advance the sim by ``dt`` [s] (module docstring)."""
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        now = self.time + dt
        self.world.advance_to(now)
        self.time = now
        while self._schedule and self._schedule[0][0] <= now + SCHEDULE_TOLERANCE:
            self._schedule.pop(0)[2](self.world)
        starts = {}
        for unit_id, unit in self._units.items():
            starts[unit_id] = unit.drive.pose
            self.world.set_unit_pose(unit_id, unit.drive.step(dt))
        collisions = self._collisions(now, starts)
        due = self._due(now)
        scenes = self._scenes(due)
        scans = [self._scan(unit_id, unit, now, scenes[unit_id]) for unit_id, unit in due]
        acks = self.poster.post(scans) if self.poster is not None and scans else []
        held = tuple((uid, other) for uid, u in self._units.items() for other in sorted(u.touching))
        return StepResult(now, tuple(scans), tuple(collisions), tuple(acks), held)

    # ------------------------------------------------------------------ internals
    def _start(self, seed: int) -> None:
        self.seed = seed
        self.time = 0.0
        children = np.random.SeedSequence(seed).spawn(len(self.specs))
        self._units = {}
        for spec, child in zip(self.specs, children, strict=True):
            lidar_seed, pose_seed = child.spawn(2)
            self.world.set_unit_pose(spec.unit_id, spec.start)
            self._units[spec.unit_id] = SimUnit(
                spec=spec,
                drive=DriveUnit(spec.unit_id, spec.start, spec.drive),
                lidar=Lidar(
                    spec.lidar, spec.drive.radius, np.random.default_rng(lidar_seed), spec.caster
                ),
                localizer=Localizer(spec.pose_noise, np.random.default_rng(pose_seed)),
            )
        for unit_id, unit in self._units.items():  # contacts at the start are not events
            unit.touching = frozenset(c.other_id for c in self.world.contacts(unit_id))

    def _collisions(self, now: float, starts: Mapping[str, Pose2D]) -> list[CollisionEvent]:
        """Check every unit's contacts after the move from ``starts`` (all checked before any
        unit is put back); halt and put back each unit that began one (module docstring).

        Putting a unit back can make a contact of its own (a unit following it closely
        now ends on it): the check runs again, in rounds, with each unit's step now ending
        where it was put; every contact that began this step is reported once. After
        ``CONTACT_ROUNDS`` rounds what is left is reported without putting anyone back."""
        ends = {unit_id: self.world.unit_pose(unit_id) for unit_id in self._units}
        reported: dict[str, set[str]] = {unit_id: set() for unit_id in self._units}
        events: list[CollisionEvent] = []
        for round_ in range(CONTACT_ROUNDS):
            contacts = {unit_id: self.world.contacts(unit_id) for unit_id in self._units}
            begun = False
            for unit_id, unit in self._units.items():
                new = [
                    c
                    for c in contacts[unit_id]
                    if c.other_id not in unit.touching and c.other_id not in reported[unit_id]
                ]
                if not new:
                    continue
                begun = True
                unit.drive.halt()
                if round_ < CONTACT_ROUNDS - 1:
                    others = [c.other_id for c in new]
                    pose = _between(
                        starts[unit_id],
                        ends[unit_id],
                        self._first_touch(unit_id, starts, ends, others),
                    )
                    unit.drive.pose = pose
                    self.world.set_unit_pose(unit_id, pose)
                else:
                    pose = self.world.unit_pose(unit_id)
                for c in new:
                    moved_onto = self._overlap(unit_id, c.other_id, starts, ends, 0.0)
                    cause = "scenario" if moved_onto else "fleet"
                    events.append(
                        CollisionEvent(
                            now, unit_id, c.other_id, c.other_kind, pose.x, pose.y, cause
                        )
                    )
                    reported[unit_id].add(c.other_id)
            if not begun:
                break
            ends = {unit_id: self.world.unit_pose(unit_id) for unit_id in self._units}
        for unit_id, unit in self._units.items():
            unit.touching = frozenset(c.other_id for c in self.world.contacts(unit_id))
        return events

    def _first_touch(
        self,
        unit_id: str,
        starts: Mapping[str, Pose2D],
        ends: Mapping[str, Pose2D],
        others: list[str],
    ) -> float:
        """The latest fraction of this step at which unit ``unit_id`` overlapped none of
        ``others`` (units among them moving along their own steps), bisected; 1.0 when it
        overlapped one already at the start (something moved onto it)."""

        def clear(f: float) -> bool:
            return not any(self._overlap(unit_id, o, starts, ends, f) for o in others)

        if not clear(0.0):
            return 1.0
        lo, hi = 0.0, 1.0
        for _ in range(CONTACT_BISECTIONS):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if clear(mid) else (lo, mid)
        return lo

    def _overlap(
        self,
        unit_id: str,
        other: str,
        starts: Mapping[str, Pose2D],
        ends: Mapping[str, Pose2D],
        f: float,
    ) -> bool:
        """Whether unit ``unit_id``, ``f`` of the way along its step, overlaps ``other``: an
        obstacle where it is now, or a unit ``f`` of the way along its own step."""
        here = _between(starts[unit_id], ends[unit_id], f)
        there = None
        if other in ends:
            moved = _between(starts[other], ends[other], f)
            there = (moved.x, moved.y)
        return self.world.gap(unit_id, other, here.x, here.y, there) < 0

    def _due(self, now: float) -> list[tuple[str, SimUnit]]:
        """The units whose LiDAR scans at ``now``; their next slots are moved past it."""
        due = []
        for unit_id, unit in self._units.items():
            period = unit.spec.lidar.period
            if now >= unit.next_scan - SCHEDULE_TOLERANCE * period:
                due.append((unit_id, unit))
                unit.next_scan = (math.floor(now / period + SCHEDULE_TOLERANCE) + 1) * period
        return due

    def _scenes(self, due: list[tuple[str, SimUnit]]) -> dict[str, tuple]:
        """What each scanning unit's LiDAR can see, as a key (``Lidar.true_ranges``): the
        world's revision, the unit's true pose and the true poses of the units within
        its range. A unit standing still among still things casts no rays."""
        if not due:
            return {}
        order = {uid: k for k, uid in enumerate(self._units)}
        true = [self.world.unit_pose(uid) for uid in order]
        poses = np.array([(q.x, q.y, q.yaw) for q in true]).reshape(-1, 3)
        widest = max(u.spec.drive.radius for u in self._units.values())
        # every due unit's distances to every unit at once (the same hypot per pair)
        rows = np.array([order[unit_id] for unit_id, _ in due])
        reach = np.array([unit.spec.lidar.range_max + widest for _, unit in due])
        near = (
            np.hypot(poses[:, 0] - poses[rows, 0, None], poses[:, 1] - poses[rows, 1, None])
            <= reach[:, None]
        )
        near[np.arange(len(due)), rows] = False
        scenes = {}
        for j, (unit_id, _) in enumerate(due):
            x, y, yaw = poses[rows[j]]
            others = np.flatnonzero(near[j])
            scenes[unit_id] = (
                self.world.revision, x, y, yaw, others.tobytes(), poses[others].tobytes(),
            )  # fmt: skip
        return scenes

    def _scan(self, unit_id: str, unit: SimUnit, now: float, scene: tuple) -> Scan:
        lidar = unit.lidar
        ranges = lidar.measure(self.world, unit_id, scene)
        pose, pose_std = unit.localizer.estimate(self.world.unit_pose(unit_id))
        return Scan(
            unit_id=unit_id,
            stamp=now,
            pose=pose,
            angle_min=lidar.angle_min,
            angle_increment=lidar.angle_increment,
            range_min=lidar.config.range_min,
            range_max=lidar.config.range_max,
            ranges=ranges,
            pose_std=pose_std,
        )


def _between(start: Pose2D, end: Pose2D, fraction: float) -> Pose2D:
    """The pose ``fraction`` of the way from ``start`` to ``end`` (yaw the short way round)."""
    yaw = start.yaw + fraction * wrap_angle(end.yaw - start.yaw)
    return Pose2D(
        start.x + fraction * (end.x - start.x),
        start.y + fraction * (end.y - start.y),
        wrap_angle(yaw),
    )
