"""A run's ``replay.mcap`` reproduces its server's map bit for bit (every fused scan and
the map settings), and its scene holds the world's objects over time."""

import gc
import json
import math
import shutil
import tempfile
from pathlib import Path

import httpx
import numpy as np
import orjson
import pytest
from mcap.reader import make_reader

from fleet.layout import DEFAULT_HEIGHT_M, Kind, Obstacle
from fleet.shapes import Cylinder
from fleet.world import World
from mapserver.core.occupancy import occupancy_percent
from mapserver.core.scan import PoseStd, Scan
from mapserver.service.replay import belief_for, journal_scans, read_settings
from mapserver.store.offline import fuse_all
from scenarios.cli.main import main
from scenarios.replay.foxglove_messages import OBJECT_COLORS
from scenarios.replay.fused import (
    FUSED_TOPIC,
    fused_message,
    fused_scan,
    read_fused,
    shuffle_f8,
    unshuffle_f8,
)
from scenarios.replay.mcap import REPLAY_FILENAME, read_fused_replay, write_replay
from scenarios.replay.objects import ObjectRecorder
from scenarios.run import runner
from scenarios.run.embedded_server import EmbeddedServer
from scenarios.run.record import RunRecord
from scenarios.spec.scenario import load_scenario

TINY = "scenarios/tiny.yaml"
LAYOUT = Path(__file__).resolve().parents[2] / "scenarios" / "data" / "foxglove-layout.json"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """(scenario, the run's record, its server's data dir, its run folder)."""
    base = tmp_path_factory.mktemp("tiny")
    setup = load_scenario(TINY)
    record = runner.run(setup, data_dir=base / "data")
    (base / "run").mkdir()
    write_replay(record, base / "run" / REPLAY_FILENAME)
    return setup, record, base / "data", base / "run"


