"""Exact numbers from the log-odds maths, through the real fusion kernel.

One row of 1 m cells; the sensor sits in cell 0 looking along +x. A beam with range
r ends in cell floor(0.5 + r): range 3.5 ends in cell 4 (a HIT there, FREE in 0..3),
range 9.0 ends in cell 9 and so passes cell 4 (FREE).
"""

import numpy as np
import pytest
from conftest import make_scan, p_of

from mapserver.core.belief import BeliefGrid
from mapserver.core.geometry import GridGeometry
from mapserver.core.sensor_model import Policy, SensorModel, sigmoid

CELL = 4
HIT_RANGE = 3.5  # ends in cell 4
PASS_RANGE = 9.0  # passes cell 4


def model(**kwargs) -> SensorModel:
    """The textbook increments: +0.9 per hit, -0.4 per pass, prior 0.5."""
    return SensorModel(p_hit=sigmoid(0.9), p_miss=sigmoid(-0.4), **kwargs)


def grid(policy=Policy.STICKY, **kwargs) -> BeliefGrid:
    return BeliefGrid(GridGeometry(12, 1, 1.0), model(**kwargs), policy)


def feed(b: BeliefGrid, updates: list[float]) -> list[float]:
    """Fuse one scan per update (+ hit, - pass) and return the cell's L after each."""
    out = []
    for u in updates:
        b.fuse(make_scan([HIT_RANGE if u > 0 else PASS_RANGE], stamp=b.scans_fused))
        out.append(float(b.raw_log_odds()[0, CELL]))
    return out


def test_two_passes_then_a_hit_give_l_0_1_and_p_0_52():
    L = feed(grid(), [-0.4, -0.4, 0.9])
    assert L[-1] == pytest.approx(0.1, abs=1e-6)
    assert round(p_of(L[-1]), 2) == 0.52


def test_five_ray_step_through_matches_the_textbook():
    L = feed(grid(), [-0.4, -0.4, 0.9, 0.9, 0.9])
    assert [round(p_of(v), 2) for v in L] == [0.40, 0.31, 0.52, 0.73, 0.87]
    assert L == pytest.approx([-0.4, -0.8, 0.1, 1.0, 1.9], abs=1e-6)


def test_clamped_saturated_cell_needs_13_free_updates_to_fall_below_one_half():
    b = grid(Policy.DECAY)  # clamped; all stamps equal so nothing fades
    for _ in range(20):
        b.fuse(make_scan([HIT_RANGE], stamp=0.0))
    assert b.raw_log_odds()[0, CELL] == 5.0
    n = 0
    while b.raw_log_odds()[0, CELL] >= 0.0:
        b.fuse(make_scan([PASS_RANGE], stamp=0.0))
        n += 1
    assert n == 13


def count_passes_to_flip(b: BeliefGrid) -> int:
    n = 0
    while b.raw_log_odds()[0, CELL] >= -1e-4:  # below 0.5 beyond float32 rounding
        b.fuse(make_scan([PASS_RANGE], stamp=0.0))
        n += 1
    return n


def test_unclamped_cell_at_plus_50_needs_125_passes_to_reach_0_and_126_to_fall_below():
    b = grid(Policy.STICKY)
    lo = np.zeros((1, 12), np.float32)
    lo[0, CELL] = 50.0
    b.load_state(lo, np.zeros((1, 12)), stamp=0.0)
    L = feed(b, [-0.4] * 126)
    assert L[123] > 0.0
    assert L[124] == pytest.approx(0.0, abs=1e-4)
    assert L[125] < -0.39
    assert count_passes_to_flip(b) == 0


def test_thirty_unclamped_hits_need_68_passes():
    b = grid(Policy.STICKY)
    L = feed(b, [0.9] * 30)
    assert L[-1] == pytest.approx(27.0, abs=1e-4)
    assert count_passes_to_flip(b) == 68


def test_zero_evidence_never_moves_a_cell_and_the_prior_is_subtracted_once():
    prior = 0.3
    l0 = float(np.log(prior / (1 - prior)))
    m = SensorModel(
        p_hit=sigmoid(l0 + 0.5), p_miss=sigmoid(l0 - 0.5), prior=prior, p_miss_no_return=prior
    )
    b = BeliefGrid(GridGeometry(12, 1, 1.0), m, Policy.STICKY)
    start = b.raw_log_odds().copy()
    assert np.all(start == np.float32(l0))
    for i in range(50):  # a hit and a pass of equal and opposite evidence, 50 times
        b.fuse(make_scan([HIT_RANGE], stamp=float(i)))
        b.fuse(make_scan([PASS_RANGE], stamp=float(i)))
    after = b.raw_log_odds()
    assert after[0, CELL] == pytest.approx(l0, abs=1e-5)  # not 50 * 2 * l0 of drift
    assert np.all(after[0, 10:] == np.float32(l0))  # never observed: exactly the prior


def test_binary_policy_last_ray_wins():
    b = grid(Policy.BINARY)
    feed(b, [0.9, 0.9, 0.9, -0.4])
    assert b.raw_log_odds()[0, CELL] == -5.0
    feed(b, [-0.4] * 10 + [0.9])
    assert b.raw_log_odds()[0, CELL] == 5.0


def test_sticky_policy_never_clamps():
    b = grid(Policy.STICKY)
    L = feed(b, [0.9] * 10)
    assert L[-1] == pytest.approx(9.0, abs=1e-5)
