"""Scenario files: the shipped ones load, values round-trip, every error names the file,
the line and the field, trips are seeded, and no input raises anything but ScenarioError."""

from __future__ import annotations

import math
import pickle
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.layout import Kind
from fleet.world import World
from mapserver.core.sensor_model import Policy
from scenarios.spec.scenario import (
    TOP_KEYS,
    BreakdownEvent,
    DropEvent,
    MoveEvent,
    PersonEvent,
    RemoveEvent,
    ScenarioError,
    load_scenario,
    parse_scenario,
    task_stream,
)

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
SHIPPED = (
    "static_shift", "moved_pod", "dropped_tote", "person_crossing", "busy_shift",
    "hundred_units", "tiny", "dropouts", "thousand_units",
)  # fmt: skip

BASE = """\
name: base
duration: 30.0
seed: 0
layout:
  floor: {width: 12.0, height: 8.0}
  lanes: {x: [1.5, 10.5], y: [1.5, 6.5]}
  obstacles:
    - {id: rack-1, kind: rack, box: {x: 6.0, y: 4.0, size_x: 6.0, size_y: 2.0}}
    - {id: pod-1, kind: pod, box: {x: 4.0, y: 5.4, size_x: 0.8, size_y: 0.8}}
  stations:
    - {id: pick-1, x: 6.0, y: 1.5}
  storage:
    - {id: s-1, x: 8.0, y: 6.5}
units:
  count: 2
  lidar: {beams: 90}
tasks:
  count: 3
map_server:
  policy: decay
  sensor_model: {p_hit: 0.75}
events:
  - {at: 2.0, drop: tote-1, x: 10.5, y: 4.0}
  - {at: 5.0, remove: tote-1}
"""


def load_text(text: str, tmp_path: Path, name: str = "case.yaml", **kwargs):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return load_scenario(path, **kwargs)


def line_of(text: str, fragment: str) -> int:
    """1-based line of the first line holding ``fragment``."""
    return next(i for i, line in enumerate(text.splitlines(), 1) if fragment in line)


# ---------------------------------------------------------------------------- shipped
@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_scenario_loads_with_units_stops_and_a_grid_covering_the_floor(name):
    scenario = load_scenario(SCENARIOS / f"{name}.yaml")
    assert scenario.name == name
    assert scenario.units.count >= 1 and len(scenario.unit_specs()) == scenario.units.count
    geometry = scenario.geometry()
    assert geometry.width * geometry.resolution >= scenario.layout.width
    assert geometry.height * geometry.resolution >= scenario.layout.height
    graph = scenario.build_lane_graph()
    assert set(scenario.stops()) <= set(graph.nodes)
    assert scenario.tasks.enabled and next(task_stream(scenario), None) is not None


def test_the_shipped_set_is_complete_and_busy_shift_has_every_event_kind():
    assert {p.stem for p in SCENARIOS.glob("*.yaml")} >= set(SHIPPED)
    busy = load_scenario(SCENARIOS / "busy_shift.yaml")
    assert busy.units.count == 20 and busy.duration == 600.0
    kinds = {event.kind for event in busy.events}
    assert kinds == {"move", "drop", "remove", "person", "breakdown"}


def test_moved_pod_moves_the_pod_blocking_the_dead_end_out_of_the_way():
    scenario = load_scenario(SCENARIOS / "moved_pod.yaml")
    (move,) = scenario.events
    assert move == MoveEvent(60.0, "pod-9", 12.0, 1.8)
    assert scenario.layout.obstacle("pod-9").kind is Kind.POD
    assert 4 <= scenario.units.count <= 6 and scenario.duration == 180.0
    on_the_line = {s.id: s.x for s in scenario.storage if s.y == pytest.approx(16.33)}
    assert {sid for sid, x in on_the_line.items() if x > 24.6} == {"s-1"}  # behind the pod
    wall = scenario.layout.obstacle("wall-dead-end").shape.bounds()
    assert on_the_line["s-1"] < wall[0]  # and before the wall that closes the dead end


