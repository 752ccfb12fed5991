"""The fleet clock: a stamp may lead the wall clock and the fleet's median by a bound."""

from hypothesis import given
from hypothesis import strategies as st

from mapserver.service.fleet_clock import FleetClock

WALL = 1.8e9  # [s] the server's epoch clock in these tests


def clock(max_lead_s=5.0, window_scans=1000):
    return FleetClock(max_lead_s, window_scans, wall_clock=lambda: WALL)


def test_an_empty_fleet_bounds_stamps_by_the_wall_clock_only():
    c = clock()
    assert c.fleet_median() is None
    assert c.check(WALL + 5.0) is None
    lead = c.check(WALL + 5.5)
    assert lead.reference == WALL and lead.reference_name == "the server's wall clock"
    assert "leads the server's wall clock" in lead.describe() and "by 5.5 s" in lead.describe()


def test_a_unit_may_lead_the_lower_median_of_the_fleet_by_max_lead():
    c = clock()
    for unit, stamp in (("u1", 10.0), ("u2", 11.0), ("u3", 12.0), ("u4", 13.0)):
        c.observe(unit, stamp)
    assert c.fleet_median() == 11.0  # lower median of 10, 11, 12, 13
    assert c.check(16.0) is None
    lead = c.check(16.5)
    assert (lead.reference, lead.stamp, lead.max_lead_s) == (11.0, 16.5, 5.0)
    assert "clock.max_lead_s = 5 s" in lead.describe()


def test_with_two_units_the_slower_one_holds_the_clock():
    c = clock()
    c.observe("good", 100.0)
    c.observe("bad", 105.0)  # as far ahead as it may be
    assert c.fleet_median() == 100.0
    assert c.check(105.1) is not None  # the bad unit cannot step further on its own
    c.observe("good", 100.1)
    assert c.check(105.1) is None


def test_units_silent_for_the_window_no_longer_count():
    c = clock(window_scans=3)
    c.observe("old", 1.0)
    for stamp in (50.0, 50.1, 50.2):
        c.observe("u1", stamp)
    assert c.fleet_median() == 50.2  # "old" was last heard 3 scans ago


def test_state_and_restore_take_back_observations():
    c = clock()
    c.observe("u1", 1.0)
    saved = c.state()
    c.observe("u2", 3.0)
    c.observe("u1", 2.0)
    c.restore(saved)
    assert c.fleet_median() == 1.0
    c.observe("u2", 3.0)
    assert c.fleet_median() == 1.0  # sorted stamps [1, 3]: lower median 1


@given(
    st.lists(
        st.tuples(st.sampled_from(["u1", "u2", "u3", "u4", "u5"]), st.floats(0, 1e6)),
        min_size=1,
        max_size=60,
    ),
    st.integers(1, 20),
)
def test_the_median_is_the_lower_median_of_the_heard_units_latest_stamps(events, window):
    c = clock(window_scans=window)
    for unit, stamp in events:
        c.observe(unit, stamp)
    recent = events[-window:]
    latest = {}
    for unit, stamp in events:  # every unit's latest stamp, if heard within the window
        latest[unit] = stamp
    heard = {unit for unit, _ in recent}
    stamps = sorted(latest[u] for u in heard)
    assert c.fleet_median() == stamps[(len(stamps) - 1) // 2]
