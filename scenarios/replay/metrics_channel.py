"""The replay's run-metrics channel: topic ``/metrics``, schema ``fleetmap.RunMetrics`` (JSON
schema, fleetmap's own; Foxglove's Plot panel plots any numeric field, e.g.
``/metrics.phantom_freezes``), one message per counters sample (``record.counters``: every
map read and at the run's end, ``scenarios.run.observers.CountersRecorder``)::

    {"timestamp": {"sec": 12, "nsec": 500000000},
     "phantom_freezes": 1, "phantom_freeze_seconds": 4.2, "true_block_freezes": 1,
     "true_block_seconds": 3.0, "stale_free_plans": 0, "inscribed_plans": 1,
     "collisions": 0, "scenario_collisions": 0, "tasks_completed": 3, "events": 2,
     "frozen_units": 1}

The fields are the metrics the metric registry shows on ``/metrics``
(``scenarios.score.metric_registry``, in its order; the schema describes each with its
title and unit). Every count is as it stood at ``timestamp`` (sim time); ``collisions``
and ``scenario_collisions`` count incidents (``scenarios.score.incidents``). The freezes'
four (``scenarios.score.counts.freeze_counts``) are their verdicts, known only once the
run is scored (a freeze's time is split into phantom and true-block segments by planning
on ground truth over it, ``planner.freeze.classify``): the replay has them (the freezes
that began by ``timestamp``, with their seconds of each kind up to it); the live stream
(``fleetmap run --foxglove``) leaves them out. The others are the sample's own fields
(``scenarios.run.record.CountersSample``). The last message of a replay holds the values
of ``metrics.json`` for the keys both have.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from scenarios.replay.foxglove_messages import foxglove_time, stamp_ns
from scenarios.replay.foxglove_schemas import TIME
from scenarios.run.record import COUNTERS, CountersSample, FreezeRecord
from scenarios.score.counts import freeze_counts
from scenarios.score.metric_registry import Metric, MetricError, View, shown_in

METRICS_TOPIC: Final = "/metrics"
METRICS_SCHEMA: Final = "fleetmap.RunMetrics"

VERDICTS: Final = freeze_counts.feeds
"""The fields known once the run is scored (the keys ``freeze_counts`` feeds)."""
SAMPLED: Final = COUNTERS
"""The fields a counters sample holds."""


def _sampled(metric: Metric) -> bool:
    """Whether the counters sample holds ``metric`` (else the freezes' verdicts do);
    MetricError for a metric on ``/metrics`` that neither holds."""
    if metric.key in SAMPLED:
        return True
    if metric.key in VERDICTS:
        return False
    raise MetricError(f"/metrics: {metric.key!r} is neither a counter nor a freeze verdict")


def schema() -> dict[str, Any]:
    """The JSON schema of the registry's ``/metrics`` fields: each a count (integer) or
    a number, at least 0, described by its title and unit; the sampled ones required."""
    metrics = shown_in(View.FOXGLOVE)
    return {
        "title": METRICS_SCHEMA,
        "type": "object",
        "properties": {
            "timestamp": TIME,
            **{
                m.key: {
                    "type": "integer" if m.unit.integer else "number",
                    "minimum": 0,
                    "description": m.label,
                }
                for m in metrics
            },
        },
        "required": ["timestamp", *(m.key for m in metrics if _sampled(m))],
    }


SCHEMA: Final[dict[str, Any]] = schema()


def metrics_message(
    sample: CountersSample, freezes: Sequence[FreezeRecord] | None = None
) -> dict[str, Any]:
    """One sample's message; with the run's scored ``freezes`` (None: not scored yet) the
    verdicts as they stood at the sample (module docstring)."""
    verdicts = None if freezes is None else freeze_counts(freezes, until=sample.stamp)
    message: dict[str, Any] = {"timestamp": foxglove_time(stamp_ns(sample.stamp))}
    for m in shown_in(View.FOXGLOVE):
        if _sampled(m):
            value = getattr(sample, m.key)
            message[m.key] = int(value) if m.unit.integer else float(value)
        elif verdicts is not None:
            message[m.key] = verdicts[m.key]
    return message
