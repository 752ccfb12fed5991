"""The writers of a scenario run's outputs: freezes.json, collisions.json, report.png and
replay.mcap (docs/files.md), from a small RunRecord made by hand."""

from __future__ import annotations

import base64
import json
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from PIL import Image

from fleet.sim import CollisionEvent
from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import BEAM_INVALID, BEAM_NO_RETURN, BEAM_RETURN, PoseStd, classify_ranges
from planner.freeze import Segment
from scenarios.replay.channels import SCHEMAS
from scenarios.replay.costmap_palette import COSTMAP_RGBA
from scenarios.replay.foxglove_messages import decode_ranges, encode_ranges
from scenarios.replay.mcap import ReplayFileError, read_geometry, read_scans, write_replay
from scenarios.run.record import (
    BlockingCell,
    CountersSample,
    EventRecord,
    FreezeRecord,
    GridSample,
    ObjectsSample,
    ObjectState,
    PlanSample,
    RecoveryStep,
    RunRecord,
    ScanSample,
    UnitSample,
)
from scenarios.score.collisions_json import write_collisions
from scenarios.score.freezes_json import write_freezes
from scenarios.score.incidents import (
    CollisionIncident,
    ContactCell,
    PlanContext,
    collision_counts,
)
from scenarios.score.report import throughput_rows, title, write_report

GEOMETRY = GridGeometry(width=40, height=30, resolution=0.25, origin_x=-1.0, origin_y=-0.5)
UNITS = ("u1", "u2", "u10")
INF, NAN = math.inf, math.nan


def _scan(unit: str, stamp: float, ranges, yaw: float = 0.3, std: PoseStd | None = None):
    return ScanSample(
        stamp=stamp,
        unit_id=unit,
        x=1.5 + stamp / 10,
        y=2.25,
        yaw=yaw,
        angle_min=-1.5,
        angle_increment=0.5,
        range_min=0.1,
        range_max=8.0,
        ranges=np.asarray(ranges, dtype=np.float32),
        pose_std=std,
    )


def _grid(stamp: float, version: int) -> GridSample:
    costs = np.full(GEOMETRY.shape, FREE, dtype=np.uint8)
    costs[:5, :] = UNKNOWN
    costs[10:12, 20:24] = LETHAL
    costs[9, 20:24] = INSCRIBED
    costs[8, 20:24] = 120 + version
    occupancy = np.where(costs == UNKNOWN, -1, np.where(costs == LETHAL, 100, 0)).astype(np.int8)
    return GridSample(stamp, version, costs, occupancy)