def replay(source, out, capsys, *extra):
    assert main(["replay", str(source), "--out", str(out), "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out.splitlines()[-1])


def test_the_replay_holds_every_scan_the_server_fused_in_its_order(tiny):
    _, record, data_dir, run_dir = tiny
    journaled, skipped = journal_scans(data_dir / "journal.sqlite3")
    settings, scans = read_fused_replay(run_dir / REPLAY_FILENAME)
    assert skipped == [] and len(scans) == len(journaled) == record.metrics["scans_fused"] == 400
    assert settings == read_settings(data_dir)
    for scan, (_, fused) in zip(scans, journaled, strict=True):
        assert scan.to_dict(with_ranges=False) == fused.to_dict(with_ranges=False)
        assert scan.ranges.tobytes() == fused.ranges.tobytes()


def test_replaying_the_run_gives_the_servers_journal_map_byte_for_byte(tiny, tmp_path, capsys):
    _, _, data_dir, run_dir = tiny
    from_run = replay(run_dir, tmp_path / "run", capsys)
    from_journal = replay(data_dir, tmp_path / "journal", capsys)
    assert from_run["scans"] == from_journal["scans"] == 400
    assert from_run["cells_updated"] == from_journal["cells_updated"]
    for name in ("logodds.npy", "map.pgm", "map.yaml"):
        assert (tmp_path / "run" / name).read_bytes() == (tmp_path / "journal" / name).read_bytes()
    assert np.count_nonzero(np.load(tmp_path / "run" / "logodds.npy")) > 1000


def test_the_replayed_belief_equals_the_servers_own_map_and_ages(tiny):
    setup, _, data_dir, run_dir = tiny
    settings, scans = read_fused_replay(run_dir / REPLAY_FILENAME)
    belief = belief_for(settings)
    fuse_all(belief, scans)
    with EmbeddedServer(data_dir, setup.server_overrides()) as server:  # the run's map back
        occupancy = httpx.get(server.url + "/v1/map", params={"format": "raw"}).content
        ages = httpx.get(server.url + "/v1/map/age", params={"format": "raw"}).content
        stamp = httpx.get(server.url + "/v1/map/meta").json()["stamp"]
    assert stamp == belief.stamp
    assert occupancy == occupancy_percent(belief.probability_at(belief.stamp)).tobytes()
    assert ages == belief.age_at().astype("<f4").tobytes()


def test_until_replays_the_scans_stamped_up_to_it(tiny, tmp_path, capsys):
    _, _, data_dir, run_dir = tiny
    from_run = replay(run_dir, tmp_path / "r", capsys, "--until", "7.5")
    from_journal = replay(data_dir, tmp_path / "j", capsys, "--until", "7.5")
    journaled, _ = journal_scans(data_dir / "journal.sqlite3", until=7.5)
    assert from_run["scans"] == from_journal["scans"] == len(journaled)
    assert len(journaled) == 2 * 75  # two units, one scan each every 0.1 s from 0.1 s
    run_map = (tmp_path / "r" / "logodds.npy").read_bytes()
    assert run_map == (tmp_path / "j" / "logodds.npy").read_bytes()


def test_the_scene_shows_each_object_and_deletes_the_removed_tote(tiny):
    _, _, _, run_dir = tiny
    shown: dict[float, set[str]] = {}
    deleted: dict[float, set[str]] = {}
    with (run_dir / REPLAY_FILENAME).open("rb") as f:
        for _, _, message in make_reader(f).iter_messages(topics=["/scene"]):
            update = orjson.loads(message.data)
            objects = {e["id"] for e in update["entities"] if e["id"].startswith("object/")}
            if objects or update["deletions"]:
                stamp = message.log_time / 1e9
                shown[stamp] = objects
                deleted[stamp] = {d["id"] for d in update["deletions"]}
    walls = {f"object/wall-{side}" for side in "snwe"}
    first, drop, removal = sorted(shown)
    assert first == pytest.approx(0.1) and 4.0 <= drop < 4.6 and 12.0 <= removal < 12.6
    assert shown[first] == walls | {"object/rack-1"}
    assert shown[drop] == walls | {"object/rack-1", "object/tote-1"}
    assert shown[removal] == shown[first] and deleted[removal] == {"object/tote-1"}
    assert deleted[first] == deleted[drop] == set()


class _Episode:
    """What ``ObjectRecorder`` reads of an episode: the world, the time, the record."""

    def __init__(self, world: World, record: RunRecord) -> None:
        self.world, self.record, self.report = world, record, None

    def at(self, now: float) -> "_Episode":
        self.report = type("Report", (), {"now": now})()
        return self


def test_object_samples_follow_moves_and_removals_and_skip_quiet_steps(tiny):
    setup, *_ = tiny
    record = RunRecord("t", "decay", 0, runner.grid_geometry(12.0, 8.0, 0.1))
    with World(setup.build_layout()) as world:
        episode, recorder = _Episode(world, record), ObjectRecorder(0.5)
        recorder.observe(episode.at(0.0))
        recorder.observe(episode.at(0.5))  # nothing changed: no sample
        world.add(Obstacle("person-1", Kind.PERSON, Cylinder(2.0, 3.0, 0.25)))
        world.move("rack-1", 5.0, 4.5, math.pi / 2)
        recorder.observe(episode.at(1.0))
        world.remove("person-1")
        recorder.observe(episode.at(1.5))
    assert [s.stamp for s in record.objects] == [0.0, 1.0, 1.5]
    rack = {s.stamp: o for s in record.objects for o in s.objects if o.object_id == "rack-1"}
    assert (rack[0.0].x, rack[0.0].y, rack[0.0].yaw) == (6.0, 4.0, 0.0)
    assert (rack[1.0].x, rack[1.0].y, rack[1.0].yaw) == (5.0, 4.5, math.pi / 2)
    assert (rack[1.0].size_x, rack[1.0].size_y, rack[1.0].height) == (6.0, 2.0, 2.5)
    person = next(o for o in record.objects[1].objects if o.object_id == "person-1")
    assert (person.kind, person.round, person.size_x, person.height) == ("person", True, 0.5, 1.75)
    assert "person-1" not in {o.object_id for o in record.objects[2].objects}
    assert len(record.objects[0].objects) == 5 == len(record.objects[2].objects)


@pytest.mark.parametrize("pose_std", [None, PoseStd(0.02, 0.01)])
def test_a_fused_scan_message_gives_the_scan_back_bit_for_bit(pose_std):
    scan = Scan.from_dict(
        {"unit_id": "u-1", "stamp": 0.1 + 0.2, "pose": {"x": 1 / 3, "y": 2e-17, "yaw": -math.pi},
         "angle_min": -3.141592653589793, "angle_increment": 2 * math.pi / 7,
         "range_min": 0.05, "range_max": 20.0,
         "ranges": [1.2000000000000002, None, math.inf, 25.0, 0.01, 5e-324, 19.999999999999996],
         **({} if pose_std is None else {"pose_std": {"xy": pose_std.xy, "yaw": pose_std.yaw}})}
    )  # fmt: skip
    seq, back = fused_scan(fused_message(7, scan))
    assert seq == 7 and back.to_dict(with_ranges=False) == scan.to_dict(with_ranges=False)
    assert back.ranges.tobytes() == scan.ranges.tobytes() and back.pose_std == pose_std


def test_a_replay_without_fused_scans_falls_back_to_its_laser_scans(tiny, tmp_path, capsys):
    _, record, _, _ = tiny
    outside = RunRecord(record.scenario, record.policy, record.seed, record.geometry)
    outside.scans = record.scans
    write_replay(outside, tmp_path / REPLAY_FILENAME)
    with (tmp_path / REPLAY_FILENAME).open("rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert FUSED_TOPIC not in topics and "/units/u1/scan" in topics
    assert read_fused_replay(tmp_path / REPLAY_FILENAME) is None
    assert main(["replay", str(tmp_path), "--out", str(tmp_path / "m"), "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out.splitlines()[-1])["scans"] == len(record.scans) < 400
    assert "approximation" in err


def test_shuffled_ranges_are_byte_planes_and_refuse_a_partial_value():
    values = np.array([1.0, -2.5, np.nan, np.inf])
    planes = shuffle_f8(values)
    assert planes[:4] == bytes(values.astype("<f8").view(np.uint8)[0::8])  # every byte 0
    assert planes[-4:] == bytes(values.astype("<f8").view(np.uint8)[7::8])  # every byte 7
    assert unshuffle_f8(planes).tobytes() == values.astype("<f8").tobytes()
    with pytest.raises(ValueError, match="not whole float64"):
        unshuffle_f8(planes[:-1])


def test_a_runs_temporary_folder_goes_when_its_fused_scans_do(tiny):
    _, _, data_dir, _ = tiny
    folder = tempfile.TemporaryDirectory()
    shutil.copytree(data_dir, Path(folder.name) / "data")
    fused = read_fused(Path(folder.name) / "data", folder)
    assert [seq for seq, _ in fused.scans()] == list(range(1, 401))
    del fused
    gc.collect()
    assert not Path(folder.name).exists()


# ------------------------------------------------------------------------------ Foxglove
def _messages(run_dir, topic):
    with (run_dir / REPLAY_FILENAME).open("rb") as f:
        return [
            (m.log_time, orjson.loads(m.data))
            for _, _, m in make_reader(f).iter_messages(topics=[topic], log_time_order=True)
        ]


def test_the_scene_draws_each_obstacle_of_the_layout_with_its_pose_size_and_colour(tiny):
    setup, _, _, run_dir = tiny
    updates = [u for _, u in _messages(run_dir, "/scene")]
    first = next(u for u in updates if u["entities"][0]["id"].startswith("object/"))
    drawn = {e["id"]: e for e in first["entities"]}
    obstacles = setup.build_layout().obstacles
    assert set(drawn) == {f"object/{o.id}" for o in obstacles}
    for obstacle in obstacles:
        entity = drawn[f"object/{obstacle.id}"]
        (cube,) = entity["cubes"]
        height = DEFAULT_HEIGHT_M[obstacle.kind]
        box = obstacle.shape
        assert cube["size"] == {"x": box.size_x, "y": box.size_y, "z": height}
        assert cube["pose"]["position"] == {"x": box.x, "y": box.y, "z": height / 2}
        r, g, b, a = OBJECT_COLORS[obstacle.kind.value]
        assert cube["color"] == {"r": r, "g": g, "b": b, "a": a}
        assert {"key": "kind", "value": obstacle.kind.value} in entity["metadata"]
    assert OBJECT_COLORS["rack"] != OBJECT_COLORS["wall"]


def test_tf_moves_each_units_frame_with_its_recorded_pose(tiny):
    _, record, _, run_dir = tiny
    frames = {}
    for ns, message in _messages(run_dir, "/tf"):
        for t in message["transforms"]:
            assert t["parent_frame_id"] == "map"
            q = t["rotation"]
            yaw = 2 * math.atan2(q["z"], q["w"])
            frames[(ns, t["child_frame_id"])] = (t["translation"]["x"], t["translation"]["y"], yaw)
    expected = {(round(u.stamp * 1e9), f"{u.unit_id}/base_link"): u for u in record.units}
    assert set(frames) == set(expected) and len(frames) == 2 * 40  # 2 units every 0.5 s
    for key, unit in expected.items():
        x, y, yaw = frames[key]
        assert (x, y) == (unit.x, unit.y)
        assert math.remainder(yaw - unit.yaw, math.tau) == pytest.approx(0, abs=1e-12)


def test_the_last_metrics_message_holds_the_runs_metrics(tiny):
    _, record, _, run_dir = tiny
    metrics = _messages(run_dir, "/metrics")
    assert [ns for ns, _ in metrics] == [round(c.stamp * 1e9) for c in record.counters]
    ns, last = metrics[-1]
    assert ns == round(record.metrics["sim_seconds"] * 1e9)
    for key in ("tasks_completed", "phantom_freezes", "phantom_freeze_seconds",
                "true_block_freezes", "stale_free_plans", "collisions", "scenario_collisions",
                "events"):  # fmt: skip
        assert last[key] == record.metrics[key], key
    done = [m["tasks_completed"] for _, m in metrics]
    assert done == sorted(done) and done[-1] == len(record.trips)


def test_the_shipped_foxglove_layout_names_only_the_replays_topics_and_fields(tiny):
    _, _, _, run_dir = tiny
    layout = json.loads(LAYOUT.read_text())
    with (run_dir / REPLAY_FILENAME).open("rb") as f:
        summary = make_reader(f).get_summary()
    schemas = {
        ch.topic: json.loads(summary.schemas[ch.schema_id].data) for ch in summary.channels.values()
    }
    panels = layout["configById"]
    assert set(_leaves(layout["layout"])) == set(panels)
    three_d, plots = panels["3D!fleetmap"], [v for k, v in panels.items() if k[:5] == "Plot!"]
    named = set(three_d["topics"]) | {panels["RosOut!log"]["topicToRender"]}
    named.add(panels["RawMessages!metrics"]["topicPath"])
    assert {"/map/costmap", "/scene", "/metrics", "/metrics/map_truth"} <= named | {
        p["value"].split(".")[0] for plot in plots for p in plot["paths"]
    }
    assert named <= set(schemas)
    for plot in plots:
        for path in plot["paths"]:
            topic, field = path["value"].split(".")
            assert field in schemas[topic]["properties"], path["value"]
            assert schemas[topic]["properties"][field]["type"] in ("integer", "number")
    assert three_d["topics"]["/map/costmap"]["colorMode"] == "rgba-fields"
    assert three_d["followTf"] == "map"


def _leaves(node):
    if isinstance(node, str):
        return [node]
    return _leaves(node["first"]) + _leaves(node["second"])
