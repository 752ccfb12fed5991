"""What watches an episode: recorders, scorers and publishers, each on its own clock.

An observer declares ``every_s`` [s] (None: every step) and, when due, reads the
episode and its last ``StepReport`` (``scenarios.run.episode``); it never changes the fleet.
``finish`` runs once at the end, before the episode scores the run. An observer that
measures run metrics declares them in ``feeds`` (keys of the metric registry,
``scenarios.score.metric_registry``: the ``metrics.json`` keys scored from what it
collected, or the counters it samples).

The standard set (``StandardObservers``): the replay's scans (every step, sampled per
unit), plans checked against ground truth (stale-free and inscribed plans), collision
incidents with what the map held where the unit touched, the freeze detector and the
evidence of blocking cells, throughput, time to clear and the map against truth
(both at every map read), the run's counters (every map read and at the end), unit
poses for the replay and the live viewer, costmap snapshots and the world's objects
(``replay_objects``).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from mapserver.api.schemas import MAX_REASON_CHARS
from mapserver.client import UnitState
from planner.freeze import FreezeDetector, UnitObservation
from planner.plan_safety import plan_safety
from scenarios.replay.objects import ObjectRecorder
from scenarios.run.agents import activity
from scenarios.run.record import (
    COUNTERS,
    CountersSample,
    GridSample,
    PlanSample,
    ScanSample,
    UnitSample,
)
from scenarios.score.counts import freeze_counts, plan_counts
from scenarios.score.free_run import free_run_metrics
from scenarios.score.incidents import (
    ContactCell,
    IncidentTracker,
    PlanContext,
    collision_counts,
    contact_cells,
    cost_class,
)
from scenarios.score.inscribing import inscribing_cells
from scenarios.score.map_truth import footprints, measure, reachable_floor
from scenarios.score.throughput import ThroughputTracker

if TYPE_CHECKING:
    from scenarios.run.episode import Episode


class Observer(Protocol):
    """Runs every ``every_s`` [s] of sim time (None: every step). One that measures run
    metrics says which in a ``feeds`` attribute (module docstring)."""

    every_s: float | None

    def observe(self, episode: Episode) -> None:
        """Look at the episode after a step."""
        ...

    def finish(self, episode: Episode) -> None:
        """The episode is over."""
        ...


class Schedule:
    """Due at the first step and then once ``period`` [s] has passed since it last was
    (every step when ``period`` is None)."""

    def __init__(self, period: float | None) -> None:
        self.period = period
        self._next = -np.inf

    def due(self, now: float) -> bool:
        if self.period is None:
            return True
        if now < self._next - 1e-9:
            return False
        self._next = now + self.period
        return True


class _Observer:
    every_s: float | None = None
    feeds: tuple[str, ...] = ()  # the metrics it measures (module docstring)

    def finish(self, episode: Episode) -> None:
        return None


class ScanRecorder(_Observer):
    """Every scan's stamp and origin (``index``: stamp -> [(unit, x, y, range_max)], for
    the evidence of freezes) and, per unit, one scan every ``sample_s`` [s] for the
    replay (``record.scans``)."""

    def __init__(self, sample_s: float) -> None:
        self.sample_s = sample_s
        self.index: dict[float, list[tuple[str, float, float, float]]] = {}
        self._next: dict[str, float] = {}

    def observe(self, episode: Episode) -> None:
        now = episode.report.now
        for scan in episode.report.sim.scans:
            self.index.setdefault(scan.stamp, []).append(
                (scan.unit_id, scan.pose.x, scan.pose.y, scan.range_max)
            )
            if now >= self._next.get(scan.unit_id, 0.0):
                episode.record.scans.append(_scan_sample(scan))
                self._next[scan.unit_id] = now + self.sample_s


class PlanChecker(_Observer):
    """Every path sent to a drive, with the cells its legs cross that are lethal or
    inscribed in ground truth (``record.plans``: stale-free and inscribed plans,
    ``planner.plan_safety``)."""

    feeds = plan_counts.feeds

    def __init__(self, episode: Episode) -> None:
        self.radius = {s.unit_id: s.drive.radius for s in episode.setup.unit_specs()}

    def observe(self, episode: Episode) -> None:
        now = episode.report.now
        for uid, path in episode.report.new_paths:
            truth = episode.truth.costmap(now)
            safety = plan_safety(path, truth, episode.geometry, self.radius[uid])
            episode.record.plans.append(
                PlanSample(now, uid, tuple(path), safety.lethal, safety.inscribed)
            )


class CollisionWatch(_Observer):
    """Collision incidents (``scenarios.score.incidents``, ``record.incidents``), every
    step: the contacts the step began and held, each new incident with the plan its unit
    was driving (the costmap it planned on, kept per unit from the step the path was
    sent) and its contact cells as that map and the truth then held them."""

    feeds = collision_counts.feeds

    def __init__(self, episode: Episode) -> None:
        self.radius = {s.unit_id: s.drive.radius for s in episode.setup.unit_specs()}
        self.tracker = IncidentTracker(incidents=episode.record.incidents)
        self._planned: dict[str, tuple[float, object]] = {}  # unit -> (stamp, Grid)

    def observe(self, episode: Episode) -> None:
        report = episode.report
        sim = report.sim
        self.tracker.observe(
            report.now, sim.collisions, sim.contacts, lambda e: self._context(episode, e)
        )
        for uid, _ in report.new_paths:  # after: a contact came before this step's plans
            self._planned[uid] = (report.now, episode.costs)

    def _context(self, episode: Episode, event) -> PlanContext | None:
        planned = self._planned.get(event.unit_id)
        if planned is None:
            return None
        stamp, grid = planned
        cells = contact_cells(
            episode.geometry, event.x, event.y, self.radius[event.unit_id],
            self._distance(episode, event.other_id),
        )  # fmt: skip
        truth = episode.truth.costmap(stamp)
        geometry = episode.geometry
        return PlanContext(
            stamp,
            grid.version,
            tuple(
                ContactCell(
                    *geometry.cell_to_world(c, r),
                    cost_class(grid.data[r, c]),
                    cost_class(truth[r, c]),
                )  # fmt: skip
                for c, r in cells
            ),
        )

    def _distance(self, episode: Episode, other_id: str):
        """[m] from points to the touched thing now: an obstacle's footprint, or a unit's."""
        obstacle = episode.world.obstacles.get(other_id)
        if obstacle is not None:
            return obstacle.shape.distance
        ox, oy = episode.report.positions[other_id]
        radius = self.radius[other_id]
        return lambda xs, ys: np.maximum(np.hypot(xs - ox, ys - oy) - radius, 0.0)


class FreezeWatch(_Observer):
    """The freeze detector (``planner.freeze``), fed every unit's state each step, and
    the map's evidence of each blocking cell, read when a unit is first blocked by it
    (``evidence``: (unit, point) -> [(stamp, CellOut)]); for an INSCRIBED blocking cell
    also the LETHAL cells that inscribe it (``held_by``: (unit, point) -> [(stamp,
    points)], ``scenarios.score.inscribing``), whose evidence is read with it."""

    feeds = freeze_counts.feeds  # scored at the end (``planner.freeze.classify``)

    def __init__(self) -> None:
        self.detector = FreezeDetector()
        self.evidence: dict = {}
        self.held_by: dict = {}

    def observe(self, episode: Episode) -> None:
        report = episode.report
        for uid, state in report.states.items():
            command = state.command
            moving = command.moving or command.kind == "idle"
            self.detector.observe(
                UnitObservation(
                    uid,
                    report.now,
                    state.has_task,
                    moving,
                    state.blocked_reason,
                    state.blocking,
                    state.goal,
                    report.positions[uid],
                    state.lane_block,
                )  # fmt: skip
            )
            if state.blocked_reason is not None:
                self._note(episode, uid, report.now, state.blocking)

    def _note(self, episode: Episode, uid: str, now: float, points) -> None:
        """Read each blocking cell's evidence from the map when the unit's current freeze
        first names it (a later freeze reads it again: ``evidence`` keeps every reading)."""
        since = self.detector.open_since(uid)
        since = now if since is None else since
        new = [p for p in points if not any(s >= since for s, _ in self.evidence.get((uid, p), ()))]
        if not new:
            return
        radius = episode.setup.inflation().inscribed_radius
        costs = episode.costs.data
        read = list(new)
        for point in new:
            sources = inscribing_cells(costs, episode.geometry, point, radius)
            self.held_by.setdefault((uid, point), []).append((now, sources))
            read += [s for s in sources if s not in read]
        for point, info in zip(read, episode.synced().query_cells(read), strict=True):
            self.evidence.setdefault((uid, point), []).append((now, info))


class Throughput(_Observer):
    """Trips, their returns and unit-ticks for the throughput metrics
    (``scenarios.score.throughput``)."""

    feeds = ("tasks_completed", *ThroughputTracker.metrics.feeds, *free_run_metrics.feeds)

    def __init__(self, episode: Episode) -> None:
        self.tracker = ThroughputTracker(
            episode.graph, episode.setup.dt, episode.coordinator.settings.arrive_tol
        )

    def observe(self, episode: Episode) -> None:
        report = episode.report
        for _, task, cause in report.returned:  # before: a trip may go out again at once
            self.tracker.returned(task, report.now, cause)
        for uid, task, node, position in report.assigned:
            limits = episode.sim.unit(uid).limits
            self.tracker.assigned(position, node, task, report.now, limits, uid)
        for uid, state in report.states.items():
            agent = episode.agents[uid]
            self.tracker.observe(uid, report.now, agent, state, report.motion[uid])

    def finish(self, episode: Episode) -> None:
        episode.record.trips = self.tracker.trips
        episode.record.unfinished_trips = self.tracker.unfinished()


class ClearingWatch(_Observer):
    """Time to clear: each removed object's old place, checked at every map read."""

    feeds = ("time_to_clear_s",)

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s

    def observe(self, episode: Episode) -> None:
        episode.clearing.observe(episode.costs.data, episode.report.now)


