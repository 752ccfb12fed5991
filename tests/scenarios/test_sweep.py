"""``fleetmap sweep``: the sweep file, its runs, the process pool, results.csv and the
trade-off plot, the missing-Ray error, and (when Ray is installed) a local Ray."""

from __future__ import annotations

import csv
import importlib.util
import json
import sys
from pathlib import Path

import pytest
from scenario_helpers import TINY, tiny5

from scenarios.cli.main import main
from scenarios.score.metric_registry import REGISTRY, metric
from scenarios.sweep.parallel import MissingExtraError, import_ray, run_sweep
from scenarios.sweep.pareto import dominates
from scenarios.sweep.sweep_file import ScenarioError, SweepRun, expand, load_sweep

HALF_LIFE = "map_server.decay.half_life_occupied"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def write_sweep(folder: Path, text: str) -> Path:
    path = folder / "sweep.yaml"
    path.write_text(text)
    return path


SWEEP = f"""\
scenarios: [tiny5.yaml]
policies: [decay, sticky]
seeds: [3]
parameters:
  {HALF_LIFE}: [10, 120]
duration: 5
"""


# ---------------------------------------------------------------------------- expansion
def test_sweep_file_expands_to_every_combination_in_order(tmp_path: Path) -> None:
    tiny5(tmp_path)
    text = f"""\
scenarios: [tiny5.yaml]
policies: [binary, decay]
seeds: {{count: 2, start: 5}}
parameters:
  {HALF_LIFE}: [10, 30, 120]
  map_server.decay.half_life_free: [60]
duration: 5
"""
    sweep = load_sweep(write_sweep(tmp_path, text))
    runs = expand(sweep)
    assert len(runs) == 2 * 3 * 1 * 2
    assert [(r.policy, dict(r.parameters)[HALF_LIFE], r.seed) for r in runs[:4]] == [
        ("binary", 10, 5),
        ("binary", 10, 6),
        ("binary", 30, 5),
        ("binary", 30, 6),
    ]
    assert runs == expand(load_sweep(tmp_path / "sweep.yaml"))  # deterministic
    first = runs[0]
    assert first.scenario == (tmp_path / "tiny5.yaml").resolve()
    assert first.overrides() == {
        HALF_LIFE: 10,
        "map_server.decay.half_life_free": 60,
        "duration": 5.0,
    }
    assert first.folder() == Path(
        "tiny5", "binary", f"{HALF_LIFE}=10__map_server.decay.half_life_free=60", "seed5"
    )
    assert len({r.folder() for r in runs}) == len(runs)  # one folder per run


def test_defaults_all_policies_seed_zero_and_no_parameter_folder(tmp_path: Path) -> None:
    tiny5(tmp_path)
    runs = expand(load_sweep(write_sweep(tmp_path, "scenarios: [tiny5.yaml]\n")))
    assert [r.policy for r in runs] == ["dual", "decay", "binary", "sticky"]
    assert {r.seed for r in runs} == {0}
    assert runs[0].folder() == Path("tiny5", "dual", "seed0")
    assert runs[0].overrides() == {}


@pytest.mark.parametrize(
    ("text", "field", "line"),
    [
        ("policies: [decay]\n", "scenarios", None),
        ("scenarios: [nope.yaml]\n", "scenarios[0]", 1),
        ("scenarios: [tiny5.yaml]\npolicies: [decay, greedy]\n", "policies[1]", 2),
        ("scenarios: [tiny5.yaml]\nseeds: [0, -1]\n", "seeds[1]", 2),
        ("scenarios: [tiny5.yaml]\nseeds: {count: 0}\n", "seeds.count", 2),
        ("scenarios: [tiny5.yaml]\nseeds: {cout: 2}\n", "seeds.cout", 2),
        ("scenarios: [tiny5.yaml]\nduration: -5\n", "duration", 2),
        ("scenarios: [tiny5.yaml]\nparameters: {a.b: 10}\n", "parameters.a.b", 2),
        ("scenarios: [tiny5.yaml]\nparameters: {'a b': [1]}\n", "parameters.a b", 2),
        ("scenarios: [tiny5.yaml]\nparameters: {x: [[1]]}\n", "parameters.x[0]", 2),
        ("scenarios: [tiny5.yaml]\nsweeps: 3\n", "sweeps", 2),
    ],
)
def test_bad_sweep_file_names_the_file_line_and_field(
    tmp_path: Path, text: str, field: str, line: int | None
) -> None:
    tiny5(tmp_path)
    path = write_sweep(tmp_path, text)
    with pytest.raises(ScenarioError) as err:
        load_sweep(path)
    assert err.value.field == field
    assert err.value.source == str(path)
    if line is not None:
        assert err.value.line == line


def test_parameter_the_scenario_rejects_fails_before_any_run(tmp_path: Path) -> None:
    tiny5(tmp_path)
    path = write_sweep(tmp_path, f"scenarios: [tiny5.yaml]\nparameters:\n  {HALF_LIFE}: [10, -4]\n")
    with pytest.raises(ScenarioError) as err:
        load_sweep(path)
    assert err.value.field == "parameters"
    assert HALF_LIFE in str(err.value) and "-4" in str(err.value)