def test_dropouts_is_a_static_warehouse_seen_by_noisy_lidars_that_drop_beams():
    scenario = load_scenario(SCENARIOS / "dropouts.yaml")
    assert scenario.events == ()
    lidar = scenario.units.lidar
    assert (lidar.range_noise, lidar.dropout_prob, lidar.spurious_prob) == (0.02, 0.05, 0.0)
    model = scenario.map_server.sensor_model
    assert (model.p_miss_no_return, model.no_return_range) == (0.45, 1.0)  # the defaults


def test_the_lidar_caster_is_a_scenario_setting_given_to_every_unit(tmp_path):
    assert {spec.caster for spec in load_text(BASE, tmp_path).unit_specs()} == {"grid"}
    text = BASE.replace("{beams: 90}", "{beams: 90, caster: bullet}")
    scenario = load_text(text, tmp_path)
    assert (scenario.units.caster, scenario.units.lidar.beams) == ("bullet", 90)
    assert {spec.caster for spec in scenario.unit_specs()} == {"bullet"}


def test_map_server_zones_cut_the_floor_into_strips_for_the_lidar_reach(tmp_path):
    one = load_text(BASE, tmp_path)
    assert one.map_server.zones == 1 and one.zone_layout().cuts == (0, 120)
    text = BASE.replace("policy: decay", "policy: decay\n  zones: 3").replace(
        "{beams: 90}", "{beams: 90, range_max: 8.0}"
    )
    three = load_text(text, tmp_path).zone_layout()
    assert three.cuts == (0, 40, 80, 120)
    assert three.reach_m == pytest.approx(8.1)  # the LiDAR's range and a cell
    assert three.margin_cells == 6  # the default inflation radius 0.55 m, and a cell
    cases = [(0, "in [1, 64]"), (2.5, "an integer"), ("13\n  resolution: 1.0", "12 grid columns")]
    for zones, reason in cases:
        bad = BASE.replace("policy: decay", f"policy: decay\n  zones: {zones}")
        with pytest.raises(ScenarioError, match=f"map_server.zones: must .*{re.escape(reason)}"):
            load_text(bad, tmp_path)


def test_the_no_return_settings_are_scenario_settings(tmp_path):
    text = BASE.replace("{p_hit: 0.75}", "{p_miss_no_return: 0.5, no_return_range: null}")
    model = load_text(text, tmp_path).map_server.sensor_model
    assert (model.p_miss_no_return, model.no_return_range) == (0.5, None)
    bad = BASE.replace("{p_hit: 0.75}", "{p_miss_no_return: 0.6}")
    with pytest.raises(ScenarioError, match="map_server.sensor_model.p_miss_no_return: must be"):
        load_text(bad, tmp_path)


# ---------------------------------------------------------------------------- values
def test_key_values_round_trip_from_the_file(tmp_path):
    scenario = load_text(BASE, tmp_path)
    assert (scenario.name, scenario.duration, scenario.dt, scenario.seed) == ("base", 30.0, 0.1, 0)
    assert scenario.source == str(tmp_path / "case.yaml")
    assert [s.id for s in scenario.layout.stations] == ["pick-1"]
    assert [(s.id, s.x, s.y, s.pod) for s in scenario.storage] == [("s-1", 8.0, 6.5, None)]
    assert scenario.units.lidar.beams == 90 and scenario.units.ids == ("u1", "u2")
    assert (scenario.tasks.count, scenario.tasks.dwell) == (3, 3.0)
    assert (scenario.tasks.return_after, scenario.tasks.retry_after) == (30.0, 60.0)  # defaults
    assert scenario.events == (
        DropEvent(2.0, "tote-1", 10.5, 4.0),
        RemoveEvent(5.0, "tote-1"),
    )
    overrides = scenario.server_overrides()
    assert overrides["policy"] == "decay"
    assert overrides["sensor_model"]["p_hit"] == 0.75
    assert overrides["grid"] == {
        "width": 120,
        "height": 80,
        "resolution": 0.1,
        "origin_x": 0.0,
        "origin_y": 0.0,
    }
    # Nav2 derives the inscribed radius from the footprint; so does a scenario
    assert overrides["inflation"]["inscribed_radius"] == scenario.units.drive.radius
    settings_ = scenario.server_settings({"port": 0})
    assert settings_.port == 0 and settings_.build_sensor_model().p_hit == 0.75