class MapTruthWatch(_Observer):
    """The shared costmap against ground truth at every map read (``scenarios.score.map_truth``,
    ``record.map_truth``): the reachable floor from the units' start cells, flood-filled
    again only when the world changed, and the units' footprints at the read left out."""

    feeds = ("map_truth",)

    def __init__(self, episode: Episode, every_s: float) -> None:
        self.every_s = every_s
        specs = episode.setup.unit_specs()
        self.starts = [episode.geometry.world_to_cell(s.start.x, s.start.y) for s in specs]
        self.radius = {s.unit_id: s.drive.radius for s in specs}
        self._revision: int | None = None
        self._reachable: np.ndarray | None = None

    def observe(self, episode: Episode) -> None:
        now = episode.report.now
        truth = episode.truth.costmap(now)
        if self._reachable is None or episode.world.revision != self._revision:
            self._reachable = reachable_floor(truth, self.starts)
            self._revision = episode.world.revision
        bodies = [(x, y, self.radius[uid]) for uid, (x, y) in episode.report.positions.items()]
        ignore = footprints(episode.geometry, bodies)
        sample = measure(now, episode.costs.data, truth, self._reachable, ignore)
        episode.record.map_truth.append(sample)


class CountersRecorder(_Observer):
    """The run's counters (``record.counters``, the replay's ``/metrics``) every ``every_s``
    [s] and once more at the end, so the last sample holds the numbers of ``metrics.json``:
    trips done (``throughput``'s), units frozen at the step, stale-free and inscribed
    plans (``plan_counts``), collision incidents (``collision_counts``) and scenario
    events so far."""

    feeds = COUNTERS

    def __init__(self, throughput: Throughput, every_s: float) -> None:
        self.throughput = throughput
        self.every_s = every_s
        self._plans_counted = 0  # ``record.plans`` (append-only) counted so far
        self._plans = Counter[str]()  # their counts (``plan_counts``, which add up)

    def observe(self, episode: Episode) -> None:
        record = episode.record
        collisions = collision_counts(record.incidents)
        self._plans.update(plan_counts(record.plans[self._plans_counted :]))
        self._plans_counted = len(record.plans)
        plans = self._plans
        record.counters.append(
            CountersSample(
                episode.report.now,
                len(self.throughput.tracker.trips),
                len(episode.report.frozen),
                plans["stale_free_plans"],
                int(collisions["collisions"]),
                int(collisions["scenario_collisions"]),
                len(episode.events),
                plans["inscribed_plans"],
            )
        )

    def finish(self, episode: Episode) -> None:
        last = episode.record.counters[-1] if episode.record.counters else None
        if last is None or last.stamp != episode.report.now:
            self.observe(episode)


