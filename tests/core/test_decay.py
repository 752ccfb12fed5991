"""Lazy freshness decay: exact fades, separate half lives, faded cells are unknown."""

import math

import numpy as np
import pytest
from conftest import make_scan

from mapserver.core.belief import BeliefGrid, CellState
from mapserver.core.geometry import GridGeometry
from mapserver.core.sensor_model import DecayParams, Policy, SensorModel

M = SensorModel()
D = DecayParams(half_life_occupied=10.0, half_life_free=40.0, fade_bound=0.05)


def observed_grid(policy=Policy.DECAY) -> BeliefGrid:
    b = BeliefGrid(GridGeometry(12, 1, 1.0), M, policy, D)
    b.fuse(make_scan([5.0], stamp=100.0))  # cells 0..4 free (l_miss), cell 5 hit (l_hit)
    return b


def test_evidence_fades_by_half_each_half_life_with_separate_half_lives():
    b = observed_grid()
    one = b.log_odds_at(110.0)[0]
    two = b.log_odds_at(120.0)[0]
    assert one[5] == pytest.approx(M.l_hit / 2, rel=1e-6)
    assert two[5] == pytest.approx(M.l_hit / 4, rel=1e-6)
    assert b.log_odds_at(140.0)[0, 0] == pytest.approx(M.l_miss / 2, rel=1e-6)
    assert b.log_odds_at(180.0)[0, 0] == pytest.approx(M.l_miss / 4, rel=1e-6)
    assert b.raw_log_odds()[0, 5] == pytest.approx(M.l_hit)  # reading never writes


def test_decay_is_applied_before_new_evidence_is_added():
    b = observed_grid()
    b.fuse(make_scan([5.0], stamp=110.0))
    assert b.raw_log_odds()[0, 5] == pytest.approx(M.l_hit / 2 + M.l_hit, rel=1e-6)
    assert b.raw_log_odds()[0, 0] == pytest.approx(M.l_miss * 2**-0.25 + M.l_miss, rel=1e-6)
    assert b.last_observed()[0, 5] == 110.0


def test_an_occupied_cell_that_is_not_observed_again_fades_to_unknown():
    b = observed_grid()
    assert b.states_at(100.0)[0, 5] == CellState.OCCUPIED
    # l_hit = 0.847 falls below the occupied threshold (0.619) after 4.5 s ...
    assert b.states_at(105.0)[0, 5] == CellState.UNKNOWN
    # ... and below the fade bound after log2(0.847 / 0.05) = 4.08 half lives.
    t_faded = 100.0 + 10.0 * math.log2(M.l_hit / D.fade_bound) + 0.01
    assert np.isnan(b.probability_at(t_faded)[0, 5])
    assert not np.isnan(b.probability_at(t_faded - 0.1)[0, 5])


def test_a_faded_cell_reads_as_never_observed_except_for_its_age():
    b = observed_grid()
    p = b.probability_at(1000.0)[0]
    assert np.all(np.isnan(p))
    assert np.all(b.states_at(1000.0)[0] == CellState.UNKNOWN)
    assert np.all(b.last_observed()[0, :6] == 100.0)


def test_reading_in_the_past_never_amplifies_evidence():
    b = observed_grid()
    assert b.log_odds_at(50.0)[0, 5] == pytest.approx(M.l_hit)


@pytest.mark.parametrize("policy", [Policy.STICKY, Policy.BINARY])
def test_sticky_and_binary_never_fade(policy):
    b = observed_grid(policy)
    assert np.array_equal(b.log_odds_at(1e6), b.raw_log_odds())
    assert b.states_at(1e6)[0, 5] == CellState.OCCUPIED


def test_free_cells_need_repeated_passes_to_read_free():
    b = BeliefGrid(GridGeometry(12, 1, 1.0), M, Policy.DECAY, D)
    for i in range(3):
        b.fuse(make_scan([5.0], stamp=100.0))
        expected = CellState.FREE if i == 2 else CellState.UNKNOWN  # -1.216 < logit(0.25)
        assert b.states_at(100.0)[0, 0] == expected


def test_the_freshness_view_gives_the_age_of_each_cells_evidence():
    b = observed_grid()
    b.fuse(make_scan([2.0], stamp=103.0))  # cells 0..2 seen again
    age = b.age_at(110.0)[0]
    assert age[:3].tolist() == [7.0, 7.0, 7.0]
    assert age[3:6].tolist() == [10.0, 10.0, 10.0]
    assert np.all(np.isnan(age[6:]))