def test_when_trips_go_back_is_set_in_the_tasks_section_and_null_means_never(tmp_path):
    knobs = "  count: 3\n  return_after: 45\n  retry_after: 0"
    scenario = load_text(BASE.replace("  count: 3", knobs), tmp_path)
    assert (scenario.tasks.return_after, scenario.tasks.retry_after) == (45.0, 0.0)
    scenario = load_text(BASE.replace("  count: 3", "  count: 3\n  return_after: null"), tmp_path)
    assert scenario.tasks.return_after is None
    text = BASE.replace("  count: 3", "  count: 3\n  return_after: soon")
    with pytest.raises(ScenarioError) as err:
        load_text(text, tmp_path, "bad.yaml")
    line = line_of(text, "return_after")
    assert str(err.value) == (
        f"{tmp_path / 'bad.yaml'}:{line}: tasks.return_after: must be a number of seconds > 0, "
        "got 'soon'"
    )


def test_pods_are_the_storage_locations_when_none_are_listed(tmp_path):
    scenario = load_text(
        BASE.replace("  storage:\n    - {id: s-1, x: 8.0, y: 6.5}\n", ""), tmp_path
    )
    (pod,) = scenario.storage
    assert (pod.id, pod.pod) == ("pod-1", "pod-1")
    assert (pod.x, pod.y) == (4.0, 6.5)  # the lane point beside the pod


def test_units_start_at_free_junctions_spread_and_the_same_for_every_seed(tmp_path):
    scenario = load_text(BASE, tmp_path)
    starts = [(p.x, p.y) for p in scenario.units.starts]
    assert starts == [(1.5, 1.5), (1.5, 6.5)]  # junctions 0 and 2 of 4, row-major
    assert scenario.units.placed
    assert scenario.with_seed(7).units.starts == scenario.units.starts


def test_explicit_starts_are_kept(tmp_path):
    text = BASE.replace("  count: 2\n", "  starts: [{x: 1.5, y: 3.0, yaw: 1.57}]\n")
    scenario = load_text(text, tmp_path)
    (start,) = scenario.units.starts
    assert (start.x, start.y, start.yaw) == (1.5, 3.0, 1.57) and not scenario.units.placed


def test_with_policy_and_with_seed_change_only_that(tmp_path):
    scenario = load_text(BASE, tmp_path)
    sticky = scenario.with_policy("sticky")
    assert sticky.map_server.policy is Policy.STICKY
    assert sticky.server_overrides()["policy"] == "sticky"
    assert sticky.with_policy(Policy.DECAY) == scenario
    assert scenario.with_seed(3).seed == 3 and scenario.with_seed(3).layout == scenario.layout
    with pytest.raises(ValueError, match="policy must be one of"):
        scenario.with_policy("careful")
    with pytest.raises(ValueError, match="seed"):
        scenario.with_seed(-1)


def test_a_scenario_pickles_for_worker_processes():
    scenario = load_scenario(SCENARIOS / "busy_shift.yaml")
    copy = pickle.loads(pickle.dumps(scenario))
    assert copy == scenario and list(task_stream(copy)) == list(task_stream(scenario))


def test_overrides_set_dotted_keys_before_validation(tmp_path):
    scenario = load_text(BASE, tmp_path, overrides={"map_server.decay.half_life_occupied": 5})
    assert scenario.map_server.decay.half_life_occupied == 5.0
    for policy in Policy:  # every policy by name, in a file or an override
        chosen = load_text(BASE, tmp_path, overrides={"map_server.policy": policy.value})
        assert chosen.map_server.policy is policy
        in_file = load_text(BASE.replace("  policy: decay", f"  policy: {policy.value}"), tmp_path)
        assert in_file.map_server.policy is policy
    with pytest.raises(ScenarioError) as err:
        load_text(BASE, tmp_path, overrides={"map_server.policy": "careful"})
    assert err.value.line is None and err.value.field == "map_server.policy (override)"


