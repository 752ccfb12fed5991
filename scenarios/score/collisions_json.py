"""``collisions.json``: every collision of a run, with its evidence; and the counts of
``metrics.json``.

A JSON list, one object per ``fleet.sim.CollisionEvent`` of the run (``RunRecord.
collisions``), in time order (ties: the sim's order, units in spec order), keys in this
order::

    {"time": 41.3, "unit": "u2", "other": "rack-7", "other_kind": "rack",
     "cause": "fleet", "position": {"x": 12.4, "y": 3.1}}

``other``: the obstacle or unit touched (``other_kind`` "unit" for a unit; a contact
between two units is listed once for each of them). ``cause``: ``"fleet"`` when the
unit's (or the other unit's) driving made the contact, ``"scenario"`` when the unit
already overlapped the other thing at the step's start: something was dropped or moved
onto it, a person walked into it (``fleet.sim``). ``position``: the unit's true centre
when it touched (put back to the first touch along its step; where it stood for a
scenario contact). Times [s] of sim time rounded to 1 ms, positions [m] in the map frame
to 1 mm.

Metrics (``collision_counts``): ``collisions`` counts the fleet's (docs/files.md: a score of
the fleet), ``scenario_collisions`` those the scenario caused.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mapserver.store.atomic import write_json
from scenarios.run.record import RunRecord

if TYPE_CHECKING:
    from fleet.sim import CollisionEvent  # imports pybullet

FLEET = "fleet"
SCENARIO = "scenario"
TIME_DECIMALS = 3  # [s] 1 ms
LENGTH_DECIMALS = 3  # [m] 1 mm


def write_collisions(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Write ``record``'s collisions to ``path`` (``collisions.json``) atomically; returns
    the path."""
    events = sorted(record.collisions, key=lambda e: e.time)  # stable: the sim's order
    return write_json(path, [collision_to_dict(e) for e in events])


def collision_to_dict(event: CollisionEvent) -> dict[str, Any]:
    """One collision as its ``collisions.json`` object (see the module docstring)."""
    return {
        "time": round(float(event.time), TIME_DECIMALS),
        "unit": event.unit_id,
        "other": event.other_id,
        "other_kind": event.other_kind,
        "cause": event.cause,
        "position": {
            "x": round(float(event.x), LENGTH_DECIMALS),
            "y": round(float(event.y), LENGTH_DECIMALS),
        },
    }


def collision_counts(record: RunRecord) -> dict[str, int]:
    """``{"collisions": the fleet's, "scenario_collisions": the scenario's}`` of
    ``record.collisions``, for ``metrics.json``. Every event counts (a contact between two
    units counts once for each)."""
    causes = [e.cause for e in record.collisions]
    return {"collisions": causes.count(FLEET), "scenario_collisions": causes.count(SCENARIO)}
