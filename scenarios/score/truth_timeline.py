"""The simulator's ground truth as the freeze classifier reads it
(``planner.freeze.TruthTimeline``): a state at a freeze's start and after each world
change during it (``fleet.ground_truth.GroundTruth.states``), each with the change in
words and, for the true-block causes, what covers a point: ``"lies in tote-1"`` on a
truly lethal cell, ``"lies within the inscribed radius of rack-3"`` on a truly inscribed
one (a unit's centre there puts its body on the obstacle)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence

from fleet.ground_truth import GroundTruth, TruthStep
from fleet.world import Change
from mapserver.core.costvalues import INSCRIBED, LETHAL
from planner.freeze import TruthState, TruthTimeline


def truth_timeline(truth: GroundTruth) -> TruthTimeline:
    """``timeline(start, end)`` [s] over ``truth`` (module docstring)."""

    def timeline(start: float, end: float) -> Iterator[TruthState]:
        for step in truth.states(start, end):
            yield TruthState(step.time, step.costs, describe(step.changes), _where(truth, step))

    return timeline


def describe(changes: Sequence[Change]) -> str:
    """World changes in words: ``"pod-9 moved"``, ``"tote-1 added, tote-2 removed"``."""
    words = []
    for change in changes:
        verb = "added" if change.before is None else "removed" if change.after is None else "moved"
        words.append(f"{change.id} {verb}")
    return ", ".join(words)


def _where(truth: GroundTruth, step: TruthStep) -> Callable[[float, float], str | None]:
    def where(x: float, y: float) -> str | None:
        geometry = truth.geometry
        if not geometry.contains_point(x, y) or not step.obstacles:
            return None
        col, row = geometry.world_to_cell(x, y)
        cost = step.costs[row, col]
        if cost not in (LETHAL, INSCRIBED):
            return None
        nearest = min(step.obstacles.values(), key=lambda o: (float(o.shape.distance(x, y)), o.id))
        if cost == LETHAL:
            return f"lies in {nearest.id}"
        return f"lies within the inscribed radius of {nearest.id}"

    return where
