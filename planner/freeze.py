"""Freezes, as CONTRACT section 3 defines them, and how they are classified.

- A *freeze*: a unit with a task commands no motion for at least ``MIN_FREEZE_S`` (1 s)
  because no admissible path or lane was available. Standing still for any other reason
  (loading at a station, waiting for a granted lane to clear) is not a freeze.
- A *phantom* freeze: during the freeze, the same planner finds a path on the
  ground-truth costmap (the true geometry rasterised and inflated as the server does).
  Otherwise the freeze is a *true block*.
- A *stale-free plan*: a plan whose path crosses a cell that is lethal in ground truth.

``FreezeDetector`` is fed one observation per unit per tick and reports each freeze once
it ends (or when the run ends), with the reason and the blocking cells its unit reported.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from mapserver.costvalues import LETHAL
from mapserver.geometry import GridGeometry

MIN_FREEZE_S = 1.0  # [s] CONTRACT 3


@dataclass(frozen=True)
class UnitObservation:
    """One unit at one tick: does it have a task, does it command motion, and if not
    because nothing admissible was found, why (``blocked_reason``) and which cells
    (world points [m]) blocked it."""

    unit_id: str
    stamp: float
    has_task: bool
    moving: bool
    blocked_reason: str | None = None
    blocking_points: tuple[tuple[float, float], ...] = ()
    goal: tuple[float, float] | None = None
    position: tuple[float, float] | None = None


@dataclass
class Freeze:
    """A freeze of ``unit_id`` from ``start`` to ``end`` [s]; ``phantom`` once classified."""

    unit_id: str
    start: float
    end: float
    reason: str
    position: tuple[float, float] | None
    goal: tuple[float, float] | None
    blocking_points: list[tuple[float, float]] = field(default_factory=list)
    phantom: bool | None = None

    @property
    def duration(self) -> float:
        """[s]"""
        return self.end - self.start


class FreezeDetector:
    """Tracks, per unit, the run of ticks in which it is blocked with a task."""

    def __init__(self, min_freeze_s: float = MIN_FREEZE_S) -> None:
        if not min_freeze_s > 0:
            raise ValueError(f"min_freeze_s must be positive, got {min_freeze_s!r}")
        self.min_freeze_s = min_freeze_s
        self._open: dict[str, Freeze] = {}
        self.freezes: list[Freeze] = []

    def observe(self, obs: UnitObservation) -> Freeze | None:
        """Feed one observation; returns a freeze that just ended (>= the minimum)."""
        blocked = obs.has_task and not obs.moving and obs.blocked_reason is not None
        current = self._open.get(obs.unit_id)
        if blocked:
            if current is None:
                self._open[obs.unit_id] = Freeze(
                    obs.unit_id, obs.stamp, obs.stamp, obs.blocked_reason, obs.position,
                    obs.goal, list(obs.blocking_points),
                )  # fmt: skip
            else:
                current.end = obs.stamp
                for point in obs.blocking_points:
                    if point not in current.blocking_points:
                        current.blocking_points.append(point)
            return None
        if current is None:
            return None
        del self._open[obs.unit_id]
        current.end = obs.stamp
        return self._keep(current)

    def finish(self, stamp: float) -> list[Freeze]:
        """End every open run at ``stamp`` [s] (the run's end); returns the freezes."""
        ended = []
        for unit_id in sorted(self._open):
            current = self._open.pop(unit_id)
            current.end = stamp
            kept = self._keep(current)
            if kept is not None:
                ended.append(kept)
        return ended

    def _keep(self, freeze: Freeze) -> Freeze | None:
        if freeze.duration < self.min_freeze_s:
            return None
        self.freezes.append(freeze)
        return freeze


def classify(
    freeze: Freeze,
    truth_costs_at: Callable[[float], np.ndarray],
    plan: Callable[[np.ndarray, tuple[float, float], tuple[float, float]], bool],
    samples: int = 3,
) -> bool:
    """Phantom or not: does ``plan(truth_costs, position, goal)`` succeed at some moment of
    the freeze (``samples`` evenly spaced stamps, start and end included)?"""
    if freeze.position is None or freeze.goal is None:
        freeze.phantom = False
        return False
    stamps = np.linspace(freeze.start, freeze.end, max(samples, 2))
    freeze.phantom = any(plan(truth_costs_at(t), freeze.position, freeze.goal) for t in stamps)
    return freeze.phantom


def stale_free_cells(
    path: Sequence[tuple[float, float]], truth_costs: np.ndarray, geometry: GridGeometry
) -> list[tuple[float, float]]:
    """The points of ``path`` [m] that lie on cells LETHAL in ground truth (empty: the plan
    is not stale-free)."""
    if not path:
        return []
    cols, rows, inside = geometry.points_to_cells(np.asarray(path, dtype=np.float64))
    hits = np.zeros(len(path), dtype=bool)
    hits[inside] = truth_costs[rows[inside], cols[inside]] == LETHAL
    return [tuple(p) for p, hit in zip(path, hits.tolist(), strict=True) if hit]
