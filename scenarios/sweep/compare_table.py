"""The tables of ``fleetmap compare``: per scenario, one Markdown table with a row per
policy and a column per headline metric, each cell the metric's mean over seeds and the
half-width of its 95 % Student's t interval (``scenarios.sweep.compare_stats``), then a row
saying whether the default policy (decay) differs from the baseline (binary) beyond noise.

Cells: ``12.3 ± 4.5`` (mean ± half-width, the metric's unit); ``12.3 (n=1)`` when only one
seed gave a value (no interval); ``-`` when none did; ``time_to_clear_s`` reads ``-``
when no run removed anything, ``never`` when objects were removed and no run of the
policy cleared one, and ``(k never)`` after the mean of the runs that did when k runs
that removed something cleared nothing. The verdict row says, per metric,
``better``/``worse`` when decay's and binary's intervals do not overlap and ``~`` when
they do (or a side has no interval).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from mapserver.core.sensor_model import DEFAULT_POLICY
from scenarios.sweep.compare_stats import CONFIDENCE, Summary, summarise, verdict
from scenarios.sweep.metric_values import CLEAR_KEY, map_truth_names, metric_value
from scenarios.sweep.parallel import RunResult

__all__ = [
    "BASELINE",
    "CANDIDATE",
    "HEADLINE",
    "Column",
    "columns_for",
    "compare_markdown",
    "scenario_table",
    "table_lines",
]

CANDIDATE = DEFAULT_POLICY.value  # the project's default policy
BASELINE = "binary"  # the Nav2 obstacle-layer baseline


@dataclass(frozen=True)
class Column:
    """A headline metric: its ``name`` (``metric_value``), ``title``, whether higher is
    better, and the decimals of its cells."""

    name: str
    title: str
    higher_is_better: bool = False
    decimals: int = 1


HEADLINE = (
    Column("phantom_freezes", "phantom freezes"),
    Column("phantom_freeze_seconds", "phantom s"),
    Column("true_block_freezes", "true blocks"),
    Column("true_block_seconds", "true block s"),
    Column("stale_free_plans", "stale-free plans"),
    Column("inscribed_plans", "inscribed plans"),
    Column("collisions", "collisions"),
    Column("collision_seconds", "collision s"),
    Column("tasks_completed", "tasks", higher_is_better=True),
    Column("trips_per_unit_hour", "trips/unit-h", higher_is_better=True),
    Column("fleet_efficiency", "efficiency", higher_is_better=True, decimals=2),
    Column(CLEAR_KEY, "time to clear s"),
)
MAP_TRUTH_COLUMNS = {
    "map_truth.phantom_cells": Column("map_truth.phantom_cells", "phantom cells"),
    "map_truth.forgotten_cells": Column("map_truth.forgotten_cells", "forgotten cells"),
    "map_truth.unknown_share": Column("map_truth.unknown_share", "unknown share", decimals=3),
}


def columns_for(runs: Sequence[Mapping[str, Any]]) -> list[Column]:
    """The headline columns, plus the map-truth means some run of ``runs`` reports."""
    return [*HEADLINE, *(MAP_TRUTH_COLUMNS[n] for n in map_truth_names(runs))]


def scenario_table(
    scenario: str, by_policy: Mapping[str, Sequence[Mapping[str, Any]]], seeds: int
) -> str:
    """The Markdown table of one scenario: ``by_policy`` maps each policy (in row order)
    to its successful runs' metrics; ``seeds``: seeds asked for per policy."""
    percent = f"{CONFIDENCE * 100:g} %"
    lines = [
        f"### {scenario}",
        "",
        f"Mean over {seeds} seed{'s' if seeds != 1 else ''} per policy ± the half-width of "
        f"its {percent} Student's t interval (n-1 degrees of freedom); (n=1): one value, "
        f"no interval. Row '{CANDIDATE} vs {BASELINE}': better/worse where the intervals "
        "do not overlap, ~ where they do.",
        "",
    ]
    return "\n".join(lines + table_lines(by_policy))


def table_lines(by_policy: Mapping[str, Sequence[Mapping[str, Any]]]) -> list[str]:
    """The Markdown table alone, a line per row (``scenario_table``'s arguments)."""
    columns = columns_for([m for runs in by_policy.values() for m in runs])
    stats = {
        policy: [summarise(_values(runs, c.name)) for c in columns]
        for policy, runs in by_policy.items()
    }
    lines = [
        "| policy | runs | " + " | ".join(c.title for c in columns) + " |",
        "|---|---:|" + "---:|" * len(columns),
    ]
    for policy, runs in by_policy.items():
        cells = [_cell(s, c, runs) for s, c in zip(stats[policy], columns, strict=True)]
        lines.append(f"| {policy} | {len(runs)} | " + " | ".join(cells) + " |")
    if CANDIDATE in stats and BASELINE in stats:
        marks = [
            verdict(a, b, c.higher_is_better)
            for a, b, c in zip(stats[CANDIDATE], stats[BASELINE], columns, strict=True)
        ]
        lines.append(f"| {CANDIDATE} vs {BASELINE} | | " + " | ".join(marks) + " |")
    return lines


def _values(runs: Sequence[Mapping[str, Any]], name: str) -> list[float]:
    return [v for v in (metric_value(m, name) for m in runs) if v is not None]


def _cell(summary: Summary, column: Column, runs: Sequence[Mapping[str, Any]]) -> str:
    never = _never(runs) if column.name == CLEAR_KEY else 0
    if summary.n == 0:
        return "never" if never else "-"
    mean = f"{summary.mean:.{column.decimals}f}"
    text = f"{mean} (n=1)" if summary.half_width is None else (
        f"{mean} ± {summary.half_width:.{column.decimals}f}")  # fmt: skip
    if never:
        text += f" ({never} never)"
    return text


def _never(runs: Sequence[Mapping[str, Any]]) -> int:
    """The runs that removed something (a non-empty ``time_to_clear_s``) and cleared none."""
    return sum(1 for m in runs if m.get(CLEAR_KEY) and metric_value(m, CLEAR_KEY) is None)


def runs_by_policy(
    results: Sequence[RunResult], scenario: str, policies: Sequence[str]
) -> dict[str, list[dict[str, Any]]]:
    """Each policy's successful runs' metrics of ``scenario`` (a file stem), in order."""
    return {
        policy: [
            r.metrics
            for r in results
            if r.status == "ok" and r.run.name == scenario and r.run.policy == policy
        ]
        for policy in policies
    }


def compare_markdown(
    results: Sequence[RunResult], scenarios: Sequence[str], policies: Sequence[str], seeds: int
) -> str:
    """The whole ``compare.md``: a table per scenario (in order), then the failed runs."""
    parts = [
        scenario_table(scenario, runs_by_policy(results, scenario, policies), seeds)
        for scenario in scenarios
    ]
    failed = [r for r in results if r.status != "ok"]
    if failed:
        lines = [f"### Failed runs ({len(failed)}, left out of the tables)", ""]
        lines += [f"- {r.run.label()}: {r.error}" for r in failed]
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"
