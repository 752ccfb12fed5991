"""One number per run for a metric of metrics.json (docs/files.md), as the comparison
table and the sweep's Pareto front read them.

A metric is named by its key (``phantom_freeze_seconds``) or, for the map-truth means, by
``map_truth.<name>`` (``map_truth.forgotten_cells`` reads ``map_truth.forgotten_cells.mean``).
``time_to_clear_s`` (a list [s], one per removal event, null when never cleared) counts as
the mean of its non-null entries. A metric the run lacks, or a non-number, is None.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["MAP_TRUTH", "MAP_TRUTH_KEYS", "map_truth_names", "metric_value"]

MAP_TRUTH = "map_truth"
MAP_TRUTH_KEYS = ("phantom_cells", "forgotten_cells", "unknown_share")
CLEAR_KEY = "time_to_clear_s"


def metric_value(metrics: Mapping[str, Any], name: str) -> float | None:
    """``name``'s number in one run's ``metrics`` (module docstring), None when absent."""
    if name.startswith(MAP_TRUTH + "."):
        return _number(_get(_get(_get(metrics, MAP_TRUTH), name[len(MAP_TRUTH) + 1 :]), "mean"))
    value = metrics.get(name)
    if name == CLEAR_KEY and isinstance(value, list):
        cleared = [v for v in (_number(x) for x in value) if v is not None]
        return math.fsum(cleared) / len(cleared) if cleared else None
    return _number(value)


def _get(mapping: Any, key: str) -> Any:
    return mapping.get(key) if isinstance(mapping, Mapping) else None


def _number(value: Any) -> float | None:
    """``value`` as a finite float; None for None, booleans, text and NaN."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def map_truth_names(runs: Iterable[Mapping[str, Any]]) -> list[str]:
    """The ``map_truth.<name>`` metrics some run of ``runs`` (metrics dicts) reports, in
    the order of docs/files.md 3; empty when no run has map_truth (it is optional here)."""
    runs = list(runs)
    names = [f"{MAP_TRUTH}.{key}" for key in MAP_TRUTH_KEYS]
    return [n for n in names if any(metric_value(m, n) is not None for m in runs)]
