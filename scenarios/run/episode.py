"""One scenario run as an episode: ``reset(seed)``, then ``step()`` until ``done``.

The shape is Gymnasium's (Towers et al., *Gymnasium: A Standard Interface for
Reinforcement Learning Environments*, 2024): ``reset`` builds everything from the
scenario and one seed, ``step`` advances ``dt`` [s] of sim time, and two episodes reset
with the same seed are identical step for step. Each ``step``:

1. the fleet steps (PyBullet): units move, scheduled events happen, LiDARs scan, and the
   tick's scans go to the map server (acknowledged before any map read, so runs are
   deterministic for a seed);
2. every ``map_read_s`` [s] the units read the shared costmap (``GET /v1/costmap``,
   raw); every ``coordination.lane_refresh_s`` of the scenario the lane coordinator
   re-reads lane costs (``coordination.lanes_from``: worked out on that costmap, or a
   ``POST /v1/query/segments``);
3. the coordinator takes the units' positions and grants lanes; breakdowns start; a trip
   that has had no route too long goes back to the queue (``scenarios.run.trip_queue``);
   released trips go to idle units (``scenarios.run.dispatch``); each unit's agent plans on
   the costmap and commands its drive;
4. the observers that are due run (``scenarios.run.observers``): each declares how often
   (``every_s``) and reads what the step did (``StepReport``); they record, score and
   publish, and never change the fleet.

``finish()`` splits every freeze into phantom and true-block segments (planning on the
ground-truth costmap at its start and after each world change during it) and assembles
the metrics of docs/files.md into the ``RunRecord``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from fleet.ground_truth import GroundTruth
from fleet.poster import ScanPoster
from fleet.sim import FleetSim, StepResult
from fleet.world import World
from mapserver.client import Grid, MapClient
from mapserver.client.zoned import ZonedMapClient
from mapserver.core.geometry import GridGeometry
from mapserver.core.queries import query_segments
from planner.coordinator import LaneCoordinator
from planner.decisions import Action
from planner.freeze import TruthLanes, classify
from planner.grid_search import GridPlanner
from planner.lane_graph import LaneGraph, SegmentQuerier
from planner.navigator import UnitNavigator
from scenarios.run.agents import AgentState, TaskAgent
from scenarios.run.dispatch import Dispatcher
from scenarios.run.fleet_filter import FleetMemberFilter
from scenarios.run.observers import Observer, Schedule, StandardObservers
from scenarios.run.record import EventRecord, RunRecord
from scenarios.run.trip_queue import ReturnWatch, TripQueue
from scenarios.score.clearing import ClearingTracker
from scenarios.score.counts import freeze_counts, plan_counts
from scenarios.score.evidence import freeze_records
from scenarios.score.free_run import free_run_metrics
from scenarios.score.incidents import collision_counts
from scenarios.score.map_truth import summary as map_truth_summary
from scenarios.score.metric_registry import check_run_metrics
from scenarios.score.truth_timeline import truth_timeline
from scenarios.spec.coordination import CoordinationSpec
from scenarios.spec.scenario import Scenario
from scenarios.spec.tasks import Task

POSTS_IN_FLIGHT = 4  # ticks of scans on their way to the server while the sim steps on
CLOCK_EVERY_S = 1.0  # [s] of sim time between declarations of its clock (docs/map-time.md)


@dataclass(frozen=True)
class RunOptions:
    """How a run is observed: map_read_s [s] between the units' costmap reads; what the
    replay keeps: unit poses every ``record_units_s`` [s], scans every ``record_scans_s``
    [s] per unit, grids every ``record_grids_s`` [s]. How the fleet is coordinated is the
    scenario's ``coordination`` section (``scenarios.spec.coordination``)."""

    map_read_s: float = 0.5
    record_units_s: float = 0.5
    record_scans_s: float = 0.5
    record_grids_s: float = 5.0


@dataclass(frozen=True)
class Motion:
    """A drive's speed [m/s] and turn rate [rad/s] over the sim step just taken."""

    speed: float
    turn_rate: float


@dataclass
class StepReport:
    """What one ``step`` did, for the observers: the sim's result, the trips returned to
    the queue (unit, trip, cause), the trips handed out (unit, trip, start node, position
    [m]), every unit's position [m] at the step,
    every agent's state and its drive's motion before the new command, the paths newly
    sent to drives, the units blocked now."""

    now: float
    sim: StepResult
    positions: dict[str, tuple[float, float]] = field(default_factory=dict)
    returned: list[tuple[str, Task, str]] = field(default_factory=list)
    assigned: list[tuple[str, Task, str, tuple[float, float]]] = field(default_factory=list)
    states: dict[str, AgentState] = field(default_factory=dict)
    motion: dict[str, Motion] = field(default_factory=dict)
    new_paths: list[tuple[str, tuple[tuple[float, float], ...]]] = field(default_factory=list)
    frozen: set[str] = field(default_factory=set)


