"""The sweep's Pareto front: dominance on hand-made points (ties, duplicates), the
settings averaged over seeds, a missing optional objective, pareto.csv, and the front's
defining property on random points."""

from __future__ import annotations

import csv
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from scenarios.sweep.parallel import RunResult
from scenarios.sweep.pareto import (
    dominates,
    non_dominated,
    pareto_settings,
    settings_of,
    used_objectives,
    write_pareto,
)
from scenarios.sweep.sweep_file import Sweep, SweepRun

HALF_LIFE = "map_server.decay.half_life_occupied"
SCENARIO = Path("tiny.yaml")


def test_dominance_needs_no_worse_everywhere_and_better_once() -> None:
    assert dominates((1, 5), (1, 6))  # a tie in one objective, better in the other
    assert dominates((0, 0, 0), (1, 1, 1))
    assert not dominates((1, 5), (1, 5))  # equal points: neither dominates
    assert not dominates((1, 5), (2, 4))  # a trade-off
    assert not dominates((2, 4), (1, 5))


def test_front_of_hand_made_points_keeps_ties_and_duplicates() -> None:
    points = [(1, 5), (2, 2), (5, 1), (3, 3), (2, 2), (1, 6), (5, 1)]
    # (3, 3) is beaten by (2, 2); (1, 6) by (1, 5); both copies of (2, 2) and (5, 1) stay
    assert non_dominated(points) == [0, 1, 2, 4, 6]
    assert non_dominated([(4.0,), (3.0,), (3.0,)]) == [1, 2]
    assert non_dominated([]) == []


@given(st.lists(st.lists(st.integers(0, 4), min_size=3, max_size=3), max_size=30))
def test_front_is_exactly_the_undominated_points(points: list[list[int]]) -> None:
    front = non_dominated(points)
    kept = [points[i] for i in front]
    for p in kept:
        assert not any(dominates(q, p) for q in points)
    for i, p in enumerate(points):
        if i not in front:
            assert any(dominates(q, p) for q in kept)


def result(policy: str, half_life: int, seed: int, **metrics: object) -> RunResult:
    run = SweepRun(SCENARIO, "tiny", policy, seed, ((HALF_LIFE, half_life),))
    return RunResult(run, "ok", Path("out"), dict(metrics))


def truth(forgotten: float) -> dict:
    cell = {"mean": forgotten, "final": 0}
    return {"phantom_cells": cell, "forgotten_cells": cell, "unknown_share": cell}


def test_settings_average_their_seeds_and_skip_failed_runs() -> None:
    failed = RunResult(SweepRun(SCENARIO, "tiny", "decay", 2, ((HALF_LIFE, 10),)), "error",
                       Path("out"), error="boom")  # fmt: skip
    results = [
        result("decay", 10, 0, phantom_freeze_seconds=4.0, stale_free_plans=1),
        result("decay", 10, 1, phantom_freeze_seconds=6.0, stale_free_plans=2),
        failed,
        result("decay", 30, 0, phantom_freeze_seconds=1.0, stale_free_plans=0),
    ]
    settings = settings_of(results)
    assert [(s.parameters, s.seeds) for s in settings] == [
        (((HALF_LIFE, 10),), 2),
        (((HALF_LIFE, 30),), 1),
    ]
    assert settings[0].objectives == {"phantom_freeze_seconds": 5.0, "stale_free_plans": 1.5}
    # map_truth is absent everywhere: that objective is skipped, the others decide
    assert used_objectives(settings) == ("phantom_freeze_seconds", "stale_free_plans")
    objectives, front = pareto_settings(settings)
    assert [dict(s.parameters)[HALF_LIFE] for s in front] == [30]


def test_forgotten_cells_counts_when_every_setting_has_it() -> None:
    results = [
        result(
            "decay", 10, 0, phantom_freeze_seconds=4.0, stale_free_plans=1, map_truth=truth(0.0)
        ),  # fmt: skip
        result(
            "decay", 30, 0, phantom_freeze_seconds=1.0, stale_free_plans=0, map_truth=truth(9.0)
        ),  # fmt: skip
    ]
    objectives, front = pareto_settings(settings_of(results))
    assert objectives == ("phantom_freeze_seconds", "stale_free_plans",
                          "map_truth.forgotten_cells")  # fmt: skip
    assert len(front) == 2  # half-life 10 forgets less, 30 freezes less: a trade-off
    # one setting without map_truth: the objective is skipped and 30 wins outright
    results[0] = result("decay", 10, 0, phantom_freeze_seconds=4.0, stale_free_plans=1)
    objectives, front = pareto_settings(settings_of(results))
    assert "map_truth.forgotten_cells" not in objectives
    assert [dict(s.parameters)[HALF_LIFE] for s in front] == [30]


def test_pareto_csv_has_one_row_per_undominated_setting(tmp_path: Path) -> None:
    sweep = Sweep((SCENARIO,), ("decay", "binary"), (0, 1), ((HALF_LIFE, (10, 30)),))
    results = [
        result("decay", 10, 0, phantom_freeze_seconds=2.0, stale_free_plans=0, map_truth=truth(1)),
        result("decay", 10, 1, phantom_freeze_seconds=4.0, stale_free_plans=0, map_truth=truth(3)),
        result("decay", 30, 0, phantom_freeze_seconds=9.0, stale_free_plans=0, map_truth=truth(2)),
        result("binary", 10, 0, phantom_freeze_seconds=1.0, stale_free_plans=3, map_truth=truth(5)),
    ]
    path = tmp_path / "pareto.csv"
    assert write_pareto(sweep, results, path) == 2
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    assert rows == [
        [
            "scenario",
            "policy",
            HALF_LIFE,
            "seeds",
            "phantom_freeze_seconds",
            "stale_free_plans",
            "forgotten_cells",
        ],  # fmt: skip
        ["tiny", "decay", "10", "2", "3.0", "0.0", "2.0"],
        ["tiny", "binary", "10", "1", "1.0", "3.0", "5.0"],
    ]
