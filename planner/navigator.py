"""What a drive unit does on its way: follow its route, plan locally, recover when blocked.

A ``UnitNavigator`` is given a route (lane waypoints [m], from the lane coordinator or a
task) and, every tick, the unit's position and the fleet's current costmap (read over
HTTP by the caller). It plans on the costmap from the unit to its next waypoint (so it
detours around a tote in an aisle) and returns a ``Command`` whose path is the plan's
line-of-sight shortcuts (``planner.path_smoothing``): a few straight legs, no
staircase. When no admissible path exists it runs a recovery sequence, as an operator would want:

1. ``wait`` up to ``wait_s`` [s], replanning every tick (a person walks on);
2. ``rotate``: turn in place once (``rotate_s`` [s]) so the LiDAR looks again, which lets
   the shared map clear a phantom;
3. ``replan``: plan once more on the refreshed costmap;
4. ``reroute``: ask for another route (``reroute`` callback, e.g. the lane coordinator);
   if there is none, wait again, with ``wait_s`` doubled up to ``max_wait_s``.

Every action is recorded (``actions``) with its stamp, cause and the cells that blocked
(world points of the first lethal or inscribed cells on the straight line to the
waypoint), so a replay can explain every freeze.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from mapserver.core.costvalues import FREE, UNKNOWN
from mapserver.core.errors import FieldError
from mapserver.core.geometry import GridGeometry
from mapserver.core.queries import query_segments
from planner.grid_search import GridPlanner, PlanResult
from planner.path_smoothing import smooth_path

Point = tuple[float, float]


@dataclass(frozen=True)
class RecoveryConfig:
    """wait_s [s] first wait; rotate_s [s] one turn in place; max_wait_s [s] back-off
    cap; arrive_m [m] a waypoint is reached within this distance; allow_unknown: plan
    through unknown cells."""

    wait_s: float = 1.0
    rotate_s: float = 4.0
    max_wait_s: float = 8.0
    arrive_m: float = 0.25
    allow_unknown: bool = True

    def __post_init__(self) -> None:
        for name in ("wait_s", "rotate_s", "max_wait_s", "arrive_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise FieldError(name, value, "must be a positive number")


@dataclass(frozen=True)
class Command:
    """What the unit should do now: ``follow`` a path, ``rotate`` in place, ``stop``
    (blocked: ``reason`` and ``blocking`` say why) or ``idle`` (no route / arrived)."""

    kind: str
    path: tuple[Point, ...] = ()
    reason: str | None = None
    blocking: tuple[Point, ...] = ()

    @property
    def moving(self) -> bool:
        """Does this command translate the unit (a turn in place does not)?"""
        return self.kind == "follow"


@dataclass(frozen=True)
class Action:
    """A recorded navigation decision: unit, stamp [s], action, cause, blocking cells."""

    unit_id: str
    stamp: float
    action: str
    cause: str
    blocking: tuple[Point, ...] = ()


@dataclass
class _Recovery:
    phase: str  # "wait", "rotate"
    since: float
    wait_s: float
    reason: str
    blocking: tuple[Point, ...] = ()


@dataclass
class UnitNavigator:
    """Route following with local planning and recovery for one unit (see module doc)."""

    unit_id: str
    geometry: GridGeometry
    planner: GridPlanner
    config: RecoveryConfig = field(default_factory=RecoveryConfig)
    reroute: Callable[[str, Point], Sequence[Point] | None] | None = None
    footprint_m: float = 0.6  # [m] cleared around the unit before planning (below)
    actions: list[Action] = field(default_factory=list)
    last_plan: PlanResult | None = None  # the latest plan, for scoring (stale-free plans)

    def __post_init__(self) -> None:
        self._route: list[Point] = []
        self._recovery: _Recovery | None = None

    @property
    def route(self) -> tuple[Point, ...]:
        """The waypoints still ahead [m]."""
        return tuple(self._route)

    def set_route(self, waypoints: Sequence[Point], stamp: float, cause: str = "task") -> None:
        """Follow ``waypoints`` [m] from now on (replacing any route)."""
        self._route = [(float(x), float(y)) for x, y in waypoints]
        self._recovery = None
        self._record(stamp, "route", f"{cause}: {len(self._route)} waypoints")

    def step(self, stamp: float, position: Point, costs: np.ndarray) -> Command:
        """The command for this tick at ``position`` [m] on ``costs`` (uint8, the grid)."""
        while self._route and math.dist(position, self._route[0]) <= self.config.arrive_m:
            self._route.pop(0)
        if not self._route:
            return Command("idle")
        target = self._route[0]
        if self._recovery is not None and self._recovery.phase == "rotate":
            if stamp - self._recovery.since < self.config.rotate_s:
                return Command("rotate", reason=self._recovery.reason)
            self._record(stamp, "replan", "turned in place to look again")
        result, path = self._plan(position, target, costs)
        if result.found:
            if self._recovery is not None:
                self._record(stamp, "resume", f"path to {_fmt(target)} found")
                self._recovery = None
            return Command("follow", path=tuple(path))
        return self._blocked(stamp, position, target, costs)

    def _plan(self, start: Point, goal: Point, costs: np.ndarray) -> tuple[PlanResult, list]:
        """Plan on ``costs`` with the unit's own footprint cleared: other units' scans
        paint its body (and its inflation) into the shared map, and a unit must be able to
        leave where it stands (as Nav2 clears the robot footprint). Returns the plan and
        the path to drive: the plan's line-of-sight shortcuts (``smooth_path``)."""
        if not costs.flags.writeable:
            costs = costs.copy()
        window, saved = self._clear_footprint(start, costs)
        try:
            self.last_plan = self.planner.plan(
                costs, start, goal, "astar", self.config.allow_unknown
            )
            path = smooth_path(self.last_plan.path, costs, self.geometry)
        finally:
            costs[window] = saved
        return self.last_plan, path

    def _clear_footprint(
        self, at: Point, costs: np.ndarray
    ) -> tuple[tuple[slice, slice], np.ndarray]:
        g = self.geometry
        reach = int(math.ceil(self.footprint_m / g.resolution))
        col, row = g.world_to_cell(*at)
        rows = slice(max(row - reach, 0), min(row + reach + 1, g.height))
        cols = slice(max(col - reach, 0), min(col + reach + 1, g.width))
        window = (rows, cols)
        saved = costs[window].copy()
        rr, cc = np.ogrid[rows, cols]
        inside = (rr - row) ** 2 + (cc - col) ** 2 <= reach * reach
        part = costs[window]
        part[inside & (part != UNKNOWN)] = FREE
        return window, saved

    def _blocked(self, stamp: float, position: Point, target: Point, costs: np.ndarray) -> Command:
        reason = f"no path to {_fmt(target)}"
        blocking = self._blocking_points(position, target, costs)
        rec = self._recovery
        if rec is None:
            self._recovery = _Recovery("wait", stamp, self.config.wait_s, reason, blocking)
            self._record(stamp, "wait", reason, blocking)
        elif rec.phase == "wait" and stamp - rec.since >= rec.wait_s:
            rec.phase, rec.since = "rotate", stamp
            self._record(stamp, "rotate", f"{reason} after waiting {rec.wait_s:g} s", blocking)
            return Command("rotate", reason=reason, blocking=blocking)
        elif rec.phase == "rotate":  # turned and replanned: still nothing
            new_route = self.reroute(self.unit_id, position) if self.reroute else None
            wait_s = min(rec.wait_s * 2.0, self.config.max_wait_s)
            if new_route:
                self._record(stamp, "reroute", f"{reason} after looking again", blocking)
                self._route = [(float(x), float(y)) for x, y in new_route]
                self._recovery = _Recovery("wait", stamp, wait_s, reason, blocking)
            else:
                self._record(stamp, "wait", f"{reason}; no other route", blocking)
                self._recovery = _Recovery("wait", stamp, wait_s, reason, blocking)
        return Command("stop", reason=reason, blocking=blocking)

    def _blocking_points(
        self, position: Point, target: Point, costs: np.ndarray
    ) -> tuple[Point, ...]:
        (report,) = query_segments(self.geometry, costs, [(*position, *target)])
        return (tuple(report.first_blocked),) if report.first_blocked else ()

    def _record(
        self, stamp: float, action: str, cause: str, blocking: tuple[Point, ...] = ()
    ) -> None:
        self.actions.append(Action(self.unit_id, stamp, action, cause, blocking))


def _fmt(point: Point) -> str:
    return f"({point[0]:.2f}, {point[1]:.2f})"