def make_record() -> RunRecord:
    """Three units for 10 s, two object samples (a pod removed, a tote dropped), three
    grids, seven scans (two units), four plans (one stale-free, one inscribed), three
    events, two freezes (u1 true block for 1 s then phantom for 1.5 s, u2 a true-block
    lane freeze), two collision incidents (u2 drove into the tote twice, the person
    walked into u10) and three counters samples."""
    record = RunRecord("moved_pod", "sticky", 7, GEOMETRY, unit_radius=0.35, unit_height=0.5)
    for i in range(21):
        t = i * 0.5
        for k, unit in enumerate(UNITS):
            frozen = unit == "u1" and 3.5 <= t < 6.0
            record.units.append(
                UnitSample(t, unit, 1.0 + k + t / 5, 2.0 + k, 0.1 * k, not frozen, frozen, "pick")
            )
    pod = ObjectState("p1", "pod", 4.0, 3.0, 1.0, 1.0, 0.0, 2.0, False)
    person = ObjectState("h1", "person", 6.0, 1.0, 0.5, 0.5, 0.0, 1.7, True)
    tote = ObjectState("t1", "tote", 2.0, 5.0, 0.4, 0.6, 0.5, 0.3, False)
    record.objects += [ObjectsSample(0.0, (pod, person)), ObjectsSample(3.0, (person, tote))]
    record.grids += [_grid(0.0, 1), _grid(5.0, 2), _grid(10.0, 3)]
    std = PoseStd(xy=0.05, yaw=0.01)
    record.scans += [
        _scan("u1", 0.5, [1.0, INF, NAN, 2.5, 7.99], std=std),
        _scan("u1", 1.0, [1.2345678, 1.0, 9.5, -INF, 0.05], yaw=3.1, std=std),
        _scan("u1", 9.5, [0.5, 0.6, 0.7, 0.8, 0.9], yaw=-2.0, std=std),
        _scan("u2", 0.5, [INF] * 5),
        _scan("u2", 2.0, [3.0, 3.0, NAN, NAN, 3.0], yaw=4.0),
        _scan("u2", 6.0, [2.0, 2.0, 2.0, 2.0, 2.0]),
        _scan("u2", 7.25, [1.0, 1.0, 1.0, 1.0, 1.0]),
    ]
    record.plans += [
        PlanSample(1.0, "u1", ((1.0, 2.0), (2.0, 2.0), (3.0, 3.0))),
        PlanSample(2.5, "u2", ((2.0, 3.0), (4.0, 3.0)), stale_cells=((4.0, 3.0),)),
        PlanSample(4.0, "u1", ()),
        PlanSample(4.5, "u1", ((1.0, 2.0), (3.0, 2.0)), inscribed_cells=((2.0, 2.0),)),
    ]
    record.events += [
        EventRecord(2.0, "drop", "t1", 2.0, 5.0, "a tote falls into aisle A"),
        EventRecord(3.0, "remove", "p1", 4.0, 3.0, "pod p1 is taken away"),
        EventRecord(4.0, "person", "h1", 6.0, 1.0, "a person crosses"),
    ]
    record.freezes += [
        FreezeRecord(
            "u2",
            5.0,
            1.5,
            (Segment(5.0, 6.5, "true_block", "no lane route on ground truth"),),
            "tote in the aisle",
            3.0,
            4.0,
            (BlockingCell(2.125, 4.875, True, 0.97, 4.75, (("u2", 4.75),)),),
            (RecoveryStep(5.5, "wait", "path blocked"),),
            lanes=(("j1_2", "s-1"),),
        ),
        FreezeRecord(
            "u1",
            3.5,
            2.5,
            (
                Segment(3.5, 4.5, "true_block", "its goal lies in p1"),
                Segment(4.5, 6.0, "phantom", "ground truth has a path (p1 removed at 4.5 s)"),
            ),
            "no admissible path",
            1.7,
            2.0,
            (
                BlockingCell(4.125, 3.125, False, 0.912345678, 2.9, (("u1", 2.9), ("u2", 2.0))),
                BlockingCell(
                    4.375,
                    3.125,
                    False,
                    None,
                    None,
                    (),
                    held_by=(BlockingCell(4.375, 3.375, False, 0.95, 2.5, (("u2", 2.5),)),),
                ),  # inscribed by a phantom the map holds 0.25 m away
            ),
            (
                RecoveryStep(4.0, "turn_in_place", "look again"),
                RecoveryStep(5.0, "replan", "still blocked"),
            ),
        ),
    ]
    record.collisions += [
        CollisionEvent(2.5, "u2", "t1", "tote", 2.1, 4.6, "fleet"),
        CollisionEvent(3.1, "u2", "t1", "tote", 2.1, 4.6, "fleet"),
        CollisionEvent(4.2, "u10", "h1", "person", 6.0, 1.4, "scenario"),
    ]
    plan = PlanContext(2.0, 5, (ContactCell(2.125, 4.875, "free", "lethal"),))
    record.incidents += [
        CollisionIncident("u2", "t1", "tote", "fleet", 2.5, 3.1, 2.1, 4.6, 2, plan),
        CollisionIncident("u10", "h1", "person", "scenario", 4.2, 4.2, 6.0, 1.4),
    ]
    record.counters += [
        CountersSample(0.0, 0, 0, 0, 0, 0, 0),
        CountersSample(4.0, 1, 1, 1, 1, 0, 3),
        CountersSample(10.0, 4, 0, 1, 1, 1, 3),
    ]
    record.time_to_clear = {"p1": 2.25, "p9": None}
    record.metrics = {
        "phantom_freezes": 1,
        "phantom_freeze_seconds": 1.5,
        "true_block_freezes": 2,
        "true_block_seconds": 2.5,
        "inscribed_plans": 1,
        "stale_free_plans": 1,
        "collisions": 1,
        "scenario_collisions": 1,
        "tasks_completed": 4,
        "sim_seconds": 10.0,
    }
    return record


@pytest.fixture(scope="module")
def record() -> RunRecord:
    return make_record()


@pytest.fixture(scope="module")
def replay(record, tmp_path_factory) -> Path:
    return write_replay(record, tmp_path_factory.mktemp("run") / "replay.mcap")


