"""``fleetmap run`` end to end on the tiny scenario: outputs, contract keys, determinism."""

import json
from dataclasses import replace

import httpx
import numpy as np
import pytest
from conftest import make_scan
from mcap.reader import make_reader
from scenario_helpers import shortened

from mapserver.client import MapClient
from scenarios.cli.main import main
from scenarios.run import runner
from scenarios.run.embedded_server import EmbeddedServer
from scenarios.score.metric_registry import REGISTRY
from scenarios.spec.scenario import load_scenario

TINY = "scenarios/tiny.yaml"
BUSY = "scenarios/busy_shift.yaml"
CONTRACT_KEYS = {
    "scenario", "policy", "seed", "units", "sim_seconds", "wall_seconds", "tasks_completed",
    "phantom_freezes", "phantom_freeze_seconds", "true_block_freezes", "stale_free_plans",
    "collisions", "time_to_clear_s", "replans", "deadlocks", "scans_fused",
    "trips_per_unit_hour", "ideal_trip_s", "trip_time_ratio", "fleet_efficiency",
    "moving_share", "mean_speed_moving", "wait_s", "map_truth",
}  # fmt: skip
WAIT_CAUSES = {"traffic", "freeze", "dwell", "breakdown", "turn"}  # "turn": beyond docs/files.md


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
    REGISTRY.check(metrics)  # every key declared in the metric registry, none missing
    assert metrics["scenario"] == "tiny" and metrics["policy"] == "dual"  # the default
    assert metrics["sim_seconds"] == pytest.approx(20.0)
    assert metrics["scans_fused"] == 2 * 20 * 10  # two units at 10 Hz
    assert len(metrics["time_to_clear_s"]) == 1  # one removal event
    assert isinstance(json.loads((out / "freezes.json").read_text()), list)
    collisions = json.loads((out / "collisions.json").read_text())
    assert sum(c["cause"] == "fleet" for c in collisions) == metrics["collisions"]
    trips = json.loads((out / "trips.json").read_text())
    assert sum(t["done"] is not None for t in trips) == metrics["tasks_completed"]
    assert metrics["trips_returned"] == sum(
        a["outcome"] == "returned" for t in trips for a in t["attempts"]
    )
    for key in ("trips_per_unit_hour", "fleet_efficiency", "moving_share", "mean_speed_moving"):
        assert isinstance(metrics[key], float) and metrics[key] >= 0, key
    for key in ("ideal_trip_s", "trip_time_ratio"):  # null: no trip completed
        assert metrics[key] is None or isinstance(metrics[key], float), key
    assert (metrics["ideal_trip_s"] is None) == (metrics["tasks_completed"] == 0)
    assert set(metrics["wait_s"]) == WAIT_CAUSES
    assert all(isinstance(s, float) and s >= 0 for s in metrics["wait_s"].values())
    assert sum(metrics["wait_s"].values()) <= 2 * 20.0  # unit-seconds: two units, 20 s
    truth = metrics["map_truth"]
    assert set(truth) == {"phantom_cells", "forgotten_cells", "unknown_share"}
    for key in ("phantom_cells", "forgotten_cells"):
        assert isinstance(truth[key]["final"], int) and truth[key]["final"] >= 0, key
        assert truth[key]["mean"] >= 0, key
    assert all(0.0 <= truth["unknown_share"][k] <= 1.0 for k in ("mean", "final"))
    assert (out / "report.png").read_bytes()[:4] == b"\x89PNG"
    with (out / "replay.mcap").open("rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert {"/map/costmap", "/map/occupancy", "/scene", "/log", "/units/u1/scan",
            "/metrics/map_truth"} <= topics  # fmt: skip


def test_a_server_whose_map_holds_scans_is_refused_before_anything_is_sent(tmp_path, capsys):
    scenario = load_scenario(TINY)
    with EmbeddedServer(tmp_path / "data", scenario.server_overrides()) as server:
        with httpx.Client(base_url=server.url, timeout=60) as http:
            client = MapClient(http)
            client.post_scan(make_scan([2.0] * 10, x=2.0, y=2.0, stamp=12.5))
            before = client.map_meta().version
            out = tmp_path / "refused"
            assert main(["run", TINY, "--out", str(out), "--server", server.url]) == 2
            assert client.map_meta().version == before
    assert capsys.readouterr().err.splitlines()[-1] == (
        "fleetmap run: error: --server: its map already holds scans up to stamp 12.5 s, and a "
        "run's units stamp their scans in sim time from 0 s: run against a server with an "
        "empty map (a new data dir; with docker compose, `down -v` first)"
    )
    assert not (out / "metrics.json").exists()


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


