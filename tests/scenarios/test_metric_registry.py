"""The metric registry (``scenarios.score.metric_registry``): a key it does not declare
cannot be emitted silently, and every view (the compare table, ``fleetmap run``'s table,
the report, the replay's ``/metrics``, a sweep's Pareto front and CSV, the docs) takes
its metrics, titles, units and directions from it: a metric added to the registry here
shows up in each with its title and direction. All unit tests on hand-made metrics."""

from __future__ import annotations

import csv
import json
import re
import typing
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mapserver.core.geometry import GridGeometry
from scenarios.cli.run import format_table
from scenarios.replay import metrics_channel
from scenarios.run.observers import CountersRecorder, StandardObservers
from scenarios.run.record import CountersSample, RunRecord
from scenarios.score import metric_registry
from scenarios.score.counts import freeze_counts, plan_counts
from scenarios.score.free_run import free_run_metrics
from scenarios.score.incidents import collision_counts
from scenarios.score.metric_docs import block_table, page_files, rewrite, stale_blocks
from scenarios.score.metric_registry import (
    COUNT,
    REGISTRY,
    SECONDS,
    Better,
    Metric,
    MetricError,
    Reduce,
    Registry,
    View,
    feeds,
)
from scenarios.score.report import throughput_rows, title
from scenarios.score.throughput import ThroughputTracker
from scenarios.sweep.compare_table import scenario_table
from scenarios.sweep.parallel import RunResult
from scenarios.sweep.pareto import pareto_settings, settings_of
from scenarios.sweep.results import cell_text, write_csv
from scenarios.sweep.sweep_file import Sweep, SweepRun

ROOT = Path(__file__).resolve().parents[2]
GEOMETRY = GridGeometry(width=4, height=4, resolution=0.5, origin_x=0.0, origin_y=0.0)
SCORERS = (
    freeze_counts, plan_counts, collision_counts, ThroughputTracker.metrics, free_run_metrics
)  # fmt: skip
RUN_OWN = {"scenario", "policy", "seed", "units", "sim_seconds", "wall_seconds", "replans",
           "deadlocks", "scans_fused", "events"}  # fmt: skip
"""The keys ``Episode._metrics`` takes from the scenario, the clock, the navigators, the
coordinator and the poster (no observer measures them)."""


def bananas(*views: View, better: Better = Better.HIGHER, **kw: object) -> Metric:
    return Metric("bananas", "bananas eaten", COUNT, better, "bananas the fleet ate", "run",
                  column="bananas", views=frozenset({View.METRICS_JSON, *views}), **kw)  # fmt: skip


@pytest.fixture
def registry(monkeypatch: pytest.MonkeyPatch):
    """Put a registry with more metrics in place: ``registry(*metrics)``."""

    def put(*metrics: Metric) -> Registry:
        bigger = REGISTRY.plus(*metrics)
        monkeypatch.setattr(metric_registry, "REGISTRY", bigger)
        return bigger

    return put


def full_metrics() -> dict:
    """A ``metrics.json`` with every key the registry declares (values irrelevant here)."""
    metrics: dict = {}
    for m in REGISTRY.shown_in(View.METRICS_JSON):
        if "." in m.key:
            metrics.setdefault(m.root, {})[m.key.split(".", 1)[1]] = 0.0
        else:
            metrics[m.key] = 0
    return metrics


# ---------------------------------------------------------------------------- emitting
def test_the_scorers_and_the_run_feed_exactly_the_registrys_keys() -> None:
    fed = [k for scorer in SCORERS for k in scorer.feeds]
    assert len(fed) == len(set(fed))  # no key fed twice
    assert set(fed) <= set(REGISTRY.json_keys()) - RUN_OWN
    REGISTRY.check(full_metrics())


def test_the_observers_declare_the_metrics_they_measure() -> None:
    observers = typing.get_type_hints(StandardObservers).values()
    scored = [k for o in observers if o is not CountersRecorder for k in getattr(o, "feeds", ())]
    assert len(scored) == len(set(scored))  # each metrics.json key measured once
    assert set(scored) | RUN_OWN == set(REGISTRY.json_keys()) and not set(scored) & RUN_OWN
    foxglove = {m.key for m in REGISTRY.shown_in(View.FOXGLOVE)}
    assert set(CountersRecorder.feeds) <= foxglove  # the counters sampled for /metrics


def test_a_key_the_registry_does_not_declare_is_named_when_checked() -> None:
    metrics = full_metrics() | {"bananas": 3}
    with pytest.raises(MetricError, match="'bananas' not declared"):
        REGISTRY.check(metrics)
    del metrics["bananas"], metrics["deadlocks"]
    with pytest.raises(MetricError, match="declared 'deadlocks' missing"):
        REGISTRY.check(metrics)
    metrics = full_metrics()
    metrics["wait_s"]["lunch"] = 1.0  # a part of an object too
    with pytest.raises(MetricError, match="wait_s: 'lunch' not declared"):
        REGISTRY.check(metrics)