class UnitRecorder(_Observer):
    """Every unit's pose, motion, freeze and task every ``every_s`` [s] (the replay)."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s

    def observe(self, episode: Episode) -> None:
        now, frozen = episode.report.now, episode.report.frozen
        for uid, unit in episode.sim.units.items():
            pose = unit.drive.pose
            agent = episode.agents[uid]
            task = agent.task.task_id if agent.task is not None else None
            moving = not unit.drive.idle
            episode.record.units.append(
                UnitSample(now, uid, pose.x, pose.y, pose.yaw, moving, uid in frozen, task)
            )


class UnitPublisher(_Observer):
    """The units, their plans, activities (``scenarios.run.agents.activity``) and the
    reasons of their freezes in the map server's live viewer."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s

    def observe(self, episode: Episode) -> None:
        now = episode.report.now
        states = []
        for uid, unit in episode.sim.units.items():
            agent, state = episode.agents[uid], episode.report.states[uid]
            plan = agent.navigator.last_plan
            path = plan.path if plan is not None and plan.found else ()
            doing = activity(now, agent, state)
            reason = state.blocked_reason[:MAX_REASON_CHARS] if doing == "frozen" else None
            states.append(
                UnitState.of(uid, now, unit.drive.pose, path, reason=reason, activity=doing)
            )
        episode.client.publish_units(states)


