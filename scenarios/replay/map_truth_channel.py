"""The replay's map-against-truth metrics channel: topic ``/metrics/map_truth``, schema
``fleetmap.MapTruth`` (JSON schema, fleetmap's own: Foxglove has no metrics type; its
Plot panel plots any numeric field, e.g. ``/metrics/map_truth.phantom_cells``), one
message per map read (``record.map_truth``, ``scenarios.score.map_truth``)::

    {"timestamp": {"sec": 12, "nsec": 500000000},
     "phantom_cells": 31, "forgotten_cells": 0, "unknown_share": 0.0421}

``timestamp``: the read's sim time; cells are counts; ``unknown_share`` in [0, 1].
"""

from __future__ import annotations

from typing import Any, Final

from scenarios.replay.foxglove_messages import foxglove_time, stamp_ns
from scenarios.replay.foxglove_schemas import TIME
from scenarios.run.record import MapTruthSample

MAP_TRUTH_TOPIC: Final = "/metrics/map_truth"
MAP_TRUTH_SCHEMA: Final = "fleetmap.MapTruth"

_COUNT: Final = {"type": "integer", "minimum": 0}
SCHEMA: Final[dict[str, Any]] = {
    "title": MAP_TRUTH_SCHEMA,
    "type": "object",
    "properties": {
        "timestamp": TIME,
        "phantom_cells": _COUNT,
        "forgotten_cells": _COUNT,
        "unknown_share": {"type": "number", "minimum": 0, "maximum": 1},
    },
    "required": ["timestamp", "phantom_cells", "forgotten_cells", "unknown_share"],
}


def map_truth_message(sample: MapTruthSample) -> dict[str, Any]:
    """One read's message (module docstring)."""
    return {
        "timestamp": foxglove_time(stamp_ns(sample.stamp)),
        "phantom_cells": int(sample.phantom_cells),
        "forgotten_cells": int(sample.forgotten_cells),
        "unknown_share": float(sample.unknown_share),
    }
