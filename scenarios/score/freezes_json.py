"""``freezes.json``: every freeze of a run, with the evidence that explains it.

A JSON list, one object per freeze, ordered by start time then unit, keys in this order::

    {"unit": "u5", "start": 35.8, "duration": 71.3, "phantom": true, "true_block": true,
     "phantom_s": 47.1, "true_block_s": 24.2,
     "segments": [
        {"start": 35.8, "end": 60.0, "kind": "true_block",
         "cause": "no lane route on ground truth"},
        {"start": 60.0, "end": 107.1, "kind": "phantom",
         "cause": "ground truth has a lane route (pod-9 moved at 60 s)"}],
     "reason": "no lane to (33.00, 16.33)",
     "position": {"x": 12.4, "y": 3.1},
     "lanes": [],
     "blocking_cells": [
        {"x": 12.875, "y": 3.125, "truly_occupied": false, "p_occ": 0.9241,
         "last_observed": 38.75, "marked_by": [{"unit": "u1", "stamp": 38.75}],
         "held_by": []}],
     "recovery": [{"stamp": 42.25, "action": "turn_in_place", "cause": "path blocked"}]}

Units: times [s] of sim time, positions [m] in the map frame. ``segments``: the freeze's
time split by what ground truth said (docs/freezes.md; ``planner.freeze``): ``phantom``
while the planner that froze the unit (the grid planner for a path freeze, the lane
router for a lane freeze) finds a way on the ground-truth costmap of the moment,
``true_block`` while it does not; ``cause`` says what it found and the world change that
began the segment. ``phantom_s``/``true_block_s`` sum them; ``phantom``/``true_block``:
the freeze has some seconds of that kind (a freeze at a pod that is moved away while
the unit waits has both). ``p_occ`` and ``last_observed`` are null for a cell never
observed.
``marked_by``: the scans (unit, stamp) that last marked the cell occupied. ``held_by``:
for a cell that blocked by inflation (cost INSCRIBED: free or unknown itself, within the
inscribed radius of an occupied cell), the LETHAL cells within that radius, nearest
first, at most 3, each an object of these keys (its own ``held_by`` empty): their
evidence is what held the unit (``scenarios.score.inscribing``); ``[]`` for a LETHAL
cell.
``lanes``: for a lane freeze (the lane coordinator had no lane for the unit: "no lane
to ...", "stranded on a blocked lane"), the blocked lanes that held it, each ``[a, b]``
(its node ids, sorted; ``scenarios.score.lane_evidence`` says which), and then
``blocking_cells`` are those lanes' first blocked cells; ``[]`` for a path freeze.
Times and positions are rounded to 1 ms and 1 mm, probabilities to 1e-4.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from mapserver.store.atomic import write_json
from planner.freeze import PHANTOM, TRUE_BLOCK, Segment
from scenarios.run.record import BlockingCell, FreezeRecord, RecoveryStep, RunRecord

TIME_DECIMALS = 3  # [s] 1 ms
LENGTH_DECIMALS = 3  # [m] 1 mm
PROBABILITY_DECIMALS = 4


def write_freezes(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Write ``record``'s freezes to ``path`` (``freezes.json``) atomically; returns the path."""
    freezes = sorted(record.freezes, key=lambda f: (f.start, f.unit_id))
    return write_json(path, [freeze_to_dict(f) for f in freezes])


def freeze_to_dict(freeze: FreezeRecord) -> dict[str, Any]:
    """One freeze as its ``freezes.json`` object (see the module docstring)."""
    return {
        "unit": freeze.unit_id,
        "start": _round(freeze.start, TIME_DECIMALS),
        "duration": _round(freeze.duration, TIME_DECIMALS),
        "phantom": freeze.phantom,
        "true_block": freeze.true_block,
        "phantom_s": _round(freeze.seconds(PHANTOM), TIME_DECIMALS),
        "true_block_s": _round(freeze.seconds(TRUE_BLOCK), TIME_DECIMALS),
        "segments": [_segment(s) for s in freeze.segments],
        "reason": freeze.reason,
        "position": _position(freeze.x, freeze.y),
        "lanes": [[a, b] for a, b in freeze.lanes],
        "blocking_cells": [_cell(c) for c in freeze.blocking],
        "recovery": [_step(s) for s in freeze.recovery],
    }


def _segment(segment: Segment) -> dict[str, Any]:
    return {
        "start": _round(segment.start, TIME_DECIMALS),
        "end": _round(segment.end, TIME_DECIMALS),
        "kind": segment.kind,
        "cause": segment.cause,
    }


def _cell(cell: BlockingCell) -> dict[str, Any]:
    return {
        **_position(cell.x, cell.y),
        "truly_occupied": bool(cell.truly_occupied),
        "p_occ": _round(cell.p_occ, PROBABILITY_DECIMALS),
        "last_observed": _round(cell.last_observed, TIME_DECIMALS),
        "marked_by": [
            {"unit": unit, "stamp": _round(stamp, TIME_DECIMALS)} for unit, stamp in cell.marked_by
        ],
        "held_by": [_cell(source) for source in cell.held_by],
    }


def _step(step: RecoveryStep) -> dict[str, Any]:
    return {
        "stamp": _round(step.stamp, TIME_DECIMALS),
        "action": step.action,
        "cause": step.cause,
    }


def _position(x: float, y: float) -> dict[str, float | None]:
    return {"x": _round(x, LENGTH_DECIMALS), "y": _round(y, LENGTH_DECIMALS)}


def _round(value: float | None, decimals: int) -> float | None:
    """``value`` rounded; None (JSON null) for None and for NaN or infinities."""
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), decimals)
