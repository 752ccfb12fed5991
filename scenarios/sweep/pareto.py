"""The sweep's tuning output: the settings no other setting beats on every objective.

A setting is one row of the sweep grid within a scenario: (scenario, policy, parameter
values). Its objectives are the means over its successful seeds of
``phantom_freeze_seconds`` [s], ``map_truth.forgotten_cells`` (cells; the mean of
map_truth.forgotten_cells.mean, used only when every setting has it, since map_truth is
optional) and ``stale_free_plans`` (count), all minimised. Setting a dominates setting b
when a is no worse in every objective and strictly better in one (Pareto dominance);
equal points do not dominate each other, so ties and duplicates are all kept.

``DIR/pareto.csv``: per scenario, one row per non-dominated setting: ``scenario``,
``policy``, one column per swept parameter, ``seeds`` (successful runs averaged), then
each objective used (``phantom_freeze_seconds``, ``forgotten_cells``, ``stale_free_plans``).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mapserver.store.atomic import atomic_output
from scenarios.sweep.metric_values import metric_value
from scenarios.sweep.parallel import RunResult
from scenarios.sweep.results import cell_text
from scenarios.sweep.sweep_file import Scalar, Sweep

__all__ = [
    "OBJECTIVES",
    "PARETO_FILENAME",
    "Setting",
    "dominates",
    "non_dominated",
    "pareto_settings",
    "settings_of",
    "used_objectives",
    "write_pareto",
]

PARETO_FILENAME = "pareto.csv"
OBJECTIVES = ("phantom_freeze_seconds", "map_truth.forgotten_cells", "stale_free_plans")
OPTIONAL_OBJECTIVES = ("map_truth.forgotten_cells",)


@dataclass(frozen=True)
class Setting:
    """One grid row: ``scenario`` (stem), ``policy``, ``parameters`` ((key, value) in
    file order), ``seeds`` (successful runs) and ``objectives`` (name -> mean over them;
    a name is absent when some run lacked it)."""

    scenario: str
    policy: str
    parameters: tuple[tuple[str, Scalar], ...]
    seeds: int
    objectives: dict[str, float]


def dominates(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether point ``a`` dominates ``b`` (all minimised): no worse anywhere, better once."""
    return all(x <= y for x, y in zip(a, b, strict=True)) and any(
        x < y for x, y in zip(a, b, strict=True)
    )


def non_dominated(points: Sequence[Sequence[float]]) -> list[int]:
    """Indices (ascending) of the points no point of ``points`` dominates; O(n^2)."""
    return [i for i, p in enumerate(points) if not any(dominates(q, p) for q in points)]


def settings_of(results: Sequence[RunResult]) -> list[Setting]:
    """The settings of ``results`` in first-seen order, objectives averaged over each
    setting's successful runs; a setting with no successful run is left out."""
    groups: dict[tuple, list[RunResult]] = {}
    for result in results:
        if result.status == "ok":
            run = result.run
            groups.setdefault((run.name, run.policy, run.parameters), []).append(result)
    out = []
    for (scenario, policy, parameters), runs in groups.items():
        means = {}
        for name in OBJECTIVES:
            values = [v for v in (metric_value(r.metrics, name) for r in runs) if v is not None]
            if len(values) == len(runs):
                means[name] = math.fsum(values) / len(values)
        out.append(Setting(scenario, policy, parameters, len(runs), means))
    return out


def used_objectives(settings: Sequence[Setting]) -> tuple[str, ...]:
    """The objectives every setting has; a missing optional one is skipped, a missing
    required one (a run without phantom_freeze_seconds) is a ValueError."""
    used = tuple(n for n in OBJECTIVES if all(n in s.objectives for s in settings))
    missing = [n for n in OBJECTIVES if n not in used and n not in OPTIONAL_OBJECTIVES]
    if missing:
        raise ValueError(f"some runs lack the objective(s) {', '.join(missing)}")
    return used


def pareto_settings(settings: Sequence[Setting]) -> tuple[tuple[str, ...], list[Setting]]:
    """(the objectives used, the non-dominated settings of each scenario, in order)."""
    objectives = used_objectives(settings)
    front: list[Setting] = []
    for scenario in dict.fromkeys(s.scenario for s in settings):
        group = [s for s in settings if s.scenario == scenario]
        points = [[s.objectives[n] for n in objectives] for s in group]
        front += [group[i] for i in non_dominated(points)]
    return objectives, front


def write_pareto(sweep: Sweep, results: Sequence[RunResult], path: Path) -> int:
    """Write ``pareto.csv`` (module docstring) at ``path`` atomically; returns its rows."""
    objectives, front = pareto_settings(settings_of(results))
    names = [n.removeprefix("map_truth.") for n in objectives]
    header = ["scenario", "policy", *sweep.parameter_names, "seeds", *names]
    text = io.StringIO(newline="")
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(header)
    for s in front:
        params = dict(s.parameters)
        row = [s.scenario, s.policy, *(params[k] for k in sweep.parameter_names), s.seeds,
               *(round(s.objectives[n], 6) for n in objectives)]  # fmt: skip
        writer.writerow([cell_text(v) for v in row])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(Path(path)) as f:
        f.write(text.getvalue().encode())
    return len(front)
