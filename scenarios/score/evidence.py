"""A freeze with its evidence, for ``freezes.json`` and the replay: the blocking cells
(ground truth, p_occ, last_observed, the scans that last observed them, and the LETHAL
cells that inscribe an INSCRIBED one, with the same evidence), the blocked
lanes of a lane freeze (``scenarios.score.lane_evidence`` names them and their cells) and the
recovery actions the unit and the coordinator took meanwhile."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from fleet.ground_truth import GroundTruth
from planner.coordinator import LaneCoordinator
from planner.decisions import Action
from planner.freeze import Freeze
from scenarios.run.record import BlockingCell, FreezeRecord, RecoveryStep

TRAFFIC = frozenset({Action.ROUTE, Action.GRANT, Action.WAIT, Action.ARRIVED})
"""Coordinator actions of ordinary traffic, not recovery: a freeze's evidence leaves
them out."""

# (unit_id, point) -> (stamp [s] read, mapserver.client.CellOut), or a list of such
# readings (one per freeze that named the point; the one read during a freeze is its)
Reading = tuple[float, object]
Evidence = Mapping[tuple[str, tuple[float, float]], Reading | Sequence[Reading]]
# stamp [s] -> [(unit_id, x, y, range_max)] of the scans taken then
ScanIndex = Mapping[float, Sequence[tuple[str, float, float, float]]]
# (unit_id, point) -> [(stamp [s] read, the LETHAL cells that inscribed it then)]
HeldBy = Mapping[tuple[str, tuple[float, float]], Sequence[tuple[float, tuple]]]


def freeze_records(
    freezes: Sequence[Freeze],
    agents: Mapping[str, object],
    coordinator: LaneCoordinator,
    truth: GroundTruth,
    evidence: Evidence,
    scans: ScanIndex,
    held_by: HeldBy | None = None,
) -> list[FreezeRecord]:
    """One FreezeRecord per classified freeze, in start order; ``held_by`` names the
    LETHAL cells behind each INSCRIBED blocking cell (none when not given)."""
    records = []
    for freeze in sorted(freezes, key=lambda f: (f.start, f.unit_id)):
        cells = tuple(
            _blocking_cell(freeze, point, evidence, truth, scans, _sources(freeze, point, held_by))
            for point in freeze.blocking_points
        )
        x, y = freeze.position or (math.nan, math.nan)
        records.append(
            FreezeRecord(
                unit_id=freeze.unit_id,
                start=freeze.start,
                duration=freeze.duration,
                segments=tuple(freeze.segments),
                reason=freeze.reason,
                x=x,
                y=y,
                blocking=cells,
                recovery=_recovery(freeze, agents[freeze.unit_id], coordinator),
                lanes=tuple(freeze.lanes),
            )
        )
    return records


def _reading(freeze: Freeze, point, evidence: Evidence | HeldBy) -> Reading:
    """The map's reading of ``point`` for this freeze: the first one taken during it, else
    the last one before it (a single reading is used as it is). ``held_by``'s readings
    are chosen the same way."""
    value = evidence[(freeze.unit_id, point)]
    if isinstance(value, tuple):
        return value
    during = [r for r in value if freeze.start <= r[0] <= freeze.end]
    if during:
        return min(during, key=lambda r: r[0])
    before = [r for r in value if r[0] < freeze.start]
    if before:
        return max(before, key=lambda r: r[0])
    return min(value, key=lambda r: r[0])


def _sources(freeze: Freeze, point, held_by: HeldBy | None) -> tuple:
    """The LETHAL cells that inscribed ``point`` when this freeze read it (none known)."""
    if not held_by or (freeze.unit_id, point) not in held_by:
        return ()
    return _reading(freeze, point, held_by)[1]


def _blocking_cell(
    freeze: Freeze, point, evidence: Evidence, truth: GroundTruth, scans: ScanIndex, sources=()
) -> BlockingCell:
    seen_at, info = _reading(freeze, point, evidence)
    truly = bool(truth.is_occupied(np.array([point]), at=seen_at)[0])
    last = info.last_observed
    marked_by: tuple[tuple[str, float], ...] = ()
    if last is not None:
        marked_by = tuple(
            (uid, last)
            for uid, sx, sy, reach in scans.get(last, ())
            if math.dist((sx, sy), point) <= reach
        )
    held_by = tuple(_blocking_cell(freeze, s, evidence, truth, scans) for s in sources)
    return BlockingCell(point[0], point[1], truly, info.p_occ, last, marked_by, held_by)


def _recovery(freeze: Freeze, agent, coordinator: LaneCoordinator) -> tuple[RecoveryStep, ...]:
    """The unit's navigator actions and the coordinator's decisions about it during the
    freeze (a traffic wait or grant is not a recovery action)."""
    steps = [
        RecoveryStep(a.stamp, a.action, a.cause)
        for a in agent.navigator.actions
        if freeze.start <= a.stamp <= freeze.end and a.action != "route"
    ]
    steps += [
        RecoveryStep(d.time, f"coordinator {d.action}", d.cause)
        for d in coordinator.log
        if d.unit == freeze.unit_id
        and freeze.start <= d.time <= freeze.end
        and d.action not in TRAFFIC
    ]
    return tuple(sorted(steps, key=lambda s: s.stamp))
