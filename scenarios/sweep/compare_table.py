"""The tables of ``fleetmap compare``: per scenario, one Markdown table with a row per
policy and a column per metric the metric registry shows in ``compare``
(``scenarios.score.metric_registry``: its header, decimals, better direction and how
seeds are reduced), each cell the metric's mean over seeds and the half-width of its
95 % Student's t interval (``scenarios.sweep.compare_stats``), then a row saying whether
the default policy differs from the baseline (binary) beyond noise. An optional metric
(``map_truth``'s) has a column only when some run reports it.

Cells: ``12.3 ± 4.5`` (mean ± half-width, the metric's unit); ``12.3 (n=1)`` when only one
seed gave a value (no interval); ``-`` when none did; a metric reduced otherwise than by
the mean (a sum, a maximum) is that number and ``(n=k)``, the runs it pools. A metric
read from a list (``time_to_clear_s``) reads ``-`` when no run's list has an entry,
``never`` when lists had entries and no run of the policy gave a number, and ``(k never)``
after the mean of the runs that did when k runs with entries gave none. The verdict row
says, per metric, ``better``/``worse`` when the two intervals do not overlap (``higher``/
``lower`` for a metric with no better direction) and ``~`` when they do (or a side has
no interval).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from mapserver.core.sensor_model import DEFAULT_POLICY
from scenarios.score.metric_registry import Metric, Read, Reduce, View, shown_in
from scenarios.sweep.compare_stats import CONFIDENCE, Summary, summarise, verdict
from scenarios.sweep.parallel import RunResult

__all__ = [
    "BASELINE",
    "CANDIDATE",
    "columns_for",
    "compare_markdown",
    "scenario_table",
    "table_lines",
]

CANDIDATE = DEFAULT_POLICY.value  # the project's default policy
BASELINE = "binary"  # the Nav2 obstacle-layer baseline


def columns_for(runs: Sequence[Mapping[str, Any]]) -> list[Metric]:
    """The registry's ``compare`` metrics, an optional one only when some run of ``runs``
    (metrics dicts) has a number for it."""
    return [
        m for m in shown_in(View.COMPARE)
        if not m.optional or any(m.number(r) is not None for r in runs)
    ]  # fmt: skip


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
    stats = {policy: [_summary(m, runs) for m in columns] for policy, runs in by_policy.items()}
    lines = [
        "| policy | runs | " + " | ".join(m.header for m in columns) + " |",
        "|---|---:|" + "---:|" * len(columns),
    ]
    for policy, runs in by_policy.items():
        cells = [_cell(s, c, runs) for s, c in zip(stats[policy], columns, strict=True)]
        lines.append(f"| {policy} | {len(runs)} | " + " | ".join(cells) + " |")
    if CANDIDATE in stats and BASELINE in stats:
        marks = [
            verdict(a, b, m.better)
            for a, b, m in zip(stats[CANDIDATE], stats[BASELINE], columns, strict=True)
        ]
        lines.append(f"| {CANDIDATE} vs {BASELINE} | | " + " | ".join(marks) + " |")
    return lines


def _summary(metric: Metric, runs: Sequence[Mapping[str, Any]]) -> Summary:
    """``metric`` over ``runs``: the mean and its interval, or (reduced otherwise) the
    reduced number without one."""
    values = [v for v in (metric.number(m) for m in runs) if v is not None]
    if metric.reduce is Reduce.MEAN:
        return summarise(values)
    reduced = metric.reduce.of(values)
    return Summary(len(values), math.nan if reduced is None else reduced, None)


def _cell(summary: Summary, metric: Metric, runs: Sequence[Mapping[str, Any]]) -> str:
    never = _never(runs, metric) if metric.read is Read.LIST_MEAN else 0
    if summary.n == 0:
        return "never" if never else "-"
    number = metric.fixed(summary.mean)
    text = f"{number} (n={summary.n})" if summary.half_width is None else (
        f"{number} ± {metric.fixed(summary.half_width)}")  # fmt: skip
    if never:
        text += f" ({never} never)"
    return text


def _never(runs: Sequence[Mapping[str, Any]], metric: Metric) -> int:
    """The runs whose list of ``metric`` has entries (something was removed) and no number
    (nothing cleared)."""
    return sum(1 for m in runs if metric.stored(m) and metric.number(m) is None)


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