# ---------------------------------------------------------------------------- errors
ERRORS = [
    # (what to replace, with what, expected field, a fragment of the expected line, reason)
    ("seed: 0", "seed: 0\ncolour: red", "colour", "colour:", "is not a field of scenario"),
    ("  count: 2", "  cont: 2", "units.cont", "cont:", "did you mean 'count'"),
    ("duration: 30.0", "duration: soon", "duration", "duration:", "got 'soon'"),
    ("duration: 30.0", "duration: -5", "duration", "duration:", "seconds in (0, 86400], got -5"),
    (
        "{at: 5.0, remove",
        "{at: soon, remove",
        "events[1].at",
        "at: soon",
        "must be a number of seconds >= 0, got 'soon'",
    ),
    ("remove: tote-1}", "remove: ghost}", "events[1].remove", "ghost", "not in the layout"),
    ("{at: 2.0, drop", "{at: 9.0, drop", "events[1].remove", "remove:", "earlier event"),
    ("policy: decay", "policy: careful", "map_server.policy", "policy:", "'careful'"),
    ("p_hit: 0.75", "p_hit: 0.4", "map_server.sensor_model.p_hit", "p_hit", "prior"),
    ("{beams: 90}", "{beams: 0}", "units.lidar.beams", "beams", "got 0"),
    ("lidar: {beams: 90}", "drive: {radius: wide}", "units.drive.radius", "radius", "number"),
    ("size_x: 6.0", "size_x: -6.0", "layout.obstacles[0].box.size_x", "rack-1", "positive"),
    (
        "{id: pick-1, x: 6.0, y: 1.5}",
        "{id: pick-1, x: 6.0, y: 2.8}",
        "layout.stations[0]",
        "pick-1",
        "from rack 'rack-1'",
    ),  # fmt: skip
    (
        "{id: s-1, x: 8.0, y: 6.5}",
        "{id: s-1, x: 6.0, y: 7.7}",
        "layout.storage[0]",
        "s-1",
        "from the nearest lane",
    ),  # fmt: skip
    (
        "{id: s-1, x: 8.0, y: 6.5}",
        "{id: pick-1, x: 8.0, y: 6.5}",
        "layout.storage[0]",
        "{id: pick-1, x: 8.0",
        "id of a station",
    ),  # fmt: skip
    ("  count: 2", "  count: 5", "units.count", "count: 5", "free lane junction"),
    (
        "  count: 2",
        "  count: 2\n  starts: [{x: 1.5, y: 1.5}]",
        "units.starts",
        "starts",
        "units.count = 2",
    ),  # fmt: skip
    (
        "tasks:\n  count: 3",
        "tasks:\n  count: 3\n  rate_per_unit: 0.1",
        "tasks.rate_per_unit",
        "rate_per_unit",
        "not both",
    ),  # fmt: skip
    ("seed: 0", "seed: 0\ndt: 0.5", "dt", "dt:", "one LiDAR period"),
    ("seed: 0", "seed: 0\nrecovery: {wait_s: 0}", "recovery.wait_s", "recovery", "positive"),
    (
        "{at: 2.0, drop: tote-1, x: 10.5, y: 4.0}",
        "{at: 2.0, breakdown: u9}",
        "events[0].breakdown",
        "u9",
        "not a unit",
    ),  # fmt: skip
    (
        "{at: 2.0, drop: tote-1, x: 10.5, y: 4.0}",
        "{at: 2.0, move: rack-1, x: 1.0, y: 1.0}",
        "events[0]",
        "move: rack-1",
        "off the floor",
    ),  # fmt: skip
    (
        "{at: 2.0, drop: tote-1, x: 10.5, y: 4.0}",
        "{at: 2.0, person: ann, path: [[1.5, 4.0], [10.5, 4.0]]}",
        "events[0].path",
        "ann",
        "walks through rack 'rack-1'",
    ),  # fmt: skip
    (
        "{at: 2.0, drop: tote-1, x: 10.5, y: 4.0}",
        "{at: 2.0, drop: pod-1, x: 10.5, y: 4.0}",
        "events[0].drop",
        "drop: pod-1",
        "already the id",
    ),  # fmt: skip
    (
        "{at: 5.0, remove: tote-1}",
        "{at: 50.0, remove: tote-1}",
        "events[1].at",
        "at: 50.0",
        "at most the duration",
    ),  # fmt: skip
    ("  count: 3", "  count: 3\n  count: 4", "tasks.count", "count: 4", "given twice"),
    ("  count: 3", "  count: 3\n  return_after: 0", "tasks.return_after", "return_after", "> 0"),
    (
        "  count: 3",
        "  count: 3\n  retry_after: -5",
        "tasks.retry_after",
        "retry_after",
        "must be a number of seconds >= 0, got -5",
    ),  # fmt: skip
    (
        "  floor: {width: 12.0",
        "  floor: {width: 12.0, colour: 1",
        "layout.floor.colour",
        "floor:",
        "not a known field",
    ),  # fmt: skip
    (
        "  lanes: {x: [1.5, 10.5]",
        "  lanes: {x: [10.5, 1.5]",
        "layout.lanes.x",
        "lanes:",
        "strictly increasing",
    ),  # fmt: skip
    (
        "  storage:",
        "  one_way: [[j0_0, j1_1]]\n  storage:",
        "layout.one_way[0]",
        "one_way",
        "not a lane",
    ),  # fmt: skip
    (
        "  storage:",
        "  one_way: circles\n  storage:",
        "layout.one_way",
        "one_way",
        "must be 'loops', 'aisles' or a list of pairs",
    ),  # fmt: skip
    (
        "map_server:",
        "map_server:\n  resolution: 0.001",
        "map_server.resolution",
        "resolution",
        "in [0.01, 1]",
    ),  # fmt: skip
]


