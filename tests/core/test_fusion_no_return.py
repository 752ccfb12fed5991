"""No-return beams (REP 117: range > range_max or +inf) are weak evidence of free space:
``l_miss_no_return`` per cell, only out to ``no_return_range``; returns are unchanged."""

import math

import numpy as np
import pytest
from conftest import make_scan
from hypothesis import given
from hypothesis import strategies as st

from mapserver.core.belief import BeliefGrid
from mapserver.core.geometry import GridGeometry
from mapserver.core.sensor_model import Policy, SensorModel, logit

M = SensorModel()  # p_miss_no_return 0.45, no_return_range 1 m
FAR = SensorModel(no_return_range=5.0)


def row(model=M, width=30, policy=Policy.DECAY, **kw) -> BeliefGrid:
    return BeliefGrid(GridGeometry(width, 1, 1.0), model, policy, **kw)


def test_a_no_return_beam_moves_cells_by_its_own_log_odds_out_to_its_range_only():
    b = row()
    result = b.fuse(make_scan([math.inf], range_max=20.0))  # from x = 0.5: to x = 1.5
    lo = b.raw_log_odds()[0]
    assert lo[:2] == pytest.approx([math.log(0.45 / 0.55)] * 2)  # -0.2007 each, cells 0, 1
    assert np.all(lo[2:] == 0.0)
    assert result.cells == 2
    assert np.all(np.isnan(b.last_observed()[0, 2:]))


def test_a_reading_beyond_range_max_is_a_no_return_too():
    b = row(SensorModel(p_miss_no_return=0.42, no_return_range=6.0))
    b.fuse(make_scan([25.0], range_max=20.0))
    lo = b.raw_log_odds()[0]
    assert lo[:7] == pytest.approx([logit(0.42)] * 7)  # to x = 6.5: cells 0..6
    assert np.all(lo[7:] == 0.0)


def test_the_scan_range_max_and_max_clearing_range_still_cap_it():
    b = row(SensorModel(no_return_range=None), max_clearing_range=5.0)
    b.fuse(make_scan([math.inf], range_max=8.0))
    assert np.count_nonzero(b.raw_log_odds()) == 6  # min(inf, 8, 5) = 5 m: cells 0..5
    b = row(SensorModel(no_return_range=None))
    b.fuse(make_scan([math.inf], range_max=8.0))
    assert np.count_nonzero(b.raw_log_odds()) == 9  # range_max: cells 0..8


def test_a_returning_beam_is_unchanged():
    b = row()
    b.fuse(make_scan([12.0]))
    lo = b.raw_log_odds()[0]
    assert lo[:12] == pytest.approx([M.l_miss] * 12)
    assert lo[12] == pytest.approx(M.l_hit)
    assert np.all(lo[13:] == 0.0)


def test_a_cell_a_return_also_crosses_takes_the_return_s_evidence_once():
    b = row(SensorModel(no_return_range=8.0))
    b.fuse(make_scan([math.inf, 5.0, math.inf], angle_increment=1e-7))
    lo = b.raw_log_odds()[0]
    assert lo[:5] == pytest.approx([M.l_miss] * 5)  # crossed by all three beams
    assert lo[5] == pytest.approx(M.l_hit)  # the return's endpoint, never weakened
    assert lo[6:9] == pytest.approx([M.l_miss_no_return] * 3)  # no-return only, to x = 8.5
    assert np.all(lo[9:] == 0.0)


def test_repeated_no_return_scans_add_up_and_are_clamped_like_any_evidence():
    b = row()
    for _ in range(3):
        b.fuse(make_scan([math.inf], stamp=0.0))  # same stamp: nothing fades
    assert b.raw_log_odds()[0, 0] == pytest.approx(3 * logit(0.45), rel=1e-6)
    for _ in range(30):
        b.fuse(make_scan([math.inf], stamp=0.0))
    assert b.raw_log_odds()[0, 0] == pytest.approx(M.clamp_min)


def test_a_saturated_wall_cell_survives_dropouts_that_would_have_cleared_it():
    """Under ``decay``, a cell held at clamp_max by returns needs 5 / 0.2007 = 25 no-return
    passes to reach the prior (12.3 at p_miss: twice as many)."""
    b = row(FAR)
    for _ in range(10):
        b.fuse(make_scan([2.0]))  # cell 2 hit ten times: clamped at +5
    for _ in range(12):
        b.fuse(make_scan([math.inf]))
    assert b.raw_log_odds()[0, 2] == pytest.approx(5.0 + 12 * logit(0.45), rel=1e-6)
    assert b.states_at()[0, 2] == 2  # still OCCUPIED (2.59 > 0.619)


def test_at_the_prior_no_return_beams_change_nothing():
    b = row(SensorModel(p_miss_no_return=0.5))
    result = b.fuse(make_scan([math.inf, 30.0], angle_increment=1e-7))
    assert result.cells == 0 and result.box.empty
    assert np.all(b.raw_log_odds() == 0.0)
    assert np.all(np.isnan(b.last_observed()))


def test_binary_clears_with_no_return_beams_out_to_range_max_as_the_baseline_does():
    """The baseline keeps the contract's range semantics at full range (Nav2's obstacle
    layer with ``inf_is_valid: true``): a dropout erases the wall it passes."""
    b = row(FAR, policy=Policy.BINARY)
    b.fuse(make_scan([2.0]))
    assert b.raw_log_odds()[0, 2] == M.clamp_max
    b.fuse(make_scan([math.inf], stamp=1.0))
    assert b.raw_log_odds()[0, 2] == M.clamp_min  # last ray wins, whatever no_return_range
    assert b.no_return_clearing(20.0) == 20.0


@given(
    ranges=st.lists(
        st.one_of(st.floats(0.1, 9.0), st.just(math.inf), st.floats(10.5, 50.0)),
        min_size=1,
        max_size=12,
    ),
    nr_range=st.floats(0.5, 12.0),
)
def test_one_scan_gives_each_cell_one_of_the_three_evidences(ranges, nr_range):
    """Property: after one scan every cell holds 0, l_hit, l_miss or l_miss_no_return, and
    cells only no-return beams reach lie within no_return_range of the sensor."""
    model = SensorModel(no_return_range=nr_range)
    b = BeliefGrid(GridGeometry(24, 24, 1.0), model)
    b.fuse(make_scan(ranges, x=12.0, y=12.0, angle_increment=0.4, range_max=10.0))
    lo = b.raw_log_odds().astype(np.float64)
    allowed = [0.0, model.l_hit, model.l_miss, model.l_miss_no_return]
    assert np.all(np.min([np.abs(lo - v) for v in allowed], axis=0) < 1e-6)
    rows, cols = np.nonzero(np.isclose(lo, model.l_miss_no_return))
    dist = np.hypot(cols + 0.5 - 12.0, rows + 0.5 - 12.0)
    assert np.all(dist <= min(nr_range, 10.0) + math.sqrt(2))  # within a cell's diagonal
