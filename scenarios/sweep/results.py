"""A sweep's outputs: ``results.csv`` (one row per run) and ``tradeoff.png``.

results.csv columns: ``scenario`` (file stem), ``policy``, ``seed``, one column per
swept parameter (its dotted key), every metrics.json key (those docs/files.md 3 names
always; in the metric registry's order, ``scenarios.score.metric_registry``; then any key
it does not know, from runs scored before, in first-seen order; ``scenario``/``policy``/
``seed`` are not repeated), then
``status`` (``ok``/``error``), ``error``, ``run_wall_seconds`` [s] and ``out_dir``. A
metric that is an object is one column per leaf, named by its dotted path
(``map_truth.forgotten_cells.mean``, ``wait_s.traffic``). A list (``time_to_clear_s``) is
JSON (``[4.5, null]``, ``[]``), so ``json.loads`` reads it back; a missing value is empty.
``fleetmap compare`` writes its ``compare.csv`` the same way.

tradeoff.png: phantom freeze time [s] (y) against stale-free plans (x), one point per
successful run, coloured by policy, axes labelled from the registry; one subplot per
swept parameter with each point labelled by its value (one plot when the grid is empty).
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mapserver.store.atomic import atomic_output
from scenarios.score.metric_registry import REGISTRY, metric
from scenarios.sweep.parallel import RunResult
from scenarios.sweep.sweep_file import Sweep

__all__ = [
    "cell_text",
    "flatten",
    "result_columns",
    "result_rows",
    "write_csv",
    "write_plot",
]

RESULTS_FILENAME = "results.csv"
PLOT_FILENAME = "tradeoff.png"
TRADEOFF_X = "stale_free_plans"
TRADEOFF_Y = "phantom_freeze_seconds"
RUN_KEYS = ("scenario", "policy", "seed")
TAIL_COLUMNS = ("status", "error", "run_wall_seconds", "out_dir")
POLICY_COLOURS = {"decay": "tab:blue", "binary": "tab:orange", "sticky": "tab:red"}


def result_columns(sweep: Sweep, results: Sequence[RunResult]) -> list[str]:
    """The CSV header (module docstring)."""
    order = {key: i for i, key in enumerate(REGISTRY.json_keys())}
    always = [k for k in REGISTRY.contract_keys() if not REGISTRY.parts(k)]
    given = [k for r in results for k in flatten(r.metrics)]
    seen = dict.fromkeys(k for k in [*always, *given] if k not in RUN_KEYS)
    known = [k for k in seen if k.split(".")[0] in order]
    metrics = sorted(known, key=lambda k: order[k.split(".")[0]])  # stable: parts in order
    metrics += [k for k in seen if k not in known]
    return [*RUN_KEYS, *sweep.parameter_names, *metrics, *TAIL_COLUMNS]


def flatten(metrics: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``metrics`` with every object replaced by its leaves under dotted keys
    (``{"wait_s": {"traffic": 1.0}}`` -> ``{"wait_s.traffic": 1.0}``), in order."""
    flat: dict[str, Any] = {}
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


def result_rows(sweep: Sweep, results: Sequence[RunResult]) -> list[dict[str, str]]:
    """One CSV row (column -> text) per result, in the order given."""
    columns = result_columns(sweep, results)
    rows = []
    for result in results:
        run = result.run
        values: dict[str, Any] = {**flatten(result.metrics), **dict(run.parameters)}
        values |= {
            "scenario": run.name,
            "policy": run.policy,
            "seed": run.seed,
            "status": result.status,
            "error": result.error,
            "run_wall_seconds": round(result.wall_seconds, 3),
            "out_dir": str(result.out_dir),
        }
        rows.append({c: cell_text(values.get(c)) for c in columns})
    return rows


def write_csv(sweep: Sweep, results: Sequence[RunResult], path: Path) -> None:
    """``results.csv`` at ``path`` (written atomically)."""
    columns = result_columns(sweep, results)
    rows = result_rows(sweep, results)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(Path(path)) as f:
        text = io.StringIO(newline="")
        writer = csv.DictWriter(text, fieldnames=columns, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        f.write(text.getvalue().encode())


def write_plot(sweep: Sweep, results: Sequence[RunResult], path: Path) -> None:
    """``tradeoff.png`` at ``path`` (module docstring), with matplotlib's Agg backend."""
    from matplotlib.figure import Figure

    ok = [r for r in results if r.status == "ok"]
    panels: list[str | None] = list(sweep.parameter_names) or [None]
    fig = Figure(figsize=(5.5 * len(panels), 4.5), dpi=100)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    policies = list(dict.fromkeys([*sweep.policies, *(r.run.policy for r in ok)]))
    for ax, name in zip(axes, panels, strict=True):
        for policy in policies:
            points = [r for r in ok if r.run.policy == policy]
            xs = [_number(r.metrics.get(TRADEOFF_X)) for r in points]
            ys = [_number(r.metrics.get(TRADEOFF_Y)) for r in points]
            ax.scatter(xs, ys, label=policy, color=POLICY_COLOURS.get(policy), alpha=0.8)
            if name is not None:
                params = [dict(r.run.parameters)[name] for r in points]
                for x, y, value in zip(xs, ys, params, strict=True):
                    ax.annotate(str(value), (x, y), textcoords="offset points", xytext=(4, 4),
                                fontsize=7)  # fmt: skip
        ax.set_xlabel(metric(TRADEOFF_X).label)
        ax.set_ylabel(metric(TRADEOFF_Y).label)
        ax.set_title(name if name is not None else "all runs", fontsize=9)
        ax.grid(True, alpha=0.3)
        if policies:
            ax.legend(title="policy", fontsize=8)
    failed = len(results) - len(ok)
    fig.suptitle(
        f"Trade-off per run ({len(ok)} ok" + (f", {failed} failed)" if failed else ")"),
        fontsize=10,
    )
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(Path(path)) as f:
        fig.savefig(f, format="png")


def _number(value: Any) -> float:
    """A metric as a float for plotting (NaN when absent or not a number)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def cell_text(value: Any) -> str:
    """A CSV cell: a list (or an object left whole) as JSON, None empty, booleans
    ``true``/``false``."""
    if value is None:
        return ""
    if isinstance(value, list | tuple | Mapping):
        return json.dumps(value)
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)
