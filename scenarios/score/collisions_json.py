"""``collisions.json``: every collision incident of a run, with what the map held where the
unit touched.

A JSON list, one object per incident (``scenarios.score.incidents``: the contacts of one
unit with one thing, of one cause, no more than 2 s apart), in start order (ties: the
sim's order), keys in this order::

    {"unit": "u4", "other": "rack-1", "other_kind": "rack", "cause": "fleet",
     "start": 108.3, "end": 179.9, "duration": 71.6, "contacts": 121,
     "position": {"x": 19.129, "y": 5.059},
     "plan": {"stamp": 108.0, "map_version": 412,
              "contact_cells": [{"x": 19.15, "y": 4.65, "map": "free", "truth": "lethal"}]}}

``other``: the obstacle or unit touched (``other_kind`` "unit" for a unit; a contact
between two units is an incident for each of them). ``cause``: ``"fleet"`` when the
unit's (or the other unit's) driving made the contact, ``"scenario"`` when the unit
already overlapped the other thing at the step's start: something was dropped or moved
onto it, a person walked into it (``fleet.sim``). ``start``/``end``: its first contact
and its last step in contact; ``contacts``: the contacts begun in it. ``position``: the
unit's true centre at its first contact (put back to the first touch along its step;
where it stood for a scenario contact). ``plan``: the path the unit was driving then,
planned at ``stamp`` on the costmap of ``map_version``, and the cells where it touched
with their cost class (``free``, ``inflated``, ``inscribed``, ``lethal``, ``unknown``)
in that costmap (``map``) and in ground truth at ``stamp`` (``truth``); null when the
unit had not planned. Times [s] of sim time rounded to 1 ms, positions [m] in the map
frame to 1 mm.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from mapserver.store.atomic import write_json
from scenarios.run.record import RunRecord
from scenarios.score.incidents import CollisionIncident, PlanContext

TIME_DECIMALS = 3  # [s] 1 ms
LENGTH_DECIMALS = 3  # [m] 1 mm


def write_collisions(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Write ``record``'s incidents to ``path`` (``collisions.json``) atomically; returns
    the path."""
    incidents = sorted(record.incidents, key=lambda i: i.start)  # stable: the sim's order
    return write_json(path, [incident_to_dict(i) for i in incidents])


def incident_to_dict(incident: CollisionIncident) -> dict[str, Any]:
    """One incident as its ``collisions.json`` object (see the module docstring)."""
    return {
        "unit": incident.unit_id,
        "other": incident.other_id,
        "other_kind": incident.other_kind,
        "cause": incident.cause,
        "start": _time(incident.start),
        "end": _time(incident.end),
        "duration": _time(incident.duration),
        "contacts": incident.contacts,
        "position": _xy(incident.x, incident.y),
        "plan": None if incident.plan is None else _plan(incident.plan),
    }


def _plan(plan: PlanContext) -> dict[str, Any]:
    return {
        "stamp": _time(plan.stamp),
        "map_version": plan.map_version,
        "contact_cells": [{**_xy(c.x, c.y), "map": c.map, "truth": c.truth} for c in plan.cells],
    }


def _time(value: float) -> float:
    return round(float(value), TIME_DECIMALS)


def _xy(x: float, y: float) -> dict[str, float]:
    return {"x": round(float(x), LENGTH_DECIMALS), "y": round(float(y), LENGTH_DECIMALS)}
