"""The fleet benchmark's congestion-free schedule bound (``tests/benchmarks/fleet.py``,
``scheduled_trip_bound``): exact counts from the schedule's arithmetic, and invariants
against the fluid bound."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from tests.benchmarks.fleet import scheduled_trip_bound


def test_a_backlog_is_whole_trips_per_unit():
    # 3 units, a backlog released at 0, 50 s trips, 120 s: each unit finishes 2 (at 50 and
    # 100 s); the third is under way at the end, which the fluid bound counts as 0.4.
    assert scheduled_trip_bound([0.0] * 20, 3, 120.0, 50.0) == 6


def test_a_trip_finishing_exactly_at_the_end_counts():
    assert scheduled_trip_bound([0.0] * 4, 2, 100.0, 50.0) == 4


def test_trips_wait_for_their_release():
    # One unit, trips released at 0, 10 and 200 s, 30 s each, 220 s: 0-30, 30-60, then
    # the third starts at its release (200 s) and is not done by 220 s.
    assert scheduled_trip_bound([0.0, 10.0, 200.0], 1, 220.0, 30.0) == 2
    assert scheduled_trip_bound([0.0, 10.0, 200.0], 1, 230.0, 30.0) == 3


def test_a_breakdown_pauses_the_trip_under_way():
    # One unit, 40 s trips, broken from 20 to 50 s: the first trip ends at 70 s, the
    # second at 110 s; by 100 s one trip, by 110 s two.
    assert scheduled_trip_bound([0.0] * 5, 1, 100.0, 40.0, {0: [(20.0, 50.0)]}) == 1
    assert scheduled_trip_bound([0.0] * 5, 1, 110.0, 40.0, {0: [(20.0, 50.0)]}) == 2


def test_a_unit_broken_down_at_a_start_waits_for_its_repair():
    # Two units; unit 0 broken from 0 to 30 s. Trips of 20 s released at 0: unit 0's
    # first trip starts at 30 s and ends at 50 s; unit 1 ends at 20, 40, 60 s. By 60 s: 4.
    assert scheduled_trip_bound([0.0] * 10, 2, 60.0, 20.0, {0: [(0.0, 30.0)]}) == 4


def test_a_unit_broken_down_for_good_finishes_nothing_more():
    assert scheduled_trip_bound([0.0] * 10, 2, 100.0, 20.0, {0: [(10.0, math.inf)]}) == 5


def test_no_ideal_trip_time_no_bound():
    assert scheduled_trip_bound([0.0], 2, 100.0, None) is None
    assert scheduled_trip_bound([0.0], 0, 100.0, 10.0) is None


@given(
    releases=st.lists(st.floats(0.0, 500.0), max_size=60),
    units=st.integers(1, 8),
    sim_s=st.floats(1.0, 600.0),
    ideal=st.floats(1.0, 200.0),
)
def test_never_above_the_fluid_bound_nor_the_releases(releases, units, sim_s, ideal):
    released = [r for r in releases if r < sim_s]
    done = scheduled_trip_bound(released, units, sim_s, ideal)
    assert 0 <= done <= len(released)
    assert done <= units * sim_s / ideal + 1e-9


@given(
    releases=st.lists(st.floats(0.0, 300.0), min_size=1, max_size=40),
    units=st.integers(1, 6),
    ideal=st.floats(1.0, 100.0),
)
def test_more_units_or_more_time_never_fewer_trips(releases, units, ideal):
    base = scheduled_trip_bound(releases, units, 300.0, ideal)
    assert scheduled_trip_bound(releases, units + 1, 300.0, ideal) >= base
    assert scheduled_trip_bound(releases, units, 400.0, ideal) >= base