@pytest.mark.parametrize(("old", "new", "field", "fragment", "reason"), ERRORS)
def test_errors_name_the_file_the_line_and_the_field(tmp_path, old, new, field, fragment, reason):
    assert old in BASE
    text = BASE.replace(old, new, 1)
    with pytest.raises(ScenarioError) as err:
        load_text(text, tmp_path, "bad.yaml")
    exc = err.value
    line = line_of(text, fragment)
    assert (exc.field, exc.line) == (field, line), str(exc)
    assert str(exc).startswith(f"{tmp_path / 'bad.yaml'}:{line}: {field}: ")
    assert reason in str(exc)


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            "duration: 30.0",
            'duration: "30"',
            "duration: must be a number of seconds in (0, 86400], got '30'",
        ),
        ("seed: 0", "seed: true", "seed: must be an integer >= 0, got True"),
        ("{beams: 90}", "{beams: 9.5}", "units.lidar.beams: must be an integer, got 9.5"),
        (
            "{beams: 90}",
            "{beams: 90, caster: fast}",
            "units.lidar.caster: must be one of ['grid', 'bullet'], got 'fast'",
        ),
        (
            "p_hit: 0.75",
            "p_hit: '0.75'",
            "map_server.sensor_model.p_hit: must be a number, got '0.75'",
        ),
        (
            "policy: decay",
            "policy: careful",
            "map_server.policy: must be one of decay, binary, sticky, dual, got 'careful'",
        ),
        ("  count: 2", "  cont: 2", "units.cont: is not a field of units; did you mean 'count'?"),
        (
            "{at: 5.0, remove: tote-1}",
            "{at: 5.0, remove: tote-1, move: tote-1}",
            "events[1]: must be a mapping with at and exactly one of move, drop, remove, person, "
            "breakdown, got {'at': 5.0, 'remove': 'tote-1', 'move': 'tote-1'}",
        ),
    ],
)  # fmt: skip
def test_types_are_strict_and_errors_read_exactly_so(tmp_path, old, new, expected):
    text = BASE.replace(old, new, 1)
    with pytest.raises(ScenarioError) as err:
        load_text(text, tmp_path, "bad.yaml")
    assert str(err.value) == f"{tmp_path / 'bad.yaml'}:{line_of(text, new[:8])}: {expected}"


def test_the_briefs_example_error_reads_exactly_so(tmp_path):
    text = BASE.replace("{at: 5.0, remove", "{at: soon, remove")
    with pytest.raises(ScenarioError) as err:
        load_text(text, tmp_path, "moved_pod.yaml")
    line = line_of(text, "at: soon")
    expected = f"moved_pod.yaml:{line}: events[1].at: must be a number of seconds >= 0, got 'soon'"
    assert str(err.value).endswith(expected)