class Episode:
    """A run of ``setup`` against the map server behind ``client`` (or the zones' servers
    behind a ``ZonedMapClient``) (module docstring).

    extra_observers: run after the standard ones (``standard_observers``), e.g. a
    progress bar. Call ``reset`` first, ``close`` at the end (or use ``with``).
    """

    def __init__(
        self,
        setup: Scenario,
        client: MapClient | ZonedMapClient,
        options: RunOptions | None = None,
        extra_observers: Sequence[Observer] = (),
    ) -> None:
        self.setup = setup
        self.client = client
        self.options = options or RunOptions()
        self.geometry = setup.geometry()
        meta = client.map_meta()
        if meta.geometry != self.geometry:
            raise ValueError(grid_mismatch(meta.geometry, self.geometry))
        if meta.stamp is not None:
            raise ValueError(
                f"--server: its map already holds scans up to stamp {meta.stamp:g} s, and a "
                "run's units stamp their scans in sim time from 0 s: run against a server "
                "with an empty map (a new data dir; with docker compose, `down -v` first)"
            )
        self._extra = tuple(extra_observers)
        self.world: World | None = None

    # ------------------------------------------------------------------ lifecycle
    def reset(self, seed: int | None = None) -> None:
        """Build the world, fleet, lanes and observers for ``seed`` (None: the
        scenario's own) at sim time 0."""
        self.close()
        if seed is not None:
            self.setup = self.setup.with_seed(seed)
        setup, opts = self.setup, self.options
        self.wall0 = time.perf_counter()
        self.record = RunRecord(
            setup.name, setup.map_server.policy.value, setup.seed, self.geometry
        )
        units = setup.unit_specs()
        self.world = world = World(setup.build_layout()).__enter__()
        radius = {spec.unit_id: spec.drive.radius for spec in units}

        def unit_positions() -> dict[str, tuple[float, float, float]]:
            return {uid: (*_xy(world.unit_pose(uid)), r) for uid, r in radius.items()}

        # Scans go out on a worker thread while the sim casts the next tick's rays;
        # every map read waits for them first (``synced``), so runs stay deterministic.
        self.poster = FleetMemberFilter(
            ScanPoster(self.client, in_flight=POSTS_IN_FLIGHT, declare_every_s=CLOCK_EVERY_S),
            unit_positions,
        )
        self.sim = FleetSim(world, units, seed=setup.seed, poster=self.poster)
        plan = setup.coordination
        self.graph = graph = setup.build_lane_graph(segment_m=plan.segment_m)
        lanes = CostmapSegments(self) if plan.lanes_from == "costmap" else self.client
        self.coordinator = coordinator = _coordinator(graph, lanes, units, plan)
        planner = GridPlanner(self.geometry)
        reroute = _rerouter(coordinator, graph)
        self.agents = {
            spec.unit_id: TaskAgent(
                spec.unit_id,
                graph,
                coordinator,
                UnitNavigator(
                    spec.unit_id, self.geometry, planner, setup.recovery, reroute=reroute
                ),
                priority=float(-i),
            )
            for i, spec in enumerate(units)
        }
        # every unit holds its start node from t = 0: the nearest node no unit before it
        # holds (the coordinator is new, so those are all the held nodes)
        held: set[str] = set()
        for i, spec in enumerate(units):
            node = graph.nearest_free_node(spec.start.x, spec.start.y, held)
            coordinator.request(spec.unit_id, node, node, float(-i), 0.0)
            held.add(node)
        self.truth = GroundTruth(world, self.geometry, setup.inflation())
        self.clearing = ClearingTracker(self.geometry)
        self.events: list = []
        for change in setup.world_schedule():
            self.sim.schedule(change.time, self._recording(change))
        self._breakdowns = list(setup.breakdowns())
        queue = TripQueue(graph, setup.tasks.retry_after)
        self.dispatcher = Dispatcher(setup.task_stream(), graph, plan.dispatch, queue)
        self.returns = ReturnWatch(setup.tasks.return_after, graph, self.geometry)
        self.costs: Grid | None = None
        self._map_reads = Schedule(opts.map_read_s)
        self._lane_reads = Schedule(plan.lane_refresh_s)
        self.standard = StandardObservers.of(self)
        self.observers = (*self.standard.all(), *self._extra)
        self._observer_schedules = [Schedule(o.every_s) for o in self.observers]
        self.report: StepReport | None = None

    def close(self) -> None:
        """Release the world (PyBullet); the record stays."""
        if self.world is not None:
            self.world.__exit__(None, None, None)
            self.world = None

    def __enter__(self) -> Episode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def now(self) -> float:
        """[s] sim time."""
        return self.sim.time

    @property
    def done(self) -> bool:
        """True once the scenario's duration has run."""
        return self.sim.time >= self.setup.duration - 1e-9

    def synced(self) -> MapClient | ZonedMapClient:
        """The map client, once every scan posted so far is acknowledged."""
        self.poster.flush()
        return self.client

    # ------------------------------------------------------------------ one step
    def step(self) -> StepReport:
        """Advance ``dt`` [s] (module docstring); returns what the step did."""
        if self.world is None:
            raise RuntimeError("reset() the episode before step()")
        result = self.sim.step(self.setup.dt)
        now = result.time
        positions = {uid: _xy(u.drive.pose) for uid, u in self.sim.units.items()}
        report = StepReport(now, result, positions)
        self.record.collisions.extend(result.collisions)
        if self._map_reads.due(now):  # due at the first step
            read = self.synced().costmap()
            # one writable copy a read: each navigator clears its own footprint in it and
            # puts it back after planning (``UnitNavigator._plan``), where a read-only
            # grid was copied whole for every plan
            self.costs = replace(read, data=read.data.copy())
        if self._lane_reads.due(now):
            if self.setup.coordination.lanes_from == "server":
                self.synced()
            self.coordinator.refresh(now)
        self.coordinator.tick(now, positions)
        self._start_breakdowns(now, positions)
        self._give_back(now, report)
        self._dispatch(now, positions, report)
        for uid, agent in self.agents.items():
            drive = self.sim.unit(uid)
            before = agent.navigator.last_plan
            state = agent.step(now, positions[uid], self.costs.data)
            report.states[uid] = state
            report.motion[uid] = Motion(drive.speed, drive.turn_rate)
            command = state.command
            if command.kind == "follow" and agent.navigator.last_plan is not before:
                drive.follow(command.path[1:] or command.path)
                report.new_paths.append((uid, command.path))
            elif command.kind in ("stop", "rotate"):
                drive.halt()
            if state.blocked_reason is not None:
                report.frozen.add(uid)
        self.report = report
        for observer, schedule in zip(self.observers, self._observer_schedules, strict=True):
            if schedule.due(now):
                observer.observe(self)
        return report

    def _start_breakdowns(self, now: float, positions) -> None:
        for event in [b for b in self._breakdowns if b.at <= now + 1e-9]:
            self._breakdowns.remove(event)
            self.agents[event.unit_id].broken_until = event.until
            self.sim.unit(event.unit_id).halt()
            x, y = positions[event.unit_id]
            self.record.events.append(
                EventRecord(now, event.kind, event.unit_id, x, y, event.describe())
            )

    def _give_back(self, now: float, report: StepReport) -> None:
        """Return to the queue the trips that have had no route too long (``returns``)."""
        for uid, agent in self.agents.items():
            status = self.coordinator.status(uid) if agent.task is not None else None
            cause = self.returns.due(now, uid, agent, status, self.costs.data)
            if cause is not None:
                task = agent.give_back(now, status.node or status.target)
                self.dispatcher.give_back(task, uid, now)
                report.returned.append((uid, task, cause))

    def _dispatch(self, now: float, positions, report: StepReport) -> None:
        idle = {
            uid: node
            for uid, agent in self.agents.items()
            if agent.task is None and now >= agent.broken_until
            if (node := self.coordinator.start_node(uid)) is not None
        }
        for uid, task in self.dispatcher.match(now, idle):
            self.agents[uid].assign(task, now, idle[uid])
            report.assigned.append((uid, task, idle[uid], positions[uid]))

    def _recording(self, change) -> Callable[[World], None]:
        """Apply a scheduled world change; record its event once, and watch every removal
        (an object leaving its place) for time to clear."""
        event = change.event

        def apply(world: World) -> None:
            object_id = getattr(event, "object_id", "")
            before = world.obstacles.get(object_id)
            change.apply(world)
            if event in self.events:
                return  # a person's later steps
            self.events.append(event)
            after = world.obstacles.get(object_id)
            where = (after or before).shape.bounds() if (after or before) else (0, 0, 0, 0)
            x, y = (where[0] + where[2]) / 2, (where[1] + where[3]) / 2
            self.record.events.append(
                EventRecord(self.sim.time, event.kind, object_id, x, y, event.describe())
            )
            if event.kind in ("move", "remove") and before is not None:
                self.clearing.removed(object_id, before.shape.bounds(), self.sim.time)

        return apply

    # ------------------------------------------------------------------ the end
    def finish(self) -> RunRecord:
        """Score the run (module docstring) and return its record."""
        self.synced()
        now = self.sim.time
        for observer in self.observers:
            observer.finish(self)
        planner = GridPlanner(self.geometry)

        def plan(costs: np.ndarray, start, goal) -> bool:
            return planner.plan(costs, start, goal).found

        lanes = TruthLanes(self.graph, self.geometry)  # lane freezes: the router on truth
        timeline = truth_timeline(self.truth)
        watch = self.standard.freezes
        watch.detector.finish(now)
        for freeze in watch.detector.freezes:  # every freeze, not only those still open
            classify(freeze, timeline, plan, lane_plan=lanes)
        self.record.freezes = freeze_records(
            watch.detector.freezes, self.agents, self.coordinator, self.truth,
            watch.evidence, self.standard.scans.index, watch.held_by,
        )  # fmt: skip
        self.record.time_to_clear = {
            w.object_id: t
            for w, t in zip(self.clearing.watches, self.clearing.times(), strict=True)
        }
        self.record.metrics = self._metrics(time.perf_counter() - self.wall0)
        return self.record

    def _metrics(self, wall_seconds: float) -> dict[str, object]:
        """``metrics.json``: the run's own keys and the scorers' (each declares the keys it
        feeds); MetricError when they differ from the metric registry's."""
        freezes = self.record.freezes
        replans = sum(
            1 for a in self.agents.values() for act in a.navigator.actions
            if act.action in ("replan", "reroute")
        ) + sum(1 for d in self.coordinator.log if d.action is Action.REROUTE)  # fmt: skip
        throughput = self.standard.throughput.tracker
        metrics = {
            "scenario": self.setup.name,
            "policy": self.record.policy,
            "seed": self.setup.seed,
            "units": self.setup.units.count,
            "sim_seconds": round(self.sim.time, 6),
            "wall_seconds": round(wall_seconds, 3),
            "tasks_completed": len(throughput.trips),
            **freeze_counts(freezes),
            **plan_counts(self.record.plans),
            **collision_counts(self.record.incidents),  # incidents (fleet's, scenario's)
            "time_to_clear_s": [None if t is None else round(t, 3) for t in self.clearing.times()],
            "map_truth": map_truth_summary(self.record.map_truth),
            "replans": replans,
            "deadlocks": self.coordinator.deadlocks,
            "scans_fused": self.poster.poster.posted,
            "events": len(self.events),
            **throughput.metrics(self.setup.units.count, self.sim.time),
            **free_run_metrics(self.setup, self.sim.time, len(throughput.trips)),
        }
        check_run_metrics(metrics)
        return metrics


