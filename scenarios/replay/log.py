"""The replay's log lines: what happened in a run, in sentences for people, one
``LogLine`` per scenario event, freeze, recovery action, unsafe plan (stale-free or
inscribed) and collision incident.

A freeze is logged at its start with everything that explains it: its phantom and
true-block seconds and each segment with its cause, the blocked lanes of a lane freeze,
each blocking cell with its ground truth, p_occ, last_observed and the scans that last
marked it, and the recovery actions taken. A collision incident is logged when it began,
under the unit's name: what it touched, where, its cause (an ERROR when the fleet drove
into it, a WARNING when the scenario moved something onto the unit; ``fleet.sim``), how
long and how many contacts (when known: the live stream logs it at its first contact),
and what the map held where it touched when the unit planned. Positions [m], times [s]
of sim time.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

from planner.freeze import PHANTOM, TRUE_BLOCK
from scenarios.replay.foxglove_messages import ERROR, INFO, WARNING
from scenarios.run.record import BlockingCell, EventRecord, FreezeRecord, PlanSample, RunRecord
from scenarios.score.incidents import CollisionIncident

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
    lines.extend(unsafe_plan_line(p) for p in record.plans if p.stale_free or p.inscribed)
    lines.extend(incident_line(i) for i in record.incidents)
    return sorted(lines, key=lambda line: line.stamp)


def event_line(event: EventRecord) -> LogLine:
    text = f"{event.kind} {event.object_id} at {_xy(event.x, event.y)}: {event.detail}"
    return LogLine(event.stamp, INFO, SCENARIO_NAME, text)


def freeze_line(freeze: FreezeRecord) -> LogLine:
    """A freeze with phantom seconds is a WARNING (the map, not the world, stopped the unit
    for a while); one that is a true block throughout is INFO."""
    phantom, true = freeze.seconds(PHANTOM), freeze.seconds(TRUE_BLOCK)
    verdict = (
        f"PHANTOM freeze ({phantom:.2f} s phantom, {true:.2f} s true block)"
        if freeze.phantom
        else "true-block freeze (ground truth is blocked too)"
    )
    parts = [f"{verdict} for {freeze.duration:.2f} s at {_xy(freeze.x, freeze.y)}: {freeze.reason}"]
    parts += [
        f"{s.start:.2f}-{s.end:.2f} s {s.kind.replace('_', ' ')}: {s.cause}"
        for s in freeze.segments
    ]
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


def unsafe_plan_line(plan: PlanSample) -> LogLine:
    """A plan through a truly lethal cell (stale-free) or, short of that, through truly
    inscribed ones (the unit's body would touch an obstacle): a WARNING."""
    if plan.stale_free:
        head, cells, what = "stale-free plan", plan.stale_cells, "lethal"
    else:
        head = "inscribed plan (the unit's body would touch an obstacle)"
        cells, what = plan.inscribed_cells, "inscribed"
    text = (
        f"{head}: the path crosses {len(cells)} cell(s) {what} in ground truth, "
        f"first at {_xy(*cells[0])}"
    )
    return LogLine(plan.stamp, WARNING, plan.unit_id, text)


def incident_line(incident: CollisionIncident) -> LogLine:
    """A collision incident the fleet caused is an ERROR, one the scenario caused a
    WARNING."""
    why = (
        "scenario: it was moved onto the unit"
        if incident.cause == "scenario"
        else "fleet: the fleet's driving made the contact"
    )
    text = (
        f"COLLISION at {_xy(incident.x, incident.y)}: touched {incident.other_kind} "
        f"{incident.other_id} (cause: {why})"
    )
    if incident.contacts > 1 or incident.duration > 0:
        text += f"; {incident.contacts} contacts over {incident.duration:.2f} s"
    plan = incident.plan
    if plan is not None and plan.cells:
        held = Counter(c.map for c in plan.cells)
        truth = Counter(c.truth for c in plan.cells)
        text += (
            f"\nplanned at {plan.stamp:.2f} s on map version {plan.map_version}; where it "
            f"touched the map held {_counts(held)}, ground truth {_counts(truth)}"
        )
    level = WARNING if incident.cause == "scenario" else ERROR
    return LogLine(incident.start, level, incident.unit_id, text)


def _counts(counter: Counter) -> str:
    return ", ".join(f"{n} {name}" for name, n in sorted(counter.items()))


def _cell(cell: BlockingCell) -> str:
    truth = "occupied" if cell.truly_occupied else "free"
    p_occ = "unknown" if cell.p_occ is None else f"{cell.p_occ:.2f}"
    seen = "never" if cell.last_observed is None else f"{cell.last_observed:.2f} s"
    marked = ", ".join(f"{unit}@{stamp:.2f}" for unit, stamp in cell.marked_by) or "no scan"
    text = f"{_xy(cell.x, cell.y)} truth {truth}, p_occ {p_occ}, seen {seen}, marked by {marked}"
    if cell.held_by:
        text += " (inscribed by " + "; ".join(_cell(c) for c in cell.held_by) + ")"
    return text


def _xy(x: float, y: float) -> str:
    return f"({x:.2f}, {y:.2f})"
