"""The replay's run-metrics channel: topic ``/metrics``, schema ``fleetmap.RunMetrics`` (JSON
schema, fleetmap's own; Foxglove's Plot panel plots any numeric field, e.g.
``/metrics.phantom_freezes``), one message per counters sample (``record.counters``: every
map read and at the run's end, ``scenarios.run.observers.CountersRecorder``)::

    {"timestamp": {"sec": 12, "nsec": 500000000},
     "tasks_completed": 3, "frozen_units": 1, "stale_free_plans": 0,
     "collisions": 0, "scenario_collisions": 0, "events": 2,
     "phantom_freezes": 1, "phantom_freeze_seconds": 4.2, "true_block_freezes": 0}

Every count is as it stood at ``timestamp`` (sim time). The last three are the freezes'
verdicts, known only once the run is scored (a freeze is judged phantom or true by
planning on ground truth over its time, ``planner.freeze.classify``): the replay has them,
counting the freezes that began by ``timestamp`` and the seconds of phantom freezes up to
it; the live stream (``fleetmap run --foxglove``) leaves them out. The last message of a
replay holds the values of ``metrics.json`` (``tasks_completed``, ``phantom_freezes``,
``phantom_freeze_seconds``, ``true_block_freezes``, ``stale_free_plans``, ``collisions``,
``scenario_collisions``, ``events``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from scenarios.replay.foxglove_messages import foxglove_time, stamp_ns
from scenarios.replay.foxglove_schemas import TIME
from scenarios.run.record import CountersSample, FreezeRecord

METRICS_TOPIC: Final = "/metrics"
METRICS_SCHEMA: Final = "fleetmap.RunMetrics"
SECONDS_DECIMALS: Final = 3  # as metrics.json

COUNTS: Final = (
    "tasks_completed", "frozen_units", "stale_free_plans", "collisions",
    "scenario_collisions", "events",
)  # fmt: skip
VERDICTS: Final = ("phantom_freezes", "phantom_freeze_seconds", "true_block_freezes")

_COUNT: Final = {"type": "integer", "minimum": 0}
SCHEMA: Final[dict[str, Any]] = {
    "title": METRICS_SCHEMA,
    "type": "object",
    "properties": {
        "timestamp": TIME,
        **{name: _COUNT for name in COUNTS},
        "phantom_freezes": _COUNT,
        "phantom_freeze_seconds": {"type": "number", "minimum": 0},
        "true_block_freezes": _COUNT,
    },
    "required": ["timestamp", *COUNTS],
}


def metrics_message(
    sample: CountersSample, freezes: Sequence[FreezeRecord] | None = None
) -> dict[str, Any]:
    """One sample's message; with the run's scored ``freezes`` (None: not scored yet) the
    verdicts as they stood at the sample (module docstring)."""
    message: dict[str, Any] = {"timestamp": foxglove_time(stamp_ns(sample.stamp))}
    message.update((name, int(getattr(sample, name))) for name in COUNTS)
    if freezes is not None:
        begun = [f for f in freezes if f.start <= sample.stamp]
        phantom = [f for f in begun if f.phantom]
        seconds = sum(min(f.duration, sample.stamp - f.start) for f in phantom)
        message["phantom_freezes"] = len(phantom)
        message["phantom_freeze_seconds"] = round(seconds, SECONDS_DECIMALS)
        message["true_block_freezes"] = len(begun) - len(phantom)
    return message