class GridRecorder(_Observer):
    """The shared costmap and occupancy every ``every_s`` [s] (the replay)."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s

    def observe(self, episode: Episode) -> None:
        costs = episode.costs
        occupancy = episode.synced().occupancy().data.copy()
        episode.record.grids.append(
            GridSample(episode.report.now, costs.version, costs.data.copy(), occupancy)
        )


@dataclass(frozen=True)
class StandardObservers:
    """The observers every run has (module docstring), by name."""

    scans: ScanRecorder
    plans: PlanChecker
    collisions: CollisionWatch
    freezes: FreezeWatch
    throughput: Throughput
    clearing: ClearingWatch
    map_truth: MapTruthWatch
    counters: CountersRecorder
    units: UnitRecorder
    publisher: UnitPublisher
    grids: GridRecorder
    objects: ObjectRecorder

    @classmethod
    def of(cls, episode: Episode) -> StandardObservers:
        opts = episode.options
        throughput = Throughput(episode)
        return cls(
            scans=ScanRecorder(opts.record_scans_s),
            plans=PlanChecker(episode),
            collisions=CollisionWatch(episode),
            freezes=FreezeWatch(),
            throughput=throughput,
            clearing=ClearingWatch(opts.map_read_s),
            map_truth=MapTruthWatch(episode, opts.map_read_s),
            counters=CountersRecorder(throughput, opts.map_read_s),
            units=UnitRecorder(opts.record_units_s),
            publisher=UnitPublisher(opts.record_units_s),
            grids=GridRecorder(opts.record_grids_s),
            objects=ObjectRecorder(opts.record_units_s),
        )

    def all(self) -> tuple[Observer, ...]:
        """In the order they run after a step."""
        return (
            self.scans, self.plans, self.collisions, self.freezes, self.throughput,
            self.clearing,
            self.map_truth, self.counters, self.units, self.publisher, self.grids,
            self.objects,
        )  # fmt: skip


class ProgressReport(_Observer):
    """Calls ``progress(now, duration)`` [s] after every step (a progress bar); after the
    last step ``now`` is ``duration`` exactly, so the last line (``180/180``) is always
    drawn: sim time summed in steps of 0.1 s ends a hair short of it (179.99999999997)."""

    def __init__(self, progress) -> None:
        self.progress = progress

    def observe(self, episode: Episode) -> None:
        duration = episode.setup.duration
        self.progress(duration if episode.done else episode.report.now, duration)


def _scan_sample(scan) -> ScanSample:
    return ScanSample(
        scan.stamp, scan.unit_id, scan.pose.x, scan.pose.y, scan.pose.yaw, scan.angle_min,
        scan.angle_increment, scan.range_min, scan.range_max, scan.ranges.astype(np.float32),
    )  # fmt: skip