# ------------------------------------------------------------------------------ freezes.json
def test_freezes_json_lists_every_freeze_with_its_evidence_in_start_order(record, tmp_path):
    path = write_freezes(record, tmp_path / "freezes.json")
    freezes = json.loads(path.read_text())
    assert [f["unit"] for f in freezes] == ["u1", "u2"]
    phantom = freezes[0]
    assert list(phantom) == [
        "unit",
        "start",
        "duration",
        "phantom",
        "true_block",
        "phantom_s",
        "true_block_s",
        "segments",
        "reason",
        "position",
        "lanes",
        "blocking_cells",
        "recovery",
    ]
    assert phantom["lanes"] == [] and freezes[1]["lanes"] == [["j1_2", "s-1"]]
    assert (phantom["phantom"], phantom["true_block"]) == (True, True)
    assert (phantom["phantom_s"], phantom["true_block_s"]) == (1.5, 1.0)
    assert phantom["segments"] == [
        {"start": 3.5, "end": 4.5, "kind": "true_block", "cause": "its goal lies in p1"},
        {"start": 4.5, "end": 6.0, "kind": "phantom",
         "cause": "ground truth has a path (p1 removed at 4.5 s)"},
    ]  # fmt: skip
    assert (freezes[1]["phantom"], freezes[1]["true_block"]) == (False, True)
    assert (freezes[1]["phantom_s"], freezes[1]["true_block_s"]) == (0.0, 1.5)
    assert phantom["start"] == 3.5 and phantom["duration"] == 2.5
    assert phantom["position"] == {"x": 1.7, "y": 2.0}
    cell, unseen = phantom["blocking_cells"]
    assert list(cell) == [
        "x", "y", "truly_occupied", "p_occ", "last_observed", "marked_by", "held_by"
    ]  # fmt: skip
    assert cell["held_by"] == []  # occupied itself
    assert cell["truly_occupied"] is False
    assert cell["p_occ"] == 0.9123  # rounded to 1e-4
    assert cell["marked_by"] == [{"unit": "u1", "stamp": 2.9}, {"unit": "u2", "stamp": 2.0}]
    assert unseen["p_occ"] is None and unseen["last_observed"] is None
    (source,) = unseen["held_by"]  # blocked by inflation: what inscribed it, with its evidence
    assert (source["x"], source["y"], source["p_occ"]) == (4.375, 3.375, 0.95)
    assert source["marked_by"] == [{"unit": "u2", "stamp": 2.5}] and source["held_by"] == []
    assert phantom["recovery"] == [
        {"stamp": 4.0, "action": "turn_in_place", "cause": "look again"},
        {"stamp": 5.0, "action": "replan", "cause": "still blocked"},
    ]


def test_freezes_json_replaces_the_old_file_and_leaves_no_temporary(record, tmp_path):
    path = tmp_path / "freezes.json"
    path.write_text("old")
    write_freezes(record, path)
    assert json.loads(path.read_text())
    assert [p.name for p in tmp_path.iterdir()] == ["freezes.json"]


def test_freezes_json_of_a_run_without_freezes_is_an_empty_list(tmp_path):
    path = write_freezes(RunRecord("static_shift", "decay", 1, GEOMETRY), tmp_path / "f.json")
    assert json.loads(path.read_text()) == []


# ------------------------------------------------------------------------------ collisions.json
def test_collisions_json_lists_every_incident_with_what_the_map_held(record, tmp_path):
    unordered = make_record()
    unordered.incidents.reverse()
    unordered.incidents.append(
        CollisionIncident("u1", "u2", "unit", "fleet", 2.5, 2.5, 1.23456, 2.0)
    )
    path = write_collisions(unordered, tmp_path / "collisions.json")
    collisions = json.loads(path.read_text())
    assert collisions == [
        {"unit": "u2", "other": "t1", "other_kind": "tote", "cause": "fleet",
         "start": 2.5, "end": 3.1, "duration": 0.6, "contacts": 2,
         "position": {"x": 2.1, "y": 4.6},
         "plan": {"stamp": 2.0, "map_version": 5, "contact_cells": [
             {"x": 2.125, "y": 4.875, "map": "free", "truth": "lethal"}]}},
        {"unit": "u1", "other": "u2", "other_kind": "unit", "cause": "fleet",
         "start": 2.5, "end": 2.5, "duration": 0.0, "contacts": 1,
         "position": {"x": 1.235, "y": 2.0}, "plan": None},
        {"unit": "u10", "other": "h1", "other_kind": "person", "cause": "scenario",
         "start": 4.2, "end": 4.2, "duration": 0.0, "contacts": 1,
         "position": {"x": 6.0, "y": 1.4}, "plan": None},
    ]  # fmt: skip
    assert collision_counts(unordered.incidents) == {
        "collisions": 2, "scenario_collisions": 1, "collision_seconds": 0.6,
        "collision_contacts": 3,
    }  # fmt: skip
    empty = RunRecord("x", "decay", 1, GEOMETRY)
    assert json.loads(write_collisions(empty, tmp_path / "none.json").read_text()) == []
    assert collision_counts(empty.incidents)["collisions"] == 0


