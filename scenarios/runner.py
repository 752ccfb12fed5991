"""Run one scenario end to end and score it against ground truth.

The loop, every ``dt`` [s] of sim time:

1. the fleet steps (PyBullet): units move, scheduled events happen, LiDARs scan, and the
   tick's scans are posted to the map server as one batch (acknowledged before going on,
   so runs are deterministic for a seed);
2. every ``map_read_s`` [s] the units read the shared costmap (``GET /v1/costmap``, raw),
   the lane coordinator re-reads lane costs (``POST /v1/query/segments``) every
   ``lane_refresh_s``, and removal events are checked for time to clear;
3. the coordinator grants lanes, each unit's agent plans on the costmap and commands
   its drive; freezes are detected (``planner.freeze``), every plan is checked against
   the ground-truth costmap (stale-free plans).

At the end every freeze is classified phantom or true by planning on the ground-truth
costmap during the freeze, and the metrics of CONTRACT section 3 are assembled.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np

from fleet.ground_truth import GroundTruth
from fleet.poster import ScanPoster
from fleet.sim import FleetSim
from fleet.world import World
from mapserver.client import Grid, MapClient, UnitState
from mapserver.geometry import GridGeometry
from planner.coordinator import LaneCoordinator
from planner.freeze import Freeze, FreezeDetector, UnitObservation, classify, stale_free_cells
from planner.grid_search import GridPlanner
from planner.lane_graph import LaneGraph
from planner.navigator import UnitNavigator
from scenarios.agents import TaskAgent
from scenarios.clearing import ClearingTracker
from scenarios.dispatch import Dispatcher
from scenarios.embedded_server import EmbeddedServer
from scenarios.evidence import freeze_records
from scenarios.fleet_filter import FleetMemberFilter
from scenarios.record import (
    EventRecord,
    GridSample,
    PlanSample,
    RunRecord,
    ScanSample,
    UnitSample,
)
from scenarios.spec import Scenario
from scenarios.throughput import ThroughputTracker

Progress = Callable[[float, float], None]
POSTS_IN_FLIGHT = 4  # ticks of scans on their way to the server while the sim steps on


@dataclass(frozen=True)
class RunOptions:
    """How a run is observed: map_read_s, lane_refresh_s [s] between reads; what the
    replay keeps: unit poses every ``record_units_s`` [s], scans every ``record_scans_s``
    [s] per unit, grids every ``record_grids_s`` [s]. How the fleet is coordinated:
    lanes split every ``segment_m`` [m] (None: junction to junction) so units can follow
    one another; ``reserve_ahead``: units are granted their next lanes before they
    reach the end of the one they drive (False: one lane at a time, on arrival);
    ``dispatch``: which idle unit gets a released trip (``scenarios.dispatch.RULES``)."""

    map_read_s: float = 0.5
    lane_refresh_s: float = 1.0
    record_units_s: float = 0.5
    record_scans_s: float = 0.5
    record_grids_s: float = 5.0
    segment_m: float | None = 4.0
    reserve_ahead: bool = True
    dispatch: str = "nearest"


RESERVE_MARGIN_M = 1.0
"""[m] how much earlier than its braking distance a unit asks for its next lanes."""


def run(
    setup: Scenario,
    server_url: str | None = None,
    options: RunOptions | None = None,
    progress: Progress | None = None,
    token: str | None = None,
    announce: Callable[[str], None] | None = None,
) -> RunRecord:
    """Run scenario ``setup`` against ``server_url`` (None: an embedded server of its own;
    ``token``: the bearer token for a server that needs one)."""
    options = options or RunOptions()
    with tempfile.TemporaryDirectory(prefix="fleetmap-run-") as tmp:
        server = None
        if server_url is None:
            server = EmbeddedServer(Path(tmp) / "data", setup.server_overrides())
            server_url = server.url
            if announce is not None:
                announce(f"map server for this run: {server_url}/ (the live viewer)")
        try:
            with httpx.Client(base_url=server_url, timeout=60) as http:
                client = MapClient(http, token=token, timeout=60)
                return _Run(setup, client, options, progress).execute()
        finally:
            if server is not None:
                server.stop()


class _Run:
    """The state of one run (see the module docstring)."""

    def __init__(
        self, setup: Scenario, client: MapClient, options: RunOptions, progress: Progress | None
    ) -> None:
        self.setup = setup
        self.client = client
        self.options = options
        self.progress = progress
        meta = client.map_meta()
        self.geometry = setup.geometry()
        if meta.geometry != self.geometry:
            raise ValueError(
                f"server: its grid {meta.geometry} is not the scenario's {self.geometry}"
            )
        self.policy = setup.map_server.policy.value
        self.record = RunRecord(setup.name, self.policy, setup.seed, self.geometry)
        self._evidence: dict = {}  # (unit, point) -> (stamp, CellInfo) when first blocked
        self._scan_index: dict[float, list] = {}  # stamp -> [(unit, x, y, range_max)]

    def execute(self) -> RunRecord:
        setup, opts = self.setup, self.options
        wall0 = time.perf_counter()
        units = setup.unit_specs()
        with World(setup.build_layout()) as world:
            radius = {spec.unit_id: spec.drive.radius for spec in units}
            sim_ref: list[FleetSim] = []

            def unit_positions() -> dict[str, tuple[float, float, float]]:
                return {
                    uid: (u.drive.pose.x, u.drive.pose.y, radius[uid])
                    for uid, u in sim_ref[0].units.items()
                }

            # Scans go out on a worker thread while the sim casts the next tick's rays;
            # every map read waits for them first (``_synced``), so runs stay deterministic.
            poster = FleetMemberFilter(
                ScanPoster(self.client, in_flight=POSTS_IN_FLIGHT), unit_positions
            )
            self._poster = poster
            sim = FleetSim(world, units, seed=setup.seed, poster=poster)
            sim_ref.append(sim)
            graph = setup.build_lane_graph(segment_m=opts.segment_m)
            coordinator = _coordinator(graph, self.client, units, opts)
            planner = GridPlanner(self.geometry)
            agents = {
                spec.unit_id: TaskAgent(
                    spec.unit_id,
                    graph,
                    coordinator,
                    UnitNavigator(spec.unit_id, self.geometry, planner, setup.recovery),
                    priority=float(-i),
                )
                for i, spec in enumerate(units)
            }
            for agent in agents.values():
                agent.navigator.reroute = _rerouter(coordinator, graph)
            for i, spec in enumerate(units):  # every unit holds its start node from t = 0
                node = _start_node(coordinator, graph, spec.unit_id, (spec.start.x, spec.start.y))
                coordinator.request(spec.unit_id, node, node, float(-i), 0.0)
            truth = GroundTruth(world, self.geometry, setup.inflation())
            clearing = ClearingTracker(self.geometry)
            events = self._schedule_events(sim, clearing)
            breakdowns = list(setup.breakdowns())
            dispatcher = Dispatcher(setup.task_stream(), graph, opts.dispatch)
            detector = FreezeDetector()
            throughput = ThroughputTracker(graph, setup.dt, coordinator.arrive_tol)
            costs: Grid | None = None
            next_read = next_refresh = next_units = next_grid = 0.0
            next_scan: dict[str, float] = {}
            collisions = tasks_done = 0
            while sim.time < setup.duration - 1e-9:
                step = sim.step(setup.dt)
                now = step.time
                collisions += len(step.collisions)
                self.record.collisions.extend(step.collisions)
                for scan in step.scans:
                    self._scan_index.setdefault(scan.stamp, []).append(
                        (scan.unit_id, scan.pose.x, scan.pose.y, scan.range_max)
                    )
                    if now >= next_scan.get(scan.unit_id, 0.0):
                        self.record.scans.append(_scan_sample(scan))
                        next_scan[scan.unit_id] = now + opts.record_scans_s
                if costs is None or now >= next_read - 1e-9:
                    costs = self._synced().costmap()
                    clearing.observe(costs.data, now)
                    next_read = now + opts.map_read_s
                if now >= next_refresh - 1e-9:
                    self._synced()
                    coordinator.refresh(now)
                    next_refresh = now + opts.lane_refresh_s
                positions = {uid: (u.drive.pose.x, u.drive.pose.y) for uid, u in sim.units.items()}
                coordinator.tick(now, positions)
                frozen_now = set()
                for event in [b for b in breakdowns if b.at <= now + 1e-9]:
                    breakdowns.remove(event)
                    agents[event.unit_id].broken_until = event.until
                    sim.unit(event.unit_id).halt()
                    x, y = positions[event.unit_id]
                    self.record.events.append(
                        EventRecord(now, event.kind, event.unit_id, x, y, event.describe())
                    )
                idle = {
                    uid: node
                    for uid, agent in agents.items()
                    if agent.task is None and now >= agent.broken_until
                    if (node := _start_node(coordinator, graph, uid, positions[uid])) is not None
                }
                for uid, task in dispatcher.match(now, idle):
                    agents[uid].assign(task, now, idle[uid])
                    throughput.assigned(positions[uid], idle[uid], task, now, sim.unit(uid).limits)
                for uid, agent in agents.items():
                    drive = sim.unit(uid)
                    before = agent.navigator.last_plan
                    state = agent.step(now, positions[uid], costs.data)
                    throughput.observe(uid, now, agent, state, drive)
                    if state.task_done is not None:
                        tasks_done += 1
                    command = state.command
                    if command.kind == "follow" and agent.navigator.last_plan is not before:
                        drive.follow(command.path[1:] or command.path)
                        self._check_plan(uid, now, command.path, truth)
                    elif command.kind in ("stop", "rotate"):
                        drive.halt()
                    obs = UnitObservation(
                        uid, now, state.has_task, command.moving or command.kind == "idle",
                        state.blocked_reason, state.blocking, state.goal, positions[uid],
                    )  # fmt: skip
                    detector.observe(obs)
                    if state.blocked_reason is not None:
                        frozen_now.add(uid)
                        self._note_blocking(uid, now, state.blocking)
                if now >= next_units - 1e-9:
                    self._record_units(sim, agents, frozen_now, now)
                    self._publish_units(sim, agents, frozen_now, now)
                    next_units = now + opts.record_units_s
                if now >= next_grid - 1e-9:
                    self.record.grids.append(
                        GridSample(
                            now,
                            costs.version,
                            costs.data.copy(),
                            self._synced().occupancy().data.copy(),
                        )
                    )
                    next_grid = now + opts.record_grids_s
                if self.progress is not None:
                    self.progress(now, setup.duration)
            self._synced()
            freezes = detector.finish(sim.time)
            self._classify(freezes, truth)
            self.record.freezes = freeze_records(
                detector.freezes, agents, coordinator, truth, self._evidence, self._scan_index
            )
            self.record.time_to_clear = {
                w.object_id: t for w, t in zip(clearing.watches, clearing.times(), strict=True)
            }
            scans_fused = self._poster.poster.posted
            self.record.trips = throughput.trips
            self.record.metrics = self._metrics(
                sim, coordinator, agents, collisions, scans_fused, tasks_done, clearing,
                time.perf_counter() - wall0, events, throughput,
            )  # fmt: skip
        return self.record

    # ------------------------------------------------------------------ scoring
    def _check_plan(self, uid: str, now: float, path, truth: GroundTruth) -> None:
        stale = stale_free_cells(path, truth.costmap(now), self.geometry)
        self.record.plans.append(PlanSample(now, uid, tuple(path), tuple(stale)))

    def _synced(self) -> MapClient:
        """The map client, once every scan posted so far is acknowledged."""
        self._poster.flush()
        return self.client

    def _note_blocking(self, uid: str, now: float, points) -> None:
        """Read each new blocking cell's evidence from the map when it is first seen."""
        new = [p for p in points if (uid, p) not in self._evidence]
        if new:
            for point, info in zip(new, self._synced().query_cells(new), strict=True):
                self._evidence[(uid, point)] = (now, info)

    def _classify(self, freezes: list[Freeze], truth: GroundTruth) -> None:
        planner = GridPlanner(self.geometry)

        def plan(costs: np.ndarray, start, goal) -> bool:
            return planner.plan(costs, start, goal).found

        for freeze in freezes:
            classify(freeze, truth.costmap, plan)

    def _record_units(self, sim: FleetSim, agents, frozen: set[str], now: float) -> None:
        for uid, unit in sim.units.items():
            pose = unit.drive.pose
            agent = agents[uid]
            task = agent.task.task_id if agent.task is not None else None
            moving = not unit.drive.idle
            self.record.units.append(
                UnitSample(now, uid, pose.x, pose.y, pose.yaw, moving, uid in frozen, task)
            )

    def _publish_units(self, sim: FleetSim, agents, frozen: set[str], now: float) -> None:
        """Show the units, their plans and freezes in the server's live viewer."""
        states = []
        for uid, unit in sim.units.items():
            plan = agents[uid].navigator.last_plan
            path = tuple(plan.path) if plan is not None and plan.found else ()
            states.append(UnitState(uid, now, unit.drive.pose, path, uid in frozen))
        self.client.publish_units(states)

    def _metrics(self, sim, coordinator, agents, collisions, scans_fused, tasks_done, clearing,
                 wall_seconds, events, throughput) -> dict[str, object]:  # fmt: skip
        freezes = self.record.freezes
        phantom = [f for f in freezes if f.phantom]
        replans = sum(
            1 for a in agents.values() for act in a.navigator.actions
            if act.action in ("replan", "reroute")
        ) + sum(1 for d in coordinator.log if d.action == "reroute")  # fmt: skip
        return {
            "scenario": self.setup.name,
            "policy": self.policy,
            "seed": self.setup.seed,
            "units": self.setup.units.count,
            "sim_seconds": round(sim.time, 6),
            "wall_seconds": round(wall_seconds, 3),
            "tasks_completed": tasks_done,
            "phantom_freezes": len(phantom),
            "phantom_freeze_seconds": round(sum(f.duration for f in phantom), 3),
            "true_block_freezes": len(freezes) - len(phantom),
            "stale_free_plans": sum(1 for p in self.record.plans if p.stale_free),
            "collisions": collisions,
            "time_to_clear_s": [None if t is None else round(t, 3) for t in clearing.times()],
            "replans": replans,
            "deadlocks": coordinator.deadlocks,
            "scans_fused": scans_fused,
            "events": len(events),
            **throughput.metrics(self.setup.units.count, sim.time),
        }

    def _schedule_events(self, sim: FleetSim, clearing: ClearingTracker) -> list:
        """Schedule the scenario's world changes; record each event once, and watch every
        removal (an object leaving its place) for time to clear."""
        events: list = []
        for change in self.setup.world_schedule():
            sim.schedule(change.time, self._recording(change, events, clearing, sim))
        return events

    def _recording(self, change, events: list, clearing: ClearingTracker, sim: FleetSim):
        event = change.event

        def apply(world: World) -> None:
            object_id = getattr(event, "object_id", "")
            before = world.obstacles.get(object_id)
            change.apply(world)
            if event in events:
                return  # a person's later steps
            events.append(event)
            after = world.obstacles.get(object_id)
            where = (after or before).shape.bounds() if (after or before) else (0, 0, 0, 0)
            x, y = (where[0] + where[2]) / 2, (where[1] + where[3]) / 2
            self.record.events.append(
                EventRecord(sim.time, event.kind, object_id, x, y, event.describe())
            )
            if event.kind in ("move", "remove") and before is not None:
                clearing.removed(object_id, before.shape.bounds(), sim.time)

        return apply


