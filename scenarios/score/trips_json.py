"""``trips.json``: every completed trip of a run, in completion order.

A JSON list, one object per trip, keys in this order::

    {"task": "t3", "unit": "u2", "assigned": 12.4, "done": 47.9, "ideal_s": 28.733,
     "actual_s": 35.5}

Times [s] of sim time, rounded to 1 ms. ``ideal_s``: the trip's congestion-free time
(``scenarios.score.throughput``, docs/throughput.md), null when the lane graph has no route
for it; ``actual_s = done - assigned``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from mapserver.store.atomic import write_json
from scenarios.run.record import RunRecord, TripRecord

TIME_DECIMALS = 3  # [s] 1 ms


def write_trips(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Write ``record``'s trips to ``path`` (``trips.json``) atomically; returns the path."""
    return write_json(path, [trip_to_dict(t) for t in record.trips])


def trip_to_dict(trip: TripRecord) -> dict[str, Any]:
    """One trip as its ``trips.json`` object (see the module docstring)."""
    return {
        "task": trip.task_id,
        "unit": trip.unit_id,
        "assigned": round(trip.assigned, TIME_DECIMALS),
        "done": round(trip.done, TIME_DECIMALS),
        "ideal_s": None if trip.ideal_s is None else round(trip.ideal_s, TIME_DECIMALS),
        "actual_s": round(trip.actual_s, TIME_DECIMALS),
    }
