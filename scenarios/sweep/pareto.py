"""The sweep's tuning output: the settings no other setting beats on every objective.

A setting is one row of the sweep grid within a scenario: (scenario, policy, parameter
values). Its objectives are the metrics the metric registry shows in ``pareto``
(``scenarios.score.metric_registry``, in its order): ``phantom_freeze_seconds`` [s],
``stale_free_plans`` (count) and ``map_truth.forgotten_cells`` (cells; the mean of
map_truth.forgotten_cells.mean, used only when every setting has it, since map_truth is
optional), each reduced over the setting's successful seeds as the registry says (the
mean), lower better (a higher-better objective is maximised). Setting a dominates setting
b when a is no worse in every objective and strictly better in one (Pareto dominance);
equal points do not dominate each other, so ties and duplicates are all kept.

``DIR/pareto.csv``: per scenario, one row per non-dominated setting: ``scenario``,
``policy``, one column per swept parameter, ``seeds`` (successful runs averaged), then
each objective used, by the last part of its key (``phantom_freeze_seconds``,
``stale_free_plans``, ``forgotten_cells``).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mapserver.store.atomic import atomic_output
from scenarios.score.metric_registry import Better, View, metric, shown_in
from scenarios.sweep.parallel import RunResult
from scenarios.sweep.results import cell_text
from scenarios.sweep.sweep_file import Scalar, Sweep

__all__ = [
    "PARETO_FILENAME",
    "Setting",
    "dominates",
    "non_dominated",
    "pareto_settings",
    "settings_of",
    "objectives",
    "used_objectives",
    "write_pareto",
]

PARETO_FILENAME = "pareto.csv"


def objectives() -> tuple[str, ...]:
    """The keys of the registry's Pareto objectives, in order."""
    return tuple(m.key for m in shown_in(View.PARETO))


@dataclass(frozen=True)
class Setting:
    """One grid row: ``scenario`` (stem), ``policy``, ``parameters`` ((key, value) in
    file order), ``seeds`` (successful runs) and ``objectives`` (name -> reduced over
    them; a name is absent when some run lacked it)."""

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
    """The settings of ``results`` in first-seen order, objectives reduced over each
    setting's successful runs; a setting with no successful run is left out."""
    groups: dict[tuple, list[RunResult]] = {}
    for result in results:
        if result.status == "ok":
            run = result.run
            groups.setdefault((run.name, run.policy, run.parameters), []).append(result)
    out = []
    for (scenario, policy, parameters), runs in groups.items():
        reduced = {}
        for m in shown_in(View.PARETO):
            values = [v for v in (m.number(r.metrics) for r in runs) if v is not None]
            if len(values) == len(runs):
                reduced[m.key] = m.reduce.of(values)
        out.append(Setting(scenario, policy, parameters, len(runs), reduced))
    return out


def used_objectives(settings: Sequence[Setting]) -> tuple[str, ...]:
    """The objectives every setting has; a missing optional one is skipped, a missing
    required one (a run without phantom_freeze_seconds) is a ValueError."""
    used = tuple(n for n in objectives() if all(n in s.objectives for s in settings))
    missing = [n for n in objectives() if n not in used and not metric(n).optional]
    if missing:
        raise ValueError(f"some runs lack the objective(s) {', '.join(missing)}")
    return used


def pareto_settings(settings: Sequence[Setting]) -> tuple[tuple[str, ...], list[Setting]]:
    """(the objectives used, the non-dominated settings of each scenario, in order)."""
    used = used_objectives(settings)
    sign = [-1.0 if metric(n).better is Better.HIGHER else 1.0 for n in used]  # minimised
    front: list[Setting] = []
    for scenario in dict.fromkeys(s.scenario for s in settings):
        group = [s for s in settings if s.scenario == scenario]
        points = [[k * s.objectives[n] for k, n in zip(sign, used, strict=True)] for s in group]
        front += [group[i] for i in non_dominated(points)]
    return used, front


def write_pareto(sweep: Sweep, results: Sequence[RunResult], path: Path) -> int:
    """Write ``pareto.csv`` (module docstring) at ``path`` atomically; returns its rows."""
    used, front = pareto_settings(settings_of(results))
    names = [n.rsplit(".", 1)[-1] for n in used]
    header = ["scenario", "policy", *sweep.parameter_names, "seeds", *names]
    text = io.StringIO(newline="")
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(header)
    for s in front:
        params = dict(s.parameters)
        row = [s.scenario, s.policy, *(params[k] for k in sweep.parameter_names), s.seeds,
               *(round(s.objectives[n], 6) for n in used)]  # fmt: skip
        writer.writerow([cell_text(v) for v in row])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(Path(path)) as f:
        f.write(text.getvalue().encode())
    return len(front)
