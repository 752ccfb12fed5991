"""The replay's run-metrics channel: topic ``/metrics``, schema ``fleetmap.RunMetrics`` (JSON
schema, fleetmap's own; Foxglove's Plot panel plots any numeric field, e.g.
``/metrics.phantom_freezes``), one message per counters sample (``record.counters``: every
map read and at the run's end, ``scenarios.run.observers.CountersRecorder``)::

    {"timestamp": {"sec": 12, "nsec": 500000000},
     "tasks_completed": 3, "frozen_units": 1, "stale_free_plans": 0,
     "collisions": 0, "scenario_collisions": 0, "events": 2, "inscribed_plans": 1,
     "phantom_freezes": 1, "phantom_freeze_seconds": 4.2, "true_block_freezes": 1,
     "true_block_seconds": 3.0}

Every count is as it stood at ``timestamp`` (sim time); ``collisions`` and
``scenario_collisions`` count incidents (``scenarios.score.incidents``). The last four
are the freezes' verdicts, known only once the run is scored (a freeze's time is split
into phantom and true-block segments by planning on ground truth over it,
``planner.freeze.classify``): the replay has them (``scenarios.score.counts``: the
freezes that began by ``timestamp``, with their seconds of each kind up to it); the live
stream (``fleetmap run --foxglove``) leaves them out. The last message of a replay holds
the values of ``metrics.json`` (``tasks_completed``, ``phantom_freezes``,
``phantom_freeze_seconds``, ``true_block_freezes``, ``true_block_seconds``,
``stale_free_plans``, ``inscribed_plans``, ``collisions``, ``scenario_collisions``,
``events``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from scenarios.replay.foxglove_messages import foxglove_time, stamp_ns
from scenarios.replay.foxglove_schemas import TIME
from scenarios.run.record import CountersSample, FreezeRecord
from scenarios.score.counts import freeze_counts

METRICS_TOPIC: Final = "/metrics"
METRICS_SCHEMA: Final = "fleetmap.RunMetrics"

COUNTS: Final = (
    "tasks_completed", "frozen_units", "stale_free_plans", "collisions",
    "scenario_collisions", "events", "inscribed_plans",
)  # fmt: skip
VERDICTS: Final = (
    "phantom_freezes", "phantom_freeze_seconds", "true_block_freezes", "true_block_seconds",
)  # fmt: skip

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
        "true_block_seconds": {"type": "number", "minimum": 0},
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
        message.update(freeze_counts(freezes, until=sample.stamp))
    return message