def test_a_scorer_cannot_declare_or_emit_an_undeclared_key() -> None:
    with pytest.raises(MetricError, match="'bananas' not declared"):
        feeds("collisions", "bananas")

    @feeds("collisions")
    def scorer(extra: dict) -> dict:
        return {"collisions": 1, **extra}

    assert scorer({}) == {"collisions": 1} and scorer.feeds == ("collisions",)
    with pytest.raises(MetricError, match=r"scorer.*'bananas' not declared"):
        scorer({"bananas": 2})


def test_a_registry_refuses_a_key_twice_a_clash_and_an_aimless_objective() -> None:
    with pytest.raises(MetricError, match="declared twice: bananas"):
        Registry([bananas(), bananas()])
    clash = Metric("collisions.fleet", "x", COUNT, Better.LOWER, "x", "collisions")
    with pytest.raises(MetricError, match="both a metric and an object of parts: collisions"):
        REGISTRY.plus(clash)
    with pytest.raises(MetricError, match="Pareto objectives need a better direction: bananas"):
        Registry([bananas(View.PARETO, better=Better.NEITHER)])
    with pytest.raises(MetricError, match="'nope' is not a metric"):
        REGISTRY["nope"]


def test_reductions_over_seeds() -> None:
    assert Reduce.MEAN.of([1.0, 2.0, 6.0]) == 3.0
    assert Reduce.SUM.of([1.0, 2.0, 6.0]) == 9.0
    assert Reduce.MAX.of([1.0, 6.0, 2.0]) == 6.0
    assert Reduce.SAME.of([4.0, 4.0]) == 4.0 and Reduce.MEAN.of([]) is None
    with pytest.raises(MetricError, match="differ"):
        Reduce.SAME.of([4.0, 5.0])
    with pytest.raises(MetricError, match="no reduction"):
        Reduce.NONE.of([1.0])


def test_a_runs_value_is_written_with_its_unit_and_decimals() -> None:
    m = metric_registry.metric
    assert m("phantom_freeze_seconds").text(4.25) == "4.2 s"
    assert m("phantom_freezes").text(3) == "3"
    assert m("fleet_efficiency").text(0.5018) == "50.2%"
    assert m("mean_speed_moving").text(1.2248) == "1.22 m/s"
    assert m("ideal_trip_s").text(None) == "n/a"
    assert m("phantom_freeze_seconds").label == "phantom freeze time [s]"
    assert m("stale_free_plans").label == "stale-free plans"


# ---------------------------------------------------------------------------- the views
def test_a_new_metric_shows_in_the_compare_table_with_its_title_and_direction(registry) -> None:
    registry(bananas(View.COMPARE))
    ate = {"dual": [{"bananas": b} for b in (9, 10, 11)],
           "binary": [{"bananas": b} for b in (1, 2, 3)]}  # fmt: skip
    lines = scenario_table("tiny", ate, 3).splitlines()
    header, dual, verdicts = lines[-5], lines[-3], lines[-1]
    assert header.endswith("| time to clear s | bananas |")
    assert dual.endswith("| 10.0 ± 2.5 |")  # t(0.975, 2) * 1 / sqrt(3) = 2.48
    assert verdicts.endswith("| better |")  # more bananas, and higher is better
    registry(bananas(View.COMPARE, better=Better.LOWER, reduce=Reduce.SUM))
    lines = scenario_table("tiny", ate, 3).splitlines()
    assert lines[-3].endswith("| 30.0 (n=3) |") and lines[-1].endswith("| ~ |")  # no interval


def test_a_new_metric_shows_in_the_run_table_and_the_report(registry) -> None:
    registry(bananas(View.RUN_TABLE, View.REPORT_TITLE, View.REPORT_TABLE))
    table = format_table([{"policy": "dual", "bananas": 7}]).splitlines()
    assert table[0].split()[-1] == "bananas" and table[2].split()[-1] == "7"
    record = RunRecord("tiny", "dual", 0, GEOMETRY, metrics={"bananas": 7, "collisions": 1})
    assert title(record).endswith("collisions 1  ·  bananas eaten 7")
    assert throughput_rows(record) == [("bananas eaten", "7")]