# ------------------------------------------------------------------------------ report.png
def test_report_is_a_1600_by_900_png(record, tmp_path):
    path = write_report(record, tmp_path / "report.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with Image.open(path) as image:
        assert image.size == (1600, 900)
        pixels = np.asarray(image.convert("RGB"))
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 50  # a picture, not a blank page


def test_report_marks_every_collision_on_the_map_and_the_timeline(record, tmp_path):
    def panels(rec, name):
        """(map, timeline) pixels: the left panel, the top-right one (not the legend)."""
        with Image.open(write_report(rec, tmp_path / name)) as image:
            rgb = np.asarray(image.convert("RGB"))
        return rgb[80:800, :850].reshape(-1, 3), rgb[80:500, 880:].reshape(-1, 3)

    def solid(pixels, color: str) -> int:
        rgb = [int(color[i : i + 2], 16) for i in (1, 3, 5)]
        return int((pixels == rgb).all(axis=1).sum())

    bare = make_record()
    bare.incidents.clear()
    with_, without = panels(record, "with.png"), panels(bare, "without.png")
    for drawn, empty in zip(with_, without, strict=True):
        for color in ("#ff7f0e", "#ffd92f"):  # fleet's star, scenario's diamond
            assert solid(empty, color) == 0 and solid(drawn, color) > 20


def test_report_title_counts_the_fleets_collisions_then_the_scenarios(record):
    assert "collisions 1 (+1 scenario)" in title(record)
    quiet = make_record()
    quiet.metrics["scenario_collisions"] = 0
    assert "collisions 1  ·" in title(quiet)


def test_report_title_names_the_run_and_its_key_metrics(record):
    head, metrics = title(record).split("\n")
    assert head == "moved_pod  |  policy sticky  |  seed 7"
    assert "phantom freezes 1" in metrics and "phantom freeze time 1.5 s" in metrics
    assert "true blocks 2" in metrics and "true-block time 2.5 s" in metrics
    assert "inscribed plans 1" in metrics
    assert "stale-free plans 1" in metrics and "tasks done 4" in metrics


def test_report_tables_the_throughput_metrics_with_na_for_a_missing_mean():
    record = make_record()
    record.metrics |= {
        "trips_per_unit_hour": 32.0,
        "ideal_trip_s": None,
        "trip_time_ratio": 1.2773,
        "fleet_efficiency": 0.5018,
        "moving_share": 0.6724,
        "mean_speed_moving": 1.2248,
        "wait_s": {"traffic": 71.5, "freeze": 99.5, "dwell": 50.6, "breakdown": 0.0, "turn": 73.0},
    }
    assert throughput_rows(record) == [
        ("trips per unit-hour", "32.0"),
        ("ideal trip (mean)", "n/a"),
        ("actual / ideal trip", "1.28"),
        ("fleet efficiency", "50.2%"),
        ("moving, with a task", "67.2%"),
        ("mean speed moving", "1.22 m/s"),
        ("standing, traffic", "71.5 s"),
        ("standing, freeze", "99.5 s"),
        ("standing, dwell", "50.6 s"),
        ("standing, breakdown", "0.0 s"),
        ("standing, turn", "73.0 s"),
    ]
    assert throughput_rows(RunRecord("x", "decay", 1, GEOMETRY)) == []


def test_report_of_a_run_with_nothing_recorded_still_draws(tmp_path):
    path = write_report(RunRecord("static_shift", "decay", 1, GEOMETRY), tmp_path / "r.png")
    with Image.open(path) as image:
        assert image.size == (1600, 900)


# ------------------------------------------------------------------------------ replay.mcap
def _read_all(path: Path):
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = [
            (schema, channel, message, json.loads(message.data))
            for schema, channel, message in reader.iter_messages(log_time_order=False)
        ]
    return summary, messages


def test_replay_holds_every_channel_with_its_foxglove_schema_and_count(record, replay):
    summary, messages = _read_all(replay)
    schema_of = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    assert schema_of == {
        "/units/u1/scan": "foxglove.LaserScan",
        "/units/u2/scan": "foxglove.LaserScan",
        "/units/u1/plan": "foxglove.PosesInFrame",
        "/units/u2/plan": "foxglove.PosesInFrame",
        "/map/occupancy": "foxglove.Grid",
        "/map/costmap": "foxglove.Grid",
        "/scene": "foxglove.SceneUpdate",
        "/tf": "foxglove.FrameTransforms",
        "/log": "foxglove.Log",
        "/metrics": "fleetmap.RunMetrics",
    }
    counts = Counter(channel.topic for _, channel, _, _ in messages)
    assert counts == {
        "/units/u1/scan": 3,
        "/units/u2/scan": 4,
        "/units/u1/plan": 3,
        "/units/u2/plan": 1,
        "/map/occupancy": 3,
        "/map/costmap": 3,
        "/scene": 21 + 2,  # one update per unit-sample stamp, one per objects sample
        "/tf": 21,  # one per unit-sample stamp
        "/metrics": 3,
        "/log": 3 + 2 + 3 + 2 + 2,  # events, freezes, recovery steps, unsafe plans,
        # collision incidents
    }
    for schema in summary.schemas.values():
        assert schema.encoding == "jsonschema"
        assert json.loads(schema.data) == SCHEMAS[schema.name]
    assert {ch.message_encoding for ch in summary.channels.values()} == {"json"}


def test_replay_messages_are_valid_for_their_schemas_and_in_time_order(replay):
    _, messages = _read_all(replay)
    for schema, channel, _, data in messages:
        _check(data, SCHEMAS[schema.name], channel.topic)
    log_times = [message.log_time for _, _, message, _ in messages]
    assert log_times == sorted(log_times)


def test_replay_timestamps_are_sim_time_in_nanoseconds(replay):
    _, messages = _read_all(replay)
    scans = [(m, d) for _, ch, m, d in messages if ch.topic == "/units/u2/scan"]
    assert [m.log_time for m, _ in scans] == [
        500_000_000,
        2_000_000_000,
        6_000_000_000,
        7_250_000_000,
    ]
    assert scans[-1][1]["timestamp"] == {"sec": 7, "nsec": 250_000_000}


def test_replay_grids_hold_the_recorded_arrays_at_the_map_origin(record, replay):
    _, messages = _read_all(replay)
    grids = {ch.topic: d for _, ch, _, d in messages if ch.topic.startswith("/map/")}
    last = record.grids[-1]
    costmap, occupancy = grids["/map/costmap"], grids["/map/occupancy"]
    data = np.frombuffer(base64.b64decode(occupancy["data"]), dtype=np.int8)
    assert np.array_equal(data.reshape(GEOMETRY.shape), last.occupancy)
    assert occupancy["fields"] == [{"name": "occupancy", "offset": 0, "type": 2}]  # INT8
    assert occupancy["row_stride"] == 40 and occupancy["cell_stride"] == 1
    cells = np.frombuffer(base64.b64decode(costmap["data"]), dtype=np.uint8)
    assert np.array_equal(cells.reshape(30, 40, 5)[..., 4], last.costs)
    assert costmap["row_stride"] == 40 * 5 and costmap["cell_stride"] == 5
    for message in (costmap, occupancy):
        assert message["column_count"] == 40
        assert message["cell_size"] == {"x": 0.25, "y": 0.25}
        assert message["pose"]["position"] == {"x": -1.0, "y": -0.5, "z": 0.0}
        assert message["frame_id"] == "map"


def test_replay_costmap_is_coloured_cell_by_cell_from_the_palette(record, replay):
    _, messages = _read_all(replay)
    grids = [d for _, ch, _, d in messages if ch.topic == "/map/costmap"]
    assert [f["name"] for f in grids[0]["fields"]] == ["red", "green", "blue", "alpha", "cost"]
    assert [(f["offset"], f["type"]) for f in grids[0]["fields"]] == [(i, 1) for i in range(5)]
    for sample, message in zip(record.grids, grids, strict=True):
        cells = np.frombuffer(base64.b64decode(message["data"]), dtype=np.uint8).reshape(30, 40, 5)
        assert np.array_equal(cells[..., :4], COSTMAP_RGBA[sample.costs])
        assert tuple(cells[0, 0]) == (112, 137, 134, 255, UNKNOWN)  # row 0: unknown
        assert tuple(cells[10, 20]) == (255, 0, 255, 255, LETHAL)
        assert tuple(cells[9, 20]) == (0, 255, 255, 255, INSCRIBED)
        assert tuple(cells[20, 0]) == (0, 0, 0, 0, FREE)  # free: transparent
        graded = 120 + sample.version
        red = round(255 * graded / 252)
        assert tuple(cells[8, 20]) == (red, 0, 255 - red, 255, graded)


def test_costmap_palette_ramps_blue_to_red_and_keeps_the_special_costs_apart():
    graded = COSTMAP_RGBA[1:253]
    assert np.all(np.diff(graded[:, 0].astype(int)) >= 0) and graded[0, 0] == 1
    assert graded[-1].tolist() == [255, 0, 0, 255]
    assert np.array_equal(graded[:, 0].astype(int) + graded[:, 2], np.full(252, 255))
    assert np.all(graded[:, 1] == 0) and np.all(graded[:, 3] == 255)
    special = {tuple(COSTMAP_RGBA[c]) for c in (FREE, INSCRIBED, LETHAL, UNKNOWN)}
    assert len(special) == 4 and not special & {tuple(c) for c in graded}
    assert COSTMAP_RGBA[FREE][3] == 0 and COSTMAP_RGBA.dtype == np.uint8


def test_replay_tf_places_each_unit_frame_at_its_recorded_pose(record, replay):
    _, messages = _read_all(replay)
    tf = [(m.log_time, d) for _, ch, m, d in messages if ch.topic == "/tf"]
    expected = {}
    for u in record.units:
        expected.setdefault(round(u.stamp * 1e9), []).append(u)
    assert [ns for ns, _ in tf] == sorted(expected)
    for ns, message in tf:
        transforms = message["transforms"]
        assert [t["child_frame_id"] for t in transforms] == [
            "u1/base_link", "u2/base_link", "u10/base_link"
        ]  # fmt: skip
        for t, u in zip(transforms, expected[ns], strict=True):
            assert t["parent_frame_id"] == "map"
            assert t["timestamp"] == {"sec": ns // 10**9, "nsec": ns % 10**9}
            assert t["translation"] == {"x": u.x, "y": u.y, "z": 0.0}
            q = t["rotation"]
            assert (q["x"], q["y"]) == (0.0, 0.0) and q["z"] ** 2 + q["w"] ** 2 == pytest.approx(1)
            assert 2 * math.atan2(q["z"], q["w"]) == pytest.approx(u.yaw, abs=1e-15)


def test_replay_metrics_hold_the_counts_and_verdicts_as_they_stood(record, replay):
    _, messages = _read_all(replay)
    metrics = [d for _, ch, _, d in messages if ch.topic == "/metrics"]
    assert [m.pop("timestamp") for m in metrics] == [
        {"sec": 0, "nsec": 0}, {"sec": 4, "nsec": 0}, {"sec": 10, "nsec": 0}
    ]  # fmt: skip
    counts = ("tasks_completed", "frozen_units", "stale_free_plans", "collisions",
              "scenario_collisions", "events")  # fmt: skip
    assert [[m[k] for k in counts] for m in metrics] == [
        [0, 0, 0, 0, 0, 0], [1, 1, 1, 1, 0, 3], [4, 0, 1, 1, 1, 3]
    ]  # fmt: skip
    verdicts = [(m["phantom_freezes"], m["phantom_freeze_seconds"], m["true_block_freezes"],
                 m["true_block_seconds"]) for m in metrics]  # fmt: skip
    # u1 true block 3.5-4.5 s then phantom to 6.0 s; u2 true block 5.0-6.5 s
    assert verdicts == [(0, 0, 0, 0), (0, 0, 1, 0.5), (1, 1.5, 2, 2.5)]
    last = metrics[-1]
    for key in ("tasks_completed", "stale_free_plans", "collisions", "scenario_collisions",
                "phantom_freezes", "phantom_freeze_seconds", "true_block_freezes",
                "true_block_seconds"):  # fmt: skip
        assert last[key] == record.metrics[key], key


def test_replay_scene_shows_units_as_cylinders_and_deletes_removed_objects(replay):
    _, messages = _read_all(replay)
    updates = [d for _, ch, _, d in messages if ch.topic == "/scene"]
    first_units = next(u for u in updates if u["entities"][0]["id"].startswith("unit/"))
    assert [e["id"] for e in first_units["entities"]] == ["unit/u1", "unit/u2", "unit/u10"]
    cylinder = first_units["entities"][0]["cylinders"][0]
    assert cylinder["size"] == {"x": 0.7, "y": 0.7, "z": 0.5}
    objects = [u for u in updates if u["entities"] and u["entities"][0]["id"].startswith("object/")]
    assert [[e["id"] for e in u["entities"]] for u in objects] == [
        ["object/p1", "object/h1"],
        ["object/h1", "object/t1"],
    ]
    assert objects[0]["entities"][0]["cubes"][0]["size"] == {"x": 1.0, "y": 1.0, "z": 2.0}
    assert objects[0]["entities"][1]["cylinders"][0]["size"] == {"x": 0.5, "y": 0.5, "z": 1.7}
    assert [(d["id"], d["type"]) for d in objects[1]["deletions"]] == [("object/p1", 0)]


def test_replay_log_explains_each_freeze(replay):
    _, messages = _read_all(replay)
    logs = [d for _, ch, _, d in messages if ch.topic == "/log"]
    phantom = next(d for d in logs if "PHANTOM" in d["message"])
    assert phantom["name"] == "u1" and phantom["level"] == 3  # WARNING
    assert phantom["timestamp"] == {"sec": 3, "nsec": 500_000_000}
    assert "(4.12, 3.12) truth free, p_occ 0.91" in phantom["message"]
    assert "marked by u1@2.90, u2@2.00" in phantom["message"]
    assert (
        "(4.38, 3.12) truth free, p_occ unknown, seen never, marked by no scan "
        "(inscribed by (4.38, 3.38) truth free, p_occ 0.95, seen 2.50 s, marked by u2@2.50)"
    ) in phantom["message"]
    assert "turn_in_place at 4.00 s" in phantom["message"]
    true_block = next(d for d in logs if "true-block" in d["message"])
    assert true_block["name"] == "u2" and true_block["level"] == 2  # INFO
    assert "truth occupied" in true_block["message"]


def test_replay_log_reports_each_collision_with_its_cause(replay):
    _, messages = _read_all(replay)
    logs = [d for _, ch, _, d in messages if ch.topic == "/log" and "COLLISION" in d["message"]]
    assert [(d["name"], d["level"], d["timestamp"]) for d in logs] == [
        ("u2", 4, {"sec": 2, "nsec": 500_000_000}),  # ERROR: the fleet drove into it
        ("u10", 3, {"sec": 4, "nsec": 200_000_000}),  # WARNING: the scenario's
    ]
    assert "touched tote t1" in logs[0]["message"] and "cause: fleet" in logs[0]["message"]
    assert "(2.10, 4.60)" in logs[0]["message"]
    assert "touched person h1" in logs[1]["message"]
    assert "cause: scenario" in logs[1]["message"]


def test_replay_log_names_the_blocked_lanes_of_a_lane_freeze(replay):
    _, messages = _read_all(replay)
    logs = [d for _, ch, _, d in messages if ch.topic == "/log" and "freeze" in d["message"]]
    lane = next(d for d in logs if d["name"] == "u2")
    assert "blocked lanes (1): j1_2-s-1" in lane["message"]
    phantom = next(d for d in logs if d["name"] == "u1")
    assert "blocked lanes" not in phantom["message"]


def test_plans_become_poses_heading_along_the_path(replay):
    _, messages = _read_all(replay)
    plans = [d for _, ch, _, d in messages if ch.topic == "/units/u1/plan"]
    poses = plans[0]["poses"]
    assert [(p["position"]["x"], p["position"]["y"]) for p in poses] == [(1, 2), (2, 2), (3, 3)]
    q = poses[1]["orientation"]
    assert 2 * math.atan2(q["z"], q["w"]) == pytest.approx(math.pi / 4)
    assert plans[1]["poses"] == []  # no path: the drawn one is cleared


# ------------------------------------------------------------------------------ read_scans
def test_read_scans_gives_back_the_scans_written(record, replay):
    scans = read_scans(replay)
    written = sorted(record.scans, key=lambda s: s.stamp)
    assert [(s.unit_id, s.stamp) for s in scans] == [(w.unit_id, w.stamp) for w in written]
    for scan, w in zip(scans, written, strict=True):
        assert (scan.pose.x, scan.pose.y) == (w.x, w.y)
        assert scan.pose.yaw == pytest.approx(math.remainder(w.yaw, math.tau), abs=1e-12)
        assert (scan.angle_min, scan.angle_increment) == (w.angle_min, w.angle_increment)
        assert (scan.range_min, scan.range_max) == (w.range_min, w.range_max)
        assert scan.frame == "map"
        assert scan.pose_std == w.pose_std
        # REP 117 classes survive: returns exact, +inf no return, NaN and -inf invalid (NaN).
        expected = w.ranges.astype(np.float64)
        expected[np.isneginf(expected)] = NAN
        np.testing.assert_array_equal(scan.ranges, expected)
        assert np.array_equal(
            classify_ranges(scan.ranges, scan.range_min, scan.range_max),
            classify_ranges(w.ranges, w.range_min, w.range_max),
        )


def test_read_scans_until_leaves_out_later_scans(replay):
    assert [s.stamp for s in read_scans(replay, until=2.0)] == [0.5, 0.5, 1.0, 2.0]


def test_ranges_encoding_is_strict_json_and_keeps_rep117_classes():
    ranges = np.array([1.5, INF, NAN, -INF, 30.0, 0.01], dtype=np.float32)
    encoded = encode_ranges(ranges)
    assert np.isfinite(encoded).all()
    assert json.loads(json.dumps(encoded.tolist(), allow_nan=False))
    decoded = decode_ranges(encoded.tolist())
    assert classify_ranges(decoded, 0.05, 20.0).tolist() == [
        BEAM_RETURN,
        BEAM_NO_RETURN,
        BEAM_INVALID,
        BEAM_INVALID,
        BEAM_NO_RETURN,
        BEAM_INVALID,
    ]
    assert decoded[1] == INF and math.isnan(decoded[2]) and math.isnan(decoded[3])


def test_read_geometry_gives_the_map_grid(replay):
    assert read_geometry(replay) == GEOMETRY


def test_reading_a_file_that_is_not_a_replay_names_it(tmp_path):
    bad = tmp_path / "replay.mcap"
    bad.write_bytes(b"not an mcap file")
    with pytest.raises(ReplayFileError, match="replay.mcap"):
        read_scans(bad)
    with pytest.raises(ReplayFileError, match="missing.mcap"):
        read_scans(tmp_path / "missing.mcap")


def test_a_bad_stamp_fails_the_write_and_leaves_no_file(tmp_path):
    record = RunRecord("x", "decay", 1, GEOMETRY)
    record.units.append(UnitSample(-1.0, "u1", 0.0, 0.0, 0.0, False, False, None))
    with pytest.raises(ValueError, match="stamp"):
        write_replay(record, tmp_path / "replay.mcap")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ helpers
def _check(value, schema: dict, where: str) -> None:
    """``value`` conforms to the JSON schema ``schema`` (the subset Foxglove's use):
    required and no unknown properties, types, enums (oneOf const), bounds."""
    if "oneOf" in schema:
        assert value in [option["const"] for option in schema["oneOf"]], where
        return
    kind = schema["type"]
    if kind == "object":
        assert isinstance(value, dict), where
        assert set(value) <= set(schema["properties"]), f"{where}: {set(value)}"
        assert set(schema.get("required", ())) <= set(value), f"{where}: {set(value)}"
        for key, item in value.items():
            _check(item, schema["properties"][key], f"{where}.{key}")
    elif kind == "array":
        assert isinstance(value, list), where
        for i, item in enumerate(value):
            _check(item, schema["items"], f"{where}[{i}]")
    else:
        python_types = {
            "number": (int, float),
            "integer": (int,),
            "string": (str,),
            "boolean": (bool,),
        }[kind]
        assert isinstance(value, python_types), f"{where}: {value!r} is not {kind}"
        assert kind == "boolean" or not isinstance(value, bool), where
        assert value >= schema.get("minimum", value), where
        assert value <= schema.get("maximum", value), where
