"""The scenario file's ``coordination`` section: validated, defaulted, swept, and run."""

from pathlib import Path

import pytest

from planner.coordination_state import CoordinatorSettings
from scenarios.run.episode import _coordinator
from scenarios.spec.coordination import CoordinationSpec
from scenarios.spec.scenario import ScenarioError, load_scenario, parse_scenario
from scenarios.sweep.sweep_file import load_sweep

TINY = Path("scenarios/tiny.yaml")
KNOBS = """
coordination:
  policy: pibt
  segment_m: 2.5
  reserve_ahead_m: 0
  clear_m: 1.1
  arrive_tol: 0.2
  retry_s: 2
  back_off_hops: 5
  lane_refresh_s: 0.5
  lanes_from: server
  dispatch: first
"""


def test_the_default_is_todays_reserve_ahead():
    assert load_scenario(TINY).coordination == CoordinationSpec()
    assert CoordinationSpec().policy == "reserve_ahead"


def test_pibt_can_be_chosen_in_the_file_or_by_an_override():
    text = TINY.read_text() + "\ncoordination:\n  policy: pibt\n"
    assert parse_scenario(text, "tiny.yaml").coordination.policy == "pibt"
    assert load_scenario(TINY, {"coordination.policy": "pibt"}).coordination.policy == "pibt"


def test_the_coordinator_takes_its_settings_from_the_file():
    scenario = parse_scenario(TINY.read_text() + KNOBS, "tiny.yaml")
    spec = scenario.coordination
    assert spec == CoordinationSpec("pibt", 2.5, 0.0, 1.1, 0.2, 2.0, 5, 0.5, "server", "first")
    coord = _coordinator(scenario.build_lane_graph(), None, scenario.unit_specs(), spec)
    assert coord.policy == "pibt"
    assert coord.settings == CoordinatorSettings(1.0, 1.1, 0.2, 2.0, 0.0, 5)


def test_unset_clearance_and_reach_come_from_the_units_drive():
    scenario = load_scenario(TINY)  # radius 0.3 m, 1.5 m/s, 1.0 m/s^2
    settings = _coordinator(
        scenario.build_lane_graph(), None, scenario.unit_specs(), scenario.coordination
    ).settings
    assert settings.clear_m == pytest.approx(2 * 0.3 + 0.2)  # the diameter + 0.2 m
    assert settings.reserve_ahead_m == pytest.approx(1.5**2 / (2 * 1.0) + 1.0)  # braking + 1 m


@pytest.mark.parametrize(
    ("key", "value", "reason"),
    [
        ("segment_m", -1, "must be a number of metres > 0"),
        ("reserve_ahead_m", -0.5, "must be a number of metres >= 0"),
        ("clear_m", "wide", "must be a number of metres > 0"),
        ("arrive_tol", 0, "must be a number of metres > 0"),
        ("retry_s", True, "must be a number of seconds > 0"),
        ("back_off_hops", 0, "must be an integer of edges in [1, 100]"),
        ("back_off_hops", 2.5, "must be an integer of edges in [1, 100]"),
        ("lane_refresh_s", -1, "must be a number of seconds > 0"),
        ("lanes_from", "disk", "must be one of costmap, server"),
        ("dispatch", "far", "must be one of first, nearest"),
    ],
)
def test_a_bad_knob_is_refused_naming_the_field_the_value_and_the_range(key, value, reason):
    with pytest.raises(ScenarioError) as caught:
        load_scenario(TINY, {f"coordination.{key}": value})
    assert f"coordination.{key} (override): {reason}, got {value!r}" in str(caught.value)


@pytest.mark.parametrize("value", ["pibbt", "PIBT", 3, None])
def test_a_bad_policy_is_refused_naming_the_field_and_the_value(value):
    with pytest.raises(ScenarioError) as caught:
        load_scenario(TINY, {"coordination.policy": value})
    message = str(caught.value)
    assert "coordination.policy" in message
    assert "must be one of reserve_ahead, pibt" in message
    assert repr(value) in message


def test_an_unknown_coordination_key_is_refused():
    text = TINY.read_text() + "\ncoordination:\n  polcy: pibt\n"
    with pytest.raises(ScenarioError, match=r"coordination\.polcy.*did you mean 'policy'"):
        parse_scenario(text, "tiny.yaml")
    text = TINY.read_text() + "\ncoordination:\n  reserve_ahed_m: 2\n"
    with pytest.raises(ScenarioError, match=r"did you mean 'reserve_ahead_m'"):
        parse_scenario(text, "tiny.yaml")


def test_coordination_knobs_are_swept_like_any_scenario_field(tmp_path):
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(
        f"scenarios: [{TINY.resolve()}]\npolicies: [decay]\nparameters:\n"
        "  coordination.policy: [reserve_ahead, pibt]\n"
        "  coordination.reserve_ahead_m: [0, 2.5]\n"
    )
    combos = load_sweep(sweep).combinations()
    assert len(combos) == 4
    loaded = {load_scenario(TINY, dict(c)).coordination for c in combos}
    assert {(s.policy, s.reserve_ahead_m) for s in loaded} == {
        ("reserve_ahead", 0.0), ("reserve_ahead", 2.5), ("pibt", 0.0), ("pibt", 2.5)
    }  # fmt: skip
    sweep.write_text(
        f"scenarios: [{TINY.resolve()}]\nparameters:\n  coordination.back_off_hops: [0]\n"
    )
    with pytest.raises(ScenarioError, match=r"coordination\.back_off_hops.*\[1, 100\], got 0"):
        load_sweep(sweep)