class CostmapSegments:
    """Lane readings (``query_segments``, docs/http-api.md 2.5) worked out on the costmap the
    fleet last read over HTTP, as the server works them out on its own: no request per
    refresh, and none of the map server's time taken from fusing scans."""

    def __init__(self, episode: Episode) -> None:
        self.episode = episode

    def query_segments(self, segments):
        """One reading per segment ``(x0, y0, x1, y1)`` [m], in order."""
        return query_segments(self.episode.geometry, self.episode.costs.data, segments)


def _xy(pose) -> tuple[float, float]:
    return (pose.x, pose.y)


def _coordinator(
    graph: LaneGraph, client: SegmentQuerier, units, plan: CoordinationSpec
) -> LaneCoordinator:
    """The run's lane coordinator as the scenario's ``coordination`` says; by default a
    node is left once a unit's body is clear of it, and units ask for their next lanes a
    braking distance (plus a margin) before the end of what they hold
    (``CoordinationSpec.settings``)."""
    radius = max(spec.drive.radius for spec in units)
    braking_m = max(spec.drive.max_speed**2 / (2 * spec.drive.max_accel) for spec in units)
    settings = plan.settings(radius, braking_m)
    return LaneCoordinator(graph, client, policy=plan.policy, settings=settings)


def _rerouter(coordinator: LaneCoordinator, graph: LaneGraph):
    """The navigator's "ask for another route": re-read the lanes, give the route's nodes."""

    def reroute(unit_id: str, position):
        status = coordinator.status(unit_id)
        if status.state == "no_route" or not status.route:
            return None
        return [graph.position(node) for node in status.route[1:2]] or None

    return reroute


def grid_mismatch(server: GridGeometry, scenario: GridGeometry) -> str:
    """Why a run cannot use a server with grid ``server``: both grids in words and the
    server settings that would give the scenario's (``grid.*``, or the same as
    ``FLEETMAP_GRID__*`` variables)."""
    wanted = scenario.differing_fields(server)
    config = ", ".join(f"grid.{name}: {value:g}" for name, value in wanted.items())
    variables = " ".join(
        f"FLEETMAP_GRID__{name.upper()}={value:g}" for name, value in wanted.items()
    )
    return (
        f"--server: its grid is {server.describe()}, the scenario's {scenario.describe()} "
        f"(start the server with {config} in its --config, or {variables}, and no --map; "
        "or run without --server)"
    )
