"""The scenario file's ``coordination.policy``: validated, defaulted, and run."""

from pathlib import Path

import pytest

from scenarios.spec.scenario import ScenarioError, load_scenario, parse_scenario

TINY = Path("scenarios/tiny.yaml")


def test_the_default_is_todays_reserve_ahead():
    assert load_scenario(TINY).coordination == "reserve_ahead"


def test_pibt_can_be_chosen_in_the_file_or_by_an_override():
    text = TINY.read_text() + "\ncoordination:\n  policy: pibt\n"
    assert parse_scenario(text, "tiny.yaml").coordination == "pibt"
    assert load_scenario(TINY, {"coordination.policy": "pibt"}).coordination == "pibt"


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
