"""``fleetmap run`` end to end on the tiny scenario: outputs, contract keys, determinism."""

import json

import pytest
from mcap.reader import make_reader

from scenarios.cli import main
from scenarios.embedded_server import EmbeddedServer
from scenarios.spec import load_scenario

TINY = "scenarios/tiny.yaml"
CONTRACT_KEYS = {
    "scenario", "policy", "seed", "units", "sim_seconds", "wall_seconds", "tasks_completed",
    "phantom_freezes", "phantom_freeze_seconds", "true_block_freezes", "stale_free_plans",
    "collisions", "time_to_clear_s", "replans", "deadlocks", "scans_fused",
}  # fmt: skip


def run(tmp_path, name, *extra):
    out = tmp_path / name
    assert main(["run", TINY, "--out", str(out), "--json", *extra]) == 0
    return out, json.loads((out / "metrics.json").read_text())


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    return run(tmp_path_factory.mktemp("runs"), "a")


def test_a_run_writes_every_output_with_every_contract_key(first_run, capsys):
    out, metrics = first_run
    assert CONTRACT_KEYS <= set(metrics)
    assert metrics["scenario"] == "tiny" and metrics["policy"] == "decay"
    assert metrics["sim_seconds"] == pytest.approx(20.0)
    assert metrics["scans_fused"] == 2 * 20 * 10  # two units at 10 Hz
    assert len(metrics["time_to_clear_s"]) == 1  # one removal event
    assert isinstance(json.loads((out / "freezes.json").read_text()), list)
    assert (out / "report.png").read_bytes()[:4] == b"\x89PNG"
    with (out / "replay.mcap").open("rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert {"/map/costmap", "/map/occupancy", "/scene", "/log", "/units/u1/scan"} <= topics


def test_same_seed_same_metrics_with_and_without_a_server(first_run, tmp_path):
    _, metrics = first_run
    _, again = run(tmp_path, "b")
    scenario = load_scenario(TINY)
    with EmbeddedServer(tmp_path / "data", scenario.server_overrides()) as server:
        _, served = run(tmp_path, "c", "--server", server.url)
    for other in (again, served):
        assert {k: v for k, v in other.items() if k != "wall_seconds"} == {
            k: v for k, v in metrics.items() if k != "wall_seconds"
        }


def test_a_bad_scenario_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nduration: -5\n")
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "bad.yaml" in capsys.readouterr().err
