"""The replay's log lines: what happened in a run, in sentences for people, one
``LogLine`` per scenario event, freeze, recovery action, stale-free plan and collision.

A freeze is logged at its start with everything that explains it: phantom or true block,
its cause, the blocked lanes of a lane freeze, each blocking cell with its ground truth,
p_occ, last_observed and the scans that last marked it, and the recovery actions taken.
A collision is logged when it began, under the unit's name: what it touched, where, and
its cause (an ERROR when the fleet drove into it, a WARNING when the scenario moved
something onto the unit; ``fleet.sim``). Positions [m], times [s] of sim time.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from scenarios.replay.foxglove_messages import ERROR, INFO, WARNING
from scenarios.run.record import BlockingCell, EventRecord, FreezeRecord, PlanSample, RunRecord

if TYPE_CHECKING:
    from fleet.sim import CollisionEvent  # imports pybullet

SCENARIO_NAME = "scenario"
"""The ``name`` of the lines about world events (lines about a unit carry its id)."""


@dataclass(frozen=True)
class LogLine:
    """One line: stamp [s], Foxglove log level, source name, message."""

    stamp: float
    level: int
    name: str
    message: str


def run_log(record: RunRecord) -> list[LogLine]:
    """Every line of ``record``, ordered by stamp (ties in the order listed above)."""
    lines = [event_line(e) for e in record.events]
    for freeze in record.freezes:
        lines.append(freeze_line(freeze))
        lines.extend(
            LogLine(s.stamp, INFO, freeze.unit_id, f"recovery: {s.action} (cause: {s.cause})")
            for s in freeze.recovery
        )
    lines.extend(stale_plan_line(p) for p in record.plans if p.stale_free)
    lines.extend(collision_line(c) for c in record.collisions)
    return sorted(lines, key=lambda line: line.stamp)


def event_line(event: EventRecord) -> LogLine:
    text = f"{event.kind} {event.object_id} at {_xy(event.x, event.y)}: {event.detail}"
    return LogLine(event.stamp, INFO, SCENARIO_NAME, text)


def freeze_line(freeze: FreezeRecord) -> LogLine:
    """A phantom freeze is a WARNING (the map, not the world, stopped the unit); a true
    block is INFO."""
    verdict = (
        "PHANTOM freeze (ground truth has a path)"
        if freeze.phantom
        else "true-block freeze (ground truth is blocked too)"
    )
    parts = [f"{verdict} for {freeze.duration:.2f} s at {_xy(freeze.x, freeze.y)}: {freeze.reason}"]
    if freeze.lanes:
        lanes = ", ".join(f"{a}-{b}" for a, b in freeze.lanes)
        parts.append(f"blocked lanes ({len(freeze.lanes)}): {lanes}")
    parts += [
        f"blocking cells ({len(freeze.blocking)}): "
        + ("; ".join(_cell(c) for c in freeze.blocking) or "none recorded"),
        "recovery: "
        + (", ".join(f"{s.action} at {s.stamp:.2f} s" for s in freeze.recovery) or "none"),
    ]
    return LogLine(
        freeze.start, WARNING if freeze.phantom else INFO, freeze.unit_id, "\n".join(parts)
    )


def stale_plan_line(plan: PlanSample) -> LogLine:
    first = plan.stale_cells[0]
    text = (
        f"stale-free plan: the path crosses {len(plan.stale_cells)} point(s) lethal in "
        f"ground truth, first at {_xy(*first)}"
    )
    return LogLine(plan.stamp, WARNING, plan.unit_id, text)


def collision_line(event: CollisionEvent) -> LogLine:
    """A collision the fleet caused is an ERROR, one the scenario caused a WARNING."""
    why = (
        "scenario: it was moved onto the unit"
        if event.cause == "scenario"
        else "fleet: the fleet's driving made the contact"
    )
    text = (
        f"COLLISION at {_xy(event.x, event.y)}: touched {event.other_kind} {event.other_id} "
        f"(cause: {why})"
    )
    level = WARNING if event.cause == "scenario" else ERROR
    return LogLine(event.time, level, event.unit_id, text)


def _cell(cell: BlockingCell) -> str:
    truth = "occupied" if cell.truly_occupied else "free"
    p_occ = "unknown" if cell.p_occ is None else f"{cell.p_occ:.2f}"
    seen = "never" if cell.last_observed is None else f"{cell.last_observed:.2f} s"
    marked = ", ".join(f"{unit}@{stamp:.2f}" for unit, stamp in cell.marked_by) or "no scan"
    return f"{_xy(cell.x, cell.y)} truth {truth}, p_occ {p_occ}, seen {seen}, marked by {marked}"


def _xy(x: float, y: float) -> str:
    return f"({x:.2f}, {y:.2f})"
