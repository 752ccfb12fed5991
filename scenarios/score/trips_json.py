"""``trips.json``: every completed trip of a run, in completion order, then every trip
returned to the queue and not completed by the end (``scenarios.run.trip_queue``).

A JSON list, one object per trip, keys in this order::

    {"task": "t3", "unit": "u2", "assigned": 12.4, "done": 47.9, "ideal_s": 28.733,
     "actual_s": 35.5,
     "attempts": [{"unit": "u1", "start": 0.1, "end": 12.3, "outcome": "returned",
                   "cause": "no_route"},
                  {"unit": "u2", "start": 12.4, "end": 47.9, "outcome": "completed",
                   "cause": null}]}

Times [s] of sim time, rounded to 1 ms. ``unit``, ``assigned``, ``done``, ``ideal_s`` and
``actual_s`` are those of the attempt that completed the trip; ``ideal_s``: its
congestion-free time from where that attempt started (``scenarios.score.throughput``,
docs/throughput.md), null when the lane graph has no route for it; ``actual_s = done -
assigned``. An unfinished trip has them all null. ``attempts``: every unit's go at the
trip in order, ``outcome`` ``completed``, ``returned`` (with its ``cause``: ``no_route``
or ``goal_blocked``) or ``open`` (still under way at the end: ``end`` null).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from mapserver.store.atomic import write_json
from scenarios.run.record import Attempt, RunRecord, TripRecord, UnfinishedTrip

TIME_DECIMALS = 3  # [s] 1 ms


def write_trips(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Write ``record``'s trips to ``path`` (``trips.json``) atomically; returns the path."""
    trips = [trip_to_dict(t) for t in record.trips]
    return write_json(path, trips + [unfinished_to_dict(t) for t in record.unfinished_trips])


def trip_to_dict(trip: TripRecord) -> dict[str, Any]:
    """One completed trip as its ``trips.json`` object (see the module docstring)."""
    return {
        "task": trip.task_id,
        "unit": trip.unit_id,
        "assigned": _time(trip.assigned),
        "done": _time(trip.done),
        "ideal_s": _time(trip.ideal_s),
        "actual_s": _time(trip.actual_s),
        "attempts": [attempt_to_dict(a) for a in trip.attempts],
    }


def unfinished_to_dict(trip: UnfinishedTrip) -> dict[str, Any]:
    """One unfinished, returned trip as its ``trips.json`` object."""
    empty = dict.fromkeys(("unit", "assigned", "done", "ideal_s", "actual_s"))
    return {"task": trip.task_id, **empty, "attempts": [attempt_to_dict(a) for a in trip.attempts]}


def attempt_to_dict(attempt: Attempt) -> dict[str, Any]:
    """One attempt as an object of ``attempts``."""
    return {
        "unit": attempt.unit_id,
        "start": _time(attempt.start),
        "end": _time(attempt.end),
        "outcome": attempt.outcome,
        "cause": attempt.cause,
    }


def _time(seconds: float | None) -> float | None:
    return None if seconds is None else round(seconds, TIME_DECIMALS)