@pytest.mark.parametrize(
    ("text", "line", "reason"),
    [
        ("duration: [1,\n", 2, "not valid YAML"),
        ("", None, "must be a mapping"),
        ("- 1\n- 2\n", None, "must be a mapping"),
        ("duration: 1\n---\nduration: 2\n", 2, "not valid YAML"),
        ("when: 2001-13-45\n", None, "not valid YAML"),
        ("a: !!python/object:os.system x\n", 1, "not valid YAML"),
    ],
)
def test_files_that_are_not_a_yaml_mapping_are_scenario_errors(text, line, reason):
    with pytest.raises(ScenarioError) as err:
        parse_scenario(text, "x.yaml")
    assert err.value.line == line and reason in str(err.value)


def test_a_missing_file_is_a_scenario_error(tmp_path):
    with pytest.raises(ScenarioError, match="cannot read the file"):
        load_scenario(tmp_path / "nope.yaml")


# ---------------------------------------------------------------------------- tasks
def test_the_task_stream_is_deterministic_for_a_seed_and_differs_for_another(tmp_path):
    scenario = load_scenario(SCENARIOS / "person_crossing.yaml")
    first = list(task_stream(scenario))
    assert first == list(task_stream(scenario)) == list(scenario.task_stream())
    other = list(task_stream(scenario.with_seed(1)))
    assert first != other
    assert list(task_stream(scenario.with_policy("sticky"))) == first


def test_a_rate_releases_trips_by_a_poisson_process_within_the_duration():
    scenario = load_scenario(SCENARIOS / "busy_shift.yaml")
    tasks = list(task_stream(scenario))
    releases = np.array([t.release for t in tasks])
    assert np.all(np.diff(releases) >= 0) and releases[-1] < scenario.duration
    expected = scenario.tasks.rate_per_unit * scenario.units.count * scenario.duration
    assert abs(len(tasks) - expected) < 4 * math.sqrt(expected)
    stations = {s.id: (s.x, s.y) for s in scenario.layout.stations}
    storage = {s.id: (s.x, s.y) for s in scenario.storage}
    for task in tasks:
        assert storage[task.pickup_id] == task.pickup
        assert stations[task.dropoff_id] == task.dropoff
        assert task.unit is None and task.dwell == scenario.tasks.dwell
    assert [t.task_id for t in tasks[:3]] == ["t1", "t2", "t3"]


def test_a_count_is_a_backlog_released_at_zero(tmp_path):
    tasks = list(task_stream(load_text(BASE, tmp_path)))
    assert len(tasks) == 3 and {t.release for t in tasks} == {0.0}
    assert {t.pickup_id for t in tasks} == {"s-1"} and {t.dropoff_id for t in tasks} == {"pick-1"}


# ---------------------------------------------------------------------------- events
def test_a_person_walks_its_path_at_its_speed_then_leaves():
    person = PersonEvent(10.0, "ann", ((0.0, 0.0), (3.0, 0.0), (3.0, 4.0)), speed=1.0)
    assert person.end == 17.0
    assert person.position_at(9.9) is None and person.position_at(17.1) is None
    assert person.position_at(12.0) == (2.0, 0.0)
    assert person.position_at(15.0) == pytest.approx((3.0, 2.0))
    changes = person.changes(0.5)
    times = [c.time for c in changes]
    assert times[0] == 10.0 and times[-1] == 17.0 and times == sorted(times)


def test_breakdowns_are_for_units_and_change_no_world():
    breakdown = BreakdownEvent(5.0, "u1", 10.0)
    assert breakdown.until == 15.0 and breakdown.changes(0.1) == ()
    assert BreakdownEvent(5.0, "u1").until == math.inf


def test_the_world_schedule_plays_the_events_on_a_world(tmp_path):
    text = BASE.replace(
        "  - {at: 5.0, remove: tote-1}",
        "  - {at: 5.0, move: tote-1, x: 10.5, y: 3.0}\n"
        "  - {at: 6.0, person: ann, path: [[1.5, 2.5], [1.5, 5.5]], speed: 1.5}\n"
        "  - {at: 7.0, breakdown: u2, duration: 3}",
    )
    scenario = load_text(text, tmp_path)
    assert [b.unit_id for b in scenario.breakdowns()] == ["u2"]
    with World(scenario.build_layout()) as world:
        seen_person = False
        for change in scenario.world_schedule():
            world.advance_to(change.time)
            change.apply(world)
            seen_person |= "ann" in world.obstacles
        assert seen_person and "ann" not in world.obstacles  # walked, then left
        assert world.obstacle("tote-1").shape.y == 3.0


