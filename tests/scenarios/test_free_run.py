"""The congestion-free run (``scenarios.score.free_run``), the fleet benchmark's bound:
exact counts from its trips' ideal times, breakdowns as pauses, invariants, and that it
depends on the floor, trips and dispatcher but not on the lane coordinator."""

from __future__ import annotations

import dataclasses
import itertools
import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from scenarios.score.free_run import free_run, paused_end
from scenarios.spec.scenario import load_scenario
from tests.scenario_helpers import TINY

FLOOR = Path(__file__).resolve().parents[1] / "benchmarks" / "floors" / "two_way_30x25.yaml"


def tiny_backlog(folder: Path, units: int = 1, trips: int = 8, events: str = "") -> Path:
    """tiny.yaml with ``units`` units, a backlog of ``trips`` trips, 300 s, and ``events``
    (YAML list items) in place of its tote."""
    text = TINY.read_text(encoding="utf-8")
    text = text.replace("duration: 20.0", "duration: 300.0")
    text = text.replace("units:\n  count: 2", f"units:\n  count: {units}")
    text = text.replace("tasks:\n  count: 2", f"tasks:\n  count: {trips}")
    head, _, _ = text.partition("events:")
    path = folder / "backlog.yaml"
    path.write_text(head + ("events:\n" + events if events else ""), encoding="utf-8")
    return path


def test_one_unit_finishes_its_trips_back_to_back(tmp_path):
    # One unit and a backlog: trip k ends at the sum of the first k ideal times, so the
    # run cut at that instant has done k, and a hair before it k - 1.
    scenario = load_scenario(tiny_backlog(tmp_path))
    whole = free_run(scenario)
    assert whole.trips == whole.given == 8
    ends = list(itertools.accumulate(whole.ideal_s))
    assert all(s > 0 for s in whole.ideal_s)
    for k, end in enumerate(ends, start=1):
        assert free_run(scenario, end).trips == k
        assert free_run(scenario, end - 0.01).trips == k - 1
        assert free_run(scenario, end - 0.01).given == k  # the k-th is under way


def test_a_breakdown_pauses_the_unit(tmp_path):
    # Broken down from 5 s for 40 s: the trip under way ends 40 s later, and so does
    # every trip after it.
    plain = free_run(load_scenario(tiny_backlog(tmp_path)))
    broken = load_scenario(
        tiny_backlog(tmp_path, events="  - {at: 5.0, breakdown: u1, duration: 40.0}\n")
    )
    ends = list(itertools.accumulate(plain.ideal_s))
    assert ends[0] > 5.0
    for k, end in enumerate(ends, start=1):
        assert free_run(broken, end + 40.0).trips == k
        assert free_run(broken, end + 39.9).trips == k - 1


def test_a_unit_broken_down_for_good_finishes_nothing(tmp_path):
    events = "  - {at: 1.0, breakdown: u1}\n"
    assert free_run(load_scenario(tiny_backlog(tmp_path, events=events))).trips == 0


def test_two_units_do_at_least_what_one_does(tmp_path):
    one = free_run(load_scenario(tiny_backlog(tmp_path, units=1, trips=20)), 120.0)
    two = free_run(load_scenario(tiny_backlog(tmp_path, units=2, trips=20)), 120.0)
    assert two.trips > one.trips


def test_the_same_for_every_coordinator_and_run():
    scenario = load_scenario(FLOOR)
    runs = {
        policy: free_run(
            dataclasses.replace(
                scenario, coordination=dataclasses.replace(scenario.coordination, policy=policy)
            )
        )
        for policy in ("reserve_ahead", "pibt")
    }
    assert runs["pibt"] == runs["reserve_ahead"] == free_run(scenario)
    assert runs["pibt"].trips > 0


def test_never_more_than_the_fluid_bound():
    # A unit drives one trip at a time, each in its ideal time, all done by the end: the
    # completed trips' ideal times sum to at most units x seconds.
    scenario = load_scenario(FLOOR)
    run = free_run(scenario)
    assert 0 < run.trips <= run.given
    assert sum(run.ideal_s) <= scenario.units.count * run.sim_s


@pytest.mark.parametrize("cut", [30.0, 60.0, 120.0])
def test_a_longer_run_does_no_fewer(cut):
    scenario = load_scenario(FLOOR)
    assert free_run(scenario, cut).trips <= free_run(scenario, cut + 30.0).trips


@given(
    start=st.floats(0.0, 100.0),
    duration=st.floats(0.0, 100.0),
    spans=st.lists(st.tuples(st.floats(0.0, 200.0), st.floats(0.0, 50.0)), max_size=4),
)
def test_paused_work_is_never_shorter_and_never_inside_a_breakdown(start, duration, spans):
    spans = sorted((a, a + d) for a, d in spans)
    begin, end = paused_end(start, duration, spans)
    assert begin >= start
    assert end - begin >= duration - 1e-9
    assert not any(a < begin < b for a, b in spans if b > a and not math.isclose(begin, b))


def test_paused_work_exact():
    assert paused_end(0.0, 40.0, [(20.0, 50.0)]) == (0.0, 70.0)
    assert paused_end(25.0, 40.0, [(20.0, 50.0)]) == (50.0, 90.0)
    assert paused_end(0.0, 10.0, [(20.0, 50.0)]) == (0.0, 10.0)
    assert paused_end(0.0, 10.0, []) == (0.0, 10.0)


def test_a_run_reports_its_trips_against_its_congestion_free_run():
    from scenarios.run.runner import run

    scenario = load_scenario(TINY)
    metrics = run(scenario).metrics
    free = free_run(scenario, metrics["sim_seconds"]).trips
    # tiny.yaml's two trips go to its two units at 0 s; alone, one takes 18.8 s and the
    # other 23.8 s, past the run's 20 s.
    assert free == 1 and free_run(scenario, 24.0).trips == 2
    assert metrics["trips_free_run"] == free
    assert metrics["trips_of_free_run"] == round(metrics["tasks_completed"] / free, 4)
