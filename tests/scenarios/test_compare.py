"""``fleetmap compare``: the Student's t interval on hand-computed values, the verdict,
the per-run metric values (time to clear, optional map_truth), the table, the command
(a real 2-seed run of a 4 s tiny scenario; a failing run reported with exit status 1)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest
from scenario_helpers import TINY, tiny5

import scenarios.sweep.parallel
from scenarios.cli.main import main
from scenarios.score.metric_registry import Better, metric
from scenarios.sweep.compare import parse_policies
from scenarios.sweep.compare_stats import Summary, summarise, verdict
from scenarios.sweep.compare_table import columns_for, scenario_table
from scenarios.sweep.parallel import RunResult


# ---------------------------------------------------------------------------- statistics
def test_interval_matches_hand_computed_student_t() -> None:
    # [1, 2, 3]: mean 2, s = 1, t(0.975, 2) = 4.3027 (tables): 4.3027 / sqrt(3)
    assert summarise([1, 2, 3]) == Summary(3, 2.0, pytest.approx(2.4841377, abs=1e-6))
    # [10, 12]: mean 11, s = sqrt(2), t(0.975, 1) = 12.7062: 12.7062 * sqrt(2) / sqrt(2)
    assert summarise([10, 12]).half_width == pytest.approx(12.7062047, abs=1e-6)
    # [2, 4, 6, 8]: s = sqrt(20 / 3), t(0.975, 3) = 3.1824: 3.1824 * s / 2
    assert summarise([2, 4, 6, 8]) == Summary(4, 5.0, pytest.approx(4.1085205, abs=1e-6))
    assert summarise([7, 7, 7]) == Summary(3, 7.0, 0.0)


def test_one_value_gives_no_interval_and_none_gives_no_mean() -> None:
    assert summarise([3.5]) == Summary(1, 3.5, None)
    empty = summarise([])
    assert empty.n == 0 and math.isnan(empty.mean) and empty.half_width is None


def test_verdict_needs_intervals_apart() -> None:
    low, high = Summary(3, 1.0, 0.5), Summary(3, 3.0, 0.5)  # [0.5, 1.5] and [2.5, 3.5]
    lower, higher = Better.LOWER, Better.HIGHER
    assert verdict(low, high, lower) == "better"
    assert verdict(high, low, lower) == "worse"
    assert verdict(low, high, higher) == "worse"
    assert verdict(high, low, higher) == "better"
    assert verdict(low, high, Better.NEITHER) == "lower"  # apart, but neither is better
    assert verdict(high, low, Better.NEITHER) == "higher"
    touching = Summary(3, 2.0, 0.5)  # [1.5, 2.5] touches both
    assert verdict(low, touching, lower) == verdict(touching, high, lower) == "~"
    assert verdict(Summary(1, 1.0, None), high, lower) == "~"  # no interval: no claim
    assert verdict(Summary(3, 0.0, 0.0), Summary(3, 2.0, 0.0), lower) == "better"


# ---------------------------------------------------------------------------- metric values
def truth(forgotten: float) -> dict:
    return {
        "phantom_cells": {"mean": 2.0, "final": 1},
        "forgotten_cells": {"mean": forgotten, "final": 0},
        "unknown_share": {"mean": 0.25, "final": 0.2},
    }


def test_metric_values_read_time_to_clear_and_optional_map_truth() -> None:
    run = {"time_to_clear_s": [2.0, None, 4.0], "collisions": 0, "map_truth": truth(6.5)}
    clear, forgotten = metric("time_to_clear_s"), metric("map_truth.forgotten_cells")
    assert clear.number(run) == 3.0  # mean of the non-null entries
    assert clear.number({"time_to_clear_s": [None]}) is None
    assert metric("collisions").number(run) == 0.0
    assert forgotten.number(run) == 6.5
    assert forgotten.number({"collisions": 0}) is None
    assert forgotten.number({"map_truth": {"forgotten_cells": 3}}) is None
    assert metric("collisions").number({"collisions": True}) is None
    optional = [m.key for m in columns_for([{}, run]) if m.optional]
    assert [m.key for m in columns_for([{"collisions": 0}]) if m.optional] == []
    assert optional == [
        "map_truth.phantom_cells",
        "map_truth.forgotten_cells",
        "map_truth.unknown_share",
    ]


# ---------------------------------------------------------------------------- table
def runs(phantom_s: list[float], **extra: object) -> list[dict]:
    return [
        {"phantom_freeze_seconds": p, "phantom_freezes": 1, "tasks_completed": 4,
         "time_to_clear_s": [None] if i == 0 else [10.0 * i], **extra}
        for i, p in enumerate(phantom_s)
    ]  # fmt: skip


def table_rows(text: str) -> dict[str, dict[str, str]]:
    lines = [line for line in text.splitlines() if line.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = {}
    for line in lines[2:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0]] = dict(zip(header, cells, strict=True))
    return rows


def test_table_cells_are_mean_and_half_width_with_a_verdict_row() -> None:
    text = scenario_table(
        "tiny", {"dual": runs([1, 2, 3]), "binary": runs([10, 12]), "sticky": runs([5])}, 3
    )
    assert "95 % Student's t interval" in text and "Mean over 3 seeds" in text
    rows = table_rows(text)
    assert rows["dual"]["runs"] == "3"
    assert rows["dual"]["phantom s"] == "2.0 ± 2.5"
    assert rows["binary"]["phantom s"] == "11.0 ± 12.7"
    assert rows["sticky"]["phantom s"] == "5.0 (n=1)"
    assert rows["dual"]["time to clear s"] == "15.0 ± 63.5 (1 never)"  # [10, 20] and a never
    assert rows["sticky"]["time to clear s"] == "never"
    assert rows["dual"]["collisions"] == "-"  # no run reports it
    assert "forgotten cells" not in rows["dual"]  # map_truth absent: no columns
    verdicts = rows["dual vs binary"]
    assert verdicts["phantom s"] == "~"  # [-0.5, 4.5] and [-1.7, 23.7] overlap
    assert verdicts["phantom freezes"] == "~"  # identical values


def test_time_to_clear_is_empty_where_nothing_was_removed_and_never_only_where_it_was():
    nothing = [{"phantom_freezes": 0, "time_to_clear_s": []} for _ in range(2)]
    stuck = [{"phantom_freezes": 0, "time_to_clear_s": [None]} for _ in range(2)]
    mixed = [*nothing, {"phantom_freezes": 0, "time_to_clear_s": [4.0]}, *stuck]
    rows = table_rows(scenario_table("t", {"decay": nothing, "binary": stuck, "x": mixed}, 5))
    assert rows["decay"]["time to clear s"] == "-"
    assert rows["binary"]["time to clear s"] == "never"
    assert rows["x"]["time to clear s"] == "4.0 (n=1) (2 never)"  # the two that removed


def test_table_verdicts_and_map_truth_columns() -> None:
    dual = runs([1, 1, 1], map_truth=truth(1.0))
    binary = runs([4, 4, 4], map_truth=truth(3.0))
    binary[0]["tasks_completed"] = binary[1]["tasks_completed"] = binary[2]["tasks_completed"] = 2
    rows = table_rows(scenario_table("tiny", {"dual": dual, "binary": binary}, 3))
    assert rows["dual"]["forgotten cells"] == "1.0 ± 0.0"
    assert rows["dual"]["unknown share"] == "0.250 ± 0.000"
    verdicts = rows["dual vs binary"]
    assert verdicts["phantom s"] == "better"  # lower is better
    assert verdicts["tasks"] == "better"  # 4 > 2: higher is better
    assert verdicts["forgotten cells"] == "better"
    assert verdicts["phantom cells"] == "~"


def test_policies_parse_and_bad_ones_are_named() -> None:
    assert parse_policies(" decay, binary ") == ("decay", "binary")
    for text, word in (("decay,greedy", "greedy"), ("decay,decay", "twice"), (",", "at least")):
        with pytest.raises(ValueError, match=word):
            parse_policies(text)


# ---------------------------------------------------------------------------- the command
def test_compare_runs_every_seed_and_writes_csv_and_tables(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    argv = ["compare", str(tiny5(tmp_path, duration=4.0)), "--policies", "binary", "--seeds", "2"]
    assert main([*argv, "--workers", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "[1/2] tiny5/binary/seed" in printed and "[2/2] tiny5/binary/seed" in printed
    assert f"{out / 'compare.csv'}" in printed and f"{out / 'compare.md'}" in printed
    with (out / "compare.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["scenario"], r["policy"], r["seed"], r["status"]) for r in rows] == [
        ("tiny5", "binary", "0", "ok"),
        ("tiny5", "binary", "1", "ok"),
    ]
    assert all(float(r["sim_seconds"]) == 4.0 for r in rows)
    nested = [c for c in rows[0] if "." in c or c == "time_to_clear_s"]  # objects' leaves
    assert "wait_s.traffic" in nested and "map_truth.forgotten_cells.mean" in nested
    for row in rows:  # every nested value reads back as JSON (a list, a leaf's number)
        assert isinstance(json.loads(row["time_to_clear_s"]), list)
        assert all(isinstance(json.loads(row[c]), int | float | list) for c in nested if row[c])
    table = (out / "compare.md").read_text()
    assert table in printed
    assert table_rows(table)["binary"]["runs"] == "2"
    assert (out / "tiny5" / "binary" / "seed1" / "metrics.json").is_file()


def test_a_failed_run_is_listed_and_exits_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def fake_run_sweep(runs, out_dir, workers=None, on_result=None, on_wait=None):  # noqa: ANN001, ANN202
        results = [
            RunResult(runs[0], "ok", out_dir, {"phantom_freeze_seconds": 2.0}),
            RunResult(runs[1], "error", out_dir, error="RuntimeError: server died"),
        ]
        for result in results:
            on_result(result)
        return results

    monkeypatch.setattr(scenarios.sweep.parallel, "run_sweep", fake_run_sweep)
    out = tmp_path / "out"
    assert (
        main(["compare", str(TINY), "--policies", "decay", "--seeds", "2", "--out", str(out)]) == 1
    )
    captured = capsys.readouterr()
    assert "[2/2] tiny/decay/seed1 FAILED: RuntimeError: server died" in captured.out
    assert "1 of 2 runs failed" in captured.err and "tiny/decay/seed1" in captured.err
    table = (out / "compare.md").read_text()
    assert table_rows(table)["decay"]["phantom s"] == "2.0 (n=1)"  # the other run still counts
    assert "tiny/decay/seed1: RuntimeError: server died" in table


def test_bad_scenario_exits_two_before_any_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert main(["compare", str(tmp_path / "nope.yaml"), "--out", str(out)]) == 2
    assert "nope.yaml" in capsys.readouterr().err
    assert not out.exists()
