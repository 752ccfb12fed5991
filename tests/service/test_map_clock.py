"""The map's clock on its own (docs/map-time.md): stamps judged against the wall clock, a
declared simulation clock, or the map's simulated time; never against which units talk."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mapserver.service.map_clock import (
    DECLARED,
    EPOCH_FLOOR_S,
    SIMULATED,
    WALL,
    ClockDeclarationError,
    MapClock,
)

WALL_NOW = 1.7e9


class Wall:
    """A wall clock the test moves."""

    def __init__(self, now=WALL_NOW):
        self.now = now

    def __call__(self):
        return self.now


def clock(wall=None, **kw):
    return MapClock(wall_clock=wall or Wall(), **kw)


def test_no_stamp_may_lead_the_wall_clock_by_more_than_max_lead():
    c = clock()
    assert c.check(WALL_NOW + 5.0) is None
    lead = c.check(WALL_NOW + 300.0)
    assert lead.reference.kind == WALL and lead.offset_s == pytest.approx(300.0)
    assert "is 300 s ahead of the server's clock" in lead.describe()
    assert "this unit's clock runs 300 s ahead" in lead.describe()
    assert c.check(1e15).reference.kind == WALL


def test_epoch_stamps_of_a_fleet_that_comes_and_goes_are_never_refused():
    wall = Wall()
    c = clock(wall)
    for _ in range(100):  # half the fleet docked 2 minutes ago; the rest posts on time
        wall.now += 0.1
        for stamp in (wall.now - 120.0, wall.now, wall.now - 30.0, wall.now + 4.9):
            assert c.check(stamp) is None
            c.observe(stamp)
    assert c.reference().kind == WALL  # an epoch map binds no simulated time


def test_the_map_simulated_time_bounds_a_jump_but_not_a_laggard_or_a_late_joiner():
    wall = Wall()
    c = clock(wall, max_lead_s=5.0, max_sim_rate=10.0)
    for k in range(11):
        c.observe(float(k))  # a simulated fleet at 0..10 s
    lead = c.check(310.0)
    assert lead.reference.kind == SIMULATED and lead.reference.value == 10.0
    assert "300 s ahead of the map's simulated time (10.0 s: 10.0 s when" in lead.describe()
    assert c.check(15.0) is None and c.check(0.0) is None  # within the lead; a laggard
    wall.now += 5.0  # all silent 5 wall seconds: simulated time may have run 50 s on
    assert c.check(65.0) is None and c.check(65.1).reference.value == 60.0
    wall.now += 25.0  # 30 s: 300 s on; the bound runs on with the wall, never lapses
    assert c.check(315.0) is None and c.check(315.1) is not None
    assert c.reference().kind == SIMULATED


def test_an_epoch_stamp_is_refused_while_a_simulation_posts_and_taken_once_it_lapsed():
    wall = Wall()
    c = clock(wall)
    c.observe(12.0)
    assert c.check(WALL_NOW).reference.kind == SIMULATED
    wall.now += 11.0
    assert c.check(WALL_NOW) is None
    c.observe(WALL_NOW)
    assert c.reference().kind == WALL and c.check(3.0) is None  # sim stamps now lag


def test_a_declared_clock_binds_every_stamp_until_it_lapses():
    wall = Wall()
    c = clock(wall, sim_ttl_s=10.0)
    c.observe(100.0)
    c.declare(50.0)  # a simulation reset: the declared clock may go back
    assert c.reference().kind == DECLARED and c.declared() == (50.0, 0.0)
    assert c.check(55.0) is None
    lead = c.check(100.0)
    assert lead.reference.kind == DECLARED
    assert "declared simulation clock (50.0 s)" in lead.describe()
    wall.now += 10.5
    assert c.declared() is None and c.check(100.0) is None


@pytest.mark.parametrize("now", [WALL_NOW + 6.0, math.inf, math.nan, True, "1"])
def test_a_declared_clock_must_be_a_finite_time_not_ahead_of_the_wall(now):
    c = clock()
    with pytest.raises(ClockDeclarationError, match="^now: "):
        c.declare(now)
    assert c.declared() is None


def test_state_and_restore_take_back_what_was_observed():
    c = clock()
    c.observe(3.0)
    saved = c.state()
    c.observe(8.0)
    c.restore(saved)
    assert c.map_stamp == 3.0


def test_a_restored_simulated_map_runs_on_from_the_restart():
    wall = Wall()
    c = clock(wall)
    c.resume(42.0)
    assert c.map_stamp == 42.0 and c.check(47.0) is None and c.check(47.1) is not None
    assert c.check(WALL_NOW) is not None  # an epoch stamp waits for sim_ttl_s
    wall.now += 10.5
    assert c.check(WALL_NOW + 10.5) is None


def test_an_empty_map_takes_any_stamp_behind_the_wall_clock():
    c = clock()
    assert c.check(0.0) is None and c.check(9e8) is None and c.check(WALL_NOW) is None
    assert c.reference().kind == WALL


@given(
    stamps=st.lists(st.floats(0.0, EPOCH_FLOOR_S * 2, allow_nan=False), min_size=1, max_size=40),
    behind=st.floats(0.0, 1e9),
)
def test_a_stamp_behind_every_accepted_one_is_never_refused(stamps, behind):
    """Whatever others posted, a unit whose stamp is not ahead of the map's time is taken:
    going quiet, joining late and lagging never get a scan refused."""
    c = clock()
    for stamp in stamps:
        if c.check(stamp) is None:
            c.observe(stamp)
    assert c.check(min(c.map_stamp, WALL_NOW) - behind) is None