def _coordinator(graph: LaneGraph, client: MapClient, units, opts: RunOptions) -> LaneCoordinator:
    """The run's lane coordinator: a node is left once a unit's body is clear of it, and
    with ``opts.reserve_ahead`` units ask for their next lanes a braking distance (plus
    ``RESERVE_MARGIN_M``) before the end of what they hold."""
    clear_m = 2.0 * max(spec.drive.radius for spec in units) + 0.2
    braking_m = max(spec.drive.max_speed**2 / (2 * spec.drive.max_accel) for spec in units)
    ahead_m = braking_m + RESERVE_MARGIN_M if opts.reserve_ahead else 0.0
    return LaneCoordinator(graph, client, clear_m=clear_m, reserve_ahead_m=ahead_m)


def _start_node(coordinator: LaneCoordinator, graph: LaneGraph, uid: str, position) -> str | None:
    """Where a unit's trip starts: the node it stands at or drives to (None: stranded on a
    lane); a unit the coordinator does not know yet is at the nearest node nobody holds."""
    if uid not in coordinator.unit_ids:  # the nearest node nobody holds
        free = [n for n in graph.nodes if coordinator.holder(n) is None]
        return min(free, key=lambda n: (math.dist(graph.position(n), position), n), default=None)
    status = coordinator.status(uid)
    return status.node or status.target


def _rerouter(coordinator: LaneCoordinator, graph: LaneGraph):
    """The navigator's "ask for another route": re-read the lanes, give the route's nodes."""

    def reroute(unit_id: str, position):
        status = coordinator.status(unit_id)
        if status.state == "no_route" or not status.route:
            return None
        return [graph.position(node) for node in status.route[1:2]] or None

    return reroute


def _scan_sample(scan) -> ScanSample:
    return ScanSample(
        scan.stamp, scan.unit_id, scan.pose.x, scan.pose.y, scan.pose.yaw, scan.angle_min,
        scan.angle_increment, scan.range_min, scan.range_max, scan.ranges.astype(np.float32),
    )  # fmt: skip


def grid_geometry(width_m: float, height_m: float, resolution: float) -> GridGeometry:
    """The map grid covering a ``width_m`` x ``height_m`` [m] floor at ``resolution``."""
    return GridGeometry(
        int(math.ceil(width_m / resolution - 1e-9)),
        int(math.ceil(height_m / resolution - 1e-9)),
        resolution,
    )