# ---------------------------------------------------------------------------- running
@pytest.fixture(scope="module")
def swept(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """``fleetmap sweep`` of SWEEP (4 runs of 5 s) on 2 workers: (out folder, exit code)."""
    folder = tmp_path_factory.mktemp("sweep")
    tiny5(folder)
    path = write_sweep(folder, SWEEP)
    out = folder / "out"
    code = main(["sweep", str(path), "--workers", "2", "--out", str(out)])
    return out, code


def read_rows(out: Path) -> list[dict[str, str]]:
    with (out / "results.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def test_sweep_writes_one_row_per_run_with_every_contract_metric(
    swept: tuple[Path, int],
) -> None:
    out, code = swept
    assert code == 0
    rows = read_rows(out)
    assert [(r["policy"], r[HALF_LIFE]) for r in rows] == [
        ("decay", "10"),
        ("decay", "120"),
        ("sticky", "10"),
        ("sticky", "120"),
    ]
    for row in rows:
        assert row["status"] == "ok" and row["error"] == ""
        assert row["scenario"] == "tiny5" and row["seed"] == "3"
        for key in REGISTRY.contract_keys():
            if REGISTRY.parts(key):  # an object: a column per leaf
                continue
            assert key in row, key
        assert float(row["sim_seconds"]) == pytest.approx(5.0)
        folder = Path(row["out_dir"])
        assert folder == out / "tiny5" / row["policy"] / f"{HALF_LIFE}={row[HALF_LIFE]}" / "seed3"
        assert (folder / "metrics.json").is_file()
    # the tote is removed at 3 s: one time-to-clear entry per removal event
    assert all(len(r["time_to_clear_s"].split(";")) == 1 for r in rows)
    # objects are columns by dotted path, numbers in them (not Python reprs)
    for row in rows:
        assert "map_truth" not in row and "wait_s" not in row
        float(row["map_truth.forgotten_cells.mean"])
        assert float(row["wait_s.traffic"]) >= 0.0


def test_sweep_writes_a_png_tradeoff_plot(swept: tuple[Path, int]) -> None:
    out, _ = swept
    data = (out / "tradeoff.png").read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 5_000


def test_sweep_writes_the_undominated_settings_to_pareto_csv(swept: tuple[Path, int]) -> None:
    out, _ = swept
    with (out / "pareto.csv").open(newline="") as f:
        front = list(csv.DictReader(f))
    names = ["phantom_freeze_seconds", "stale_free_plans", "map_truth.forgotten_cells"]
    runs = {}  # one seed per setting: (policy, half-life) -> that run's objectives
    for r in read_rows(out):
        metrics = json.loads((Path(r["out_dir"]) / "metrics.json").read_text())
        runs[(r["policy"], r[HALF_LIFE])] = [metric(n).number(metrics) for n in names]
    if any(point[2] is None for point in runs.values()):  # map_truth is optional
        names.pop(2)
        runs = {k: point[:2] for k, point in runs.items()}
    columns = [n.removeprefix("map_truth.") for n in names]
    assert front and list(front[0]) == ["scenario", "policy", HALF_LIFE, "seeds", *columns]
    for row in front:
        point = [float(row[c]) for c in columns]
        assert row["seeds"] == "1"
        assert point == pytest.approx(runs[(row["policy"], row[HALF_LIFE])], abs=1e-6)
        assert not any(dominates(other, point) for other in runs.values())
    kept = {(row["policy"], row[HALF_LIFE]) for row in front}
    for key, point in runs.items():  # a setting left out is beaten by one kept
        assert key in kept or any(dominates(runs[k], point) for k in kept)


def test_failed_run_is_recorded_not_fatal(tmp_path: Path) -> None:
    good = SweepRun(tiny5(tmp_path), "tiny5", "binary", 0, (), 4.0)
    bad = SweepRun(TINY, "tiny", "decay", 0, (), 5.0)  # tiny's events fall after 5 s
    seen = []
    results = run_sweep([bad, good], tmp_path / "out", workers=2, on_result=seen.append)
    assert [r.run for r in results] == [bad, good]
    assert len(seen) == 2
    assert results[0].status == "error"
    assert "events[1].at" in results[0].error and "duration" in results[0].error
    assert results[1].status == "ok" and results[1].metrics["sim_seconds"] == 4.0


# ---------------------------------------------------------------------------- ray
def test_missing_ray_names_the_extra(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(MissingExtraError, match=r"fleetmap\[ray\]"):
        import_ray()
    tiny5(tmp_path)
    path = write_sweep(tmp_path, SWEEP)
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--ray", "local", "--out", str(out)]) == 2
    assert not (out / "results.csv").exists()


@pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="ray is not installed (optional extra fleetmap[ray]); the local-Ray test needs it",
)
def test_sweep_on_a_local_ray(tmp_path: Path) -> None:
    tiny5(tmp_path)
    path = write_sweep(tmp_path, "scenarios: [tiny5.yaml]\npolicies: [decay, sticky]\n"
                       "duration: 3\n")  # fmt: skip
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--ray", "local", "--out", str(out)]) == 0
    rows = read_rows(out)
    assert [(r["policy"], r["status"]) for r in rows] == [("decay", "ok"), ("sticky", "ok")]
    assert (out / "tradeoff.png").read_bytes().startswith(PNG_MAGIC)