def test_a_floor_served_by_zones_runs_as_one_server_would():
    """busy_shift's 100 m floor cut to 30 s, under one map server and under three (strips
    of 33 m, borders of 20.7 m): the same metrics but the wall time, trips, freezes and
    collisions, and every sampled costmap and occupancy grid the same bytes (the version
    aside: it counts each zone's scans); the zones' journals, merged, are the one
    server's."""
    records = {
        zones: runner.run(replace(load_scenario(BUSY, {"map_server.zones": zones}), duration=30.0))
        for zones in (1, 3)
    }
    one, three = records[1], records[3]
    for record in (one, three):
        record.metrics.pop("wall_seconds")
    assert one.metrics == three.metrics and one.metrics["scans_fused"] > 0
    assert (one.trips, one.freezes, one.collisions) == (
        three.trips,
        three.freezes,
        three.collisions,
    )
    assert len(one.grids) == len(three.grids) > 0
    for mine, zoned in zip(one.grids, three.grids, strict=True):
        assert mine.stamp == zoned.stamp
        np.testing.assert_array_equal(mine.costs, zoned.costs)
        np.testing.assert_array_equal(mine.occupancy, zoned.occupancy)
    # what the zones fused, merged: the one server's journal, scan for scan
    assert three.fused.settings == one.fused.settings
    mine = [(seq, scan.digest()) for seq, scan in one.fused.scans()]
    assert [(seq, scan.digest()) for seq, scan in three.fused.scans()] == mine
    assert len(mine) == one.metrics["scans_fused"]


def test_zones_are_a_run_option_checked_as_the_scenario_key(first_run, tmp_path, capsys):
    _, metrics = first_run
    _, zoned = run(tmp_path, "zoned", "--zones", "2")
    assert {k: v for k, v in zoned.items() if k != "wall_seconds"} == {
        k: v for k, v in metrics.items() if k != "wall_seconds"
    }
    capsys.readouterr()
    assert main(["run", TINY, "--out", str(tmp_path / "bad"), "--zones", "0"]) == 2
    assert "map_server.zones (override): must be an integer of map servers in [1, 64], got 0" in (
        capsys.readouterr().err
    )
    both = ["run", TINY, "--out", str(tmp_path / "both"), "--zones", "2", "--server", "http://x"]
    assert main(both) == 2
    assert "--zones: a run against --server uses that one server" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists() and not (tmp_path / "both").exists()


def test_a_bad_scenario_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nduration: -5\n")
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "bad.yaml" in capsys.readouterr().err


@pytest.mark.parametrize(
    "name",
    ["static_shift", "moved_pod", "dropped_tote", "person_crossing", "busy_shift",
     "hundred_units"],
)  # fmt: skip
def test_every_shipped_scenario_runs_to_completion(tmp_path, name):
    """Cut to the first 10 simulated seconds (later events never fire); the full runs take
    minutes (busy_shift and hundred_units ~3-5)."""
    scenario = replace(load_scenario(f"scenarios/{name}.yaml"), duration=10.0)
    record = runner.run(scenario)
    assert CONTRACT_KEYS <= set(record.metrics)
    assert record.metrics["sim_seconds"] == pytest.approx(10.0)
    assert record.metrics["scans_fused"] > 0


def test_a_pod_moved_out_of_a_dead_end_makes_a_phantom_freeze_under_sticky(tmp_path):
    """The pod moves at 60 s; the run ends at 110 s, with units frozen at its old place."""
    scenario_out = tmp_path / "moved"
    path = str(shortened(tmp_path, "moved_pod", 110.0))
    assert main(["run", path, "--policy", "sticky", "--out", str(scenario_out), "--json"]) == 0
    metrics = json.loads((scenario_out / "metrics.json").read_text())
    freezes = json.loads((scenario_out / "freezes.json").read_text())
    assert metrics["phantom_freezes"] >= 1 and metrics["phantom_freeze_seconds"] > 0
    assert metrics["time_to_clear_s"] == [None]  # sticky never forgets the pod
    phantom = [f for f in freezes if f["phantom"]]
    assert phantom
    for freeze in phantom:  # phantom seconds only once the pod has moved, at 60 s
        segments = freeze["segments"]
        assert all(s["start"] >= 60.0 for s in segments if s["kind"] == "phantom")
        assert sum(s["end"] - s["start"] for s in segments) == pytest.approx(freeze["duration"])
        if freeze["start"] >= 60.0:  # all of it after: its cells are truly free
            assert not any(cell["truly_occupied"] for cell in freeze["blocking_cells"])
    assert metrics["phantom_freeze_seconds"] == pytest.approx(
        sum(f["phantom_s"] for f in freezes), abs=1e-3
    )


def test_a_dropped_tote_never_removed_is_a_true_block_never_a_phantom(tmp_path):
    """The tote drops at 30 s; the run ends at 90 s."""
    out = tmp_path / "tote"
    path = str(shortened(tmp_path, "dropped_tote", 90.0))
    assert main(["run", path, "--out", str(out), "--json"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["true_block_freezes"] >= 1
    assert metrics["phantom_freezes"] == 0


def test_replay_rebuilds_a_map_from_a_runs_replay(first_run, tmp_path, capsys):
    out, metrics = first_run
    assert main(["replay", str(out), "--out", str(tmp_path / "map"), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert figures["scans"] == metrics["scans_fused"]  # every scan the server fused
    assert (tmp_path / "map" / "map.yaml").is_file()