def test_the_metrics_channel_takes_its_fields_and_descriptions_from_the_registry(
    registry, monkeypatch: pytest.MonkeyPatch
) -> None:
    sample = CountersSample(2.5, 3, 1, 0, 2, 1, 4, 5)
    message = metrics_channel.metrics_message(sample, freezes=[])
    shown = [m.key for m in REGISTRY.shown_in(View.FOXGLOVE)]
    assert list(message)[1:] == shown
    assert set(metrics_channel.SAMPLED) <= set(shown)  # no counter left off silently
    assert message["events"] == 4 and message["phantom_freeze_seconds"] == 0.0
    assert "phantom_freezes" not in metrics_channel.metrics_message(sample)  # live: unscored
    events = metric_registry.metric("events")
    renamed = Metric("events", "world changes", SECONDS, Better.NEITHER, "-", "run",
                     views=events.views)  # fmt: skip
    swapped = Registry(renamed if m.key == "events" else m for m in REGISTRY)
    monkeypatch.setattr(metric_registry, "REGISTRY", swapped)
    field = metrics_channel.schema()["properties"]["events"]
    assert field == {"type": "number", "minimum": 0, "description": "world changes [s]"}
    assert metrics_channel.metrics_message(sample)["events"] == 4.0  # a number now
    registry(bananas(View.FOXGLOVE))  # neither a counter nor a verdict: not sent silently
    with pytest.raises(MetricError, match="/metrics: 'bananas'"):
        metrics_channel.metrics_message(sample)


def test_a_higher_better_pareto_objective_is_maximised(registry) -> None:
    registry(bananas(View.PARETO))
    run = SweepRun(Path("tiny.yaml"), "tiny", "dual", 0, ())
    few = RunResult(run, "ok", Path("a"), {"phantom_freeze_seconds": 1.0,
                    "stale_free_plans": 0, "bananas": 2})  # fmt: skip
    many = RunResult(SweepRun(Path("tiny.yaml"), "tiny", "binary", 0, ()), "ok", Path("b"),
                     {**few.metrics, "bananas": 5})  # fmt: skip
    used, front = pareto_settings(settings_of([few, many]))
    assert used == ("phantom_freeze_seconds", "stale_free_plans", "bananas")
    assert [s.policy for s in front] == ["binary"]  # equal elsewhere, more bananas


def test_compare_csv_writes_lists_as_json_and_columns_in_registry_order(tmp_path: Path) -> None:
    sweep = Sweep((Path("tiny.yaml"),), ("dual",), (0, 1))
    metrics = full_metrics() | {"time_to_clear_s": [4.5, None], "scenario_collisions": 1}
    old = {"time_to_clear_s": [], "zzz_old_key": 2}  # a run scored before the registry
    results = [
        RunResult(SweepRun(Path("tiny.yaml"), "tiny", "dual", 0, ()), "ok", Path("a"), metrics),
        RunResult(SweepRun(Path("tiny.yaml"), "tiny", "dual", 1, ()), "ok", Path("b"), old),
    ]
    path = tmp_path / "compare.csv"
    write_csv(sweep, results, path)
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
        f.seek(0)
        header = next(csv.reader(f))
    assert [json.loads(r["time_to_clear_s"]) for r in rows] == [[4.5, None], []]
    for row in rows:  # every nested cell reads back as JSON
        for cell in row.values():
            if cell and cell[0] in "[{":
                json.loads(cell)
    roots = [c.split(".")[0] for c in header[3:-4]]
    known = [r for r in roots if r in REGISTRY.json_keys()]
    assert known == sorted(known, key=REGISTRY.json_keys().index)
    assert roots[-1] == "zzz_old_key" and "wait_s.traffic" in header


@given(st.lists(st.none() | st.integers() | st.floats(allow_nan=False, allow_infinity=False)))
def test_a_list_cell_reads_back_as_the_list(values: list) -> None:
    assert json.loads(cell_text(values)) == values


# ---------------------------------------------------------------------------- the docs
def test_the_docs_metric_lists_are_the_registrys() -> None:
    pages = {p: p.read_text() for p in page_files()}
    with_blocks = [p.name for p, text in pages.items() if "<!-- metrics:begin" in text]
    assert {"metrics.md", "throughput.md"} <= set(with_blocks)
    stale = {p.name: stale_blocks(text) for p, text in pages.items() if stale_blocks(text)}
    assert not stale, "run: python -m scenarios.score.metric_docs --write"


def test_a_docs_block_follows_the_registry() -> None:
    page = "intro\n<!-- metrics:begin clearing -->\nold\n<!-- metrics:end clearing -->\nend\n"
    assert stale_blocks(page) == ["clearing"]
    made = rewrite(page)
    assert stale_blocks(made) == [] and made.endswith("<!-- metrics:end clearing -->\nend\n")
    assert "| `time_to_clear_s` | time to clear | s | lower | mean |" in made
    assert block_table("clearing").count("\n") == 3  # header, rule, one metric
    with pytest.raises(ValueError, match="no metric of group 'nope'"):
        block_table("nope")


def test_the_contract_keys_are_those_docs_files_names() -> None:
    text = (ROOT / "docs" / "files.md").read_text()
    bullet = text[text.index("- `metrics.json` of a run") :].split("\n  - ")[0]
    named = re.findall(r"`([a-z_]+)`", bullet)  # not `metrics.json`, nor `{traffic, ...}`
    assert named[0] == "scenario" and set(named) == set(REGISTRY.contract_keys())