# ---------------------------------------------------------------------------- fuzzing
VOCABULARY = list(TOP_KEYS) + [
    "warehouse", "floor", "lanes", "obstacles", "stations", "storage", "one_way", "count",
    "starts", "lidar", "drive", "pose_noise", "rate_per_unit", "dwell", "return_after",
    "retry_after", "policy", "resolution", "sensor_model", "p_hit", "decay", "inflation",
    "at", "move", "drop", "remove", "person",
    "breakdown", "path", "x", "y", "id", "kind", "box", "width", "height", "radius", "speed",
]  # fmt: skip
scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
)
keys = st.one_of(st.sampled_from(VOCABULARY), st.text(max_size=6), st.integers(0, 3))
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(keys, inner, max_size=4)),
    max_leaves=12,
)


def _mutate(data, path, value):
    """``data`` with the value at ``path`` (indices into nested keys/items) replaced."""
    if not path or not isinstance(data, dict | list) or not data:
        return value
    if isinstance(data, dict):
        key = list(data)[path[0] % len(data)]
        return {**data, key: _mutate(data[key], path[1:], value)}
    i = path[0] % len(data)
    return [*data[:i], _mutate(data[i], path[1:], value), *data[i + 1 :]]


def _only_scenario_errors(text: str) -> None:
    try:
        parse_scenario(text, "fuzz.yaml")
    except ScenarioError:
        pass


@settings(max_examples=150)
@given(st.dictionaries(keys, values, max_size=6))
def test_arbitrary_yaml_mappings_raise_nothing_but_scenario_errors(data):
    _only_scenario_errors(yaml.safe_dump(data))


@settings(max_examples=200)
@given(st.lists(st.integers(0, 50), min_size=1, max_size=5), values)
def test_a_valid_scenario_with_any_one_value_changed_raises_nothing_but_scenario_errors(
    path, value
):
    _only_scenario_errors(yaml.safe_dump(_mutate(yaml.safe_load(BASE), path, value)))


def test_one_way_aisles_make_the_rows_one_way_and_keep_the_columns_two_way(tmp_path):
    import networkx as nx

    text = BASE.replace("  storage:", "  one_way: aisles\n  storage:", 1)
    scenario = load_text(text, tmp_path)
    assert set(scenario.one_way) == {("j0_0", "j1_0"), ("j1_1", "j0_1")}
    graph = scenario.build_lane_graph(segment_m=2.0).graph
    assert nx.is_strongly_connected(graph)
    pos = nx.get_node_attributes(graph, "pos")
    vertical = [(a, b) for a, b in graph.edges if pos[a][0] == pos[b][0]]
    assert vertical and all(graph.has_edge(b, a) for a, b in vertical)  # columns two-way
    assert all(not graph.has_edge(b, a) for a, b in graph.edges if (a, b) not in vertical)


def test_an_unknown_one_way_pattern_is_refused_naming_the_patterns(tmp_path):
    text = BASE.replace("  storage:", "  one_way: aisle\n  storage:", 1)
    with pytest.raises(
        ScenarioError, match="must be 'loops', 'aisles' or a list of pairs, got 'aisle'"
    ):
        load_text(text, tmp_path)


def test_one_way_loops_make_every_lane_one_way_and_keep_every_junction_reachable(tmp_path):
    import networkx as nx

    text = BASE.replace("  storage:", "  one_way: loops\n  storage:", 1)
    scenario = load_text(text, tmp_path)
    perimeter = {("j0_0", "j1_0"), ("j1_0", "j1_1"), ("j1_1", "j0_1"), ("j0_1", "j0_0")}
    assert set(scenario.one_way) == perimeter  # counter-clockwise
    graph = scenario.build_lane_graph(segment_m=2.0).graph
    assert nx.is_strongly_connected(graph)
    assert all(not graph.has_edge(b, a) for a, b in graph.edges)  # no lane both ways
