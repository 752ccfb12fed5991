"""Which cells one scan touches: free before a return, the endpoint, nothing beyond."""

import math

import numpy as np
import pytest
from conftest import make_scan

from mapserver.core.belief import BeliefGrid, CellBox, CellState
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import PoseStd
from mapserver.core.sensor_model import Policy, SensorModel

M = SensorModel()


def row_grid(width=12, policy=Policy.DECAY) -> BeliefGrid:
    return BeliefGrid(GridGeometry(width, 1, 1.0), M, policy)


def test_one_beam_frees_cells_before_the_return_marks_the_endpoint_and_leaves_the_rest():
    b = row_grid()
    result = b.fuse(make_scan([5.0]))  # from x=0.5: ends at x=5.5, cell 5
    lo = b.raw_log_odds()[0]
    assert lo[:5] == pytest.approx([M.l_miss] * 5)
    assert lo[5] == pytest.approx(M.l_hit)
    assert np.all(lo[6:] == 0.0)
    states = b.states_at()[0]
    assert states[5] == CellState.OCCUPIED
    assert np.all(states[6:] == CellState.UNKNOWN)
    assert np.all(np.isnan(b.last_observed()[0, 6:]))
    assert result.cells == 6
    assert result.box == CellBox(0, 0, 5, 0)


def test_many_beams_through_one_cell_move_it_once():
    b = BeliefGrid(GridGeometry(41, 41, 0.1), M, Policy.STICKY)
    # 200 beams in a narrow fan: all cross the sensor's neighbourhood.
    b.fuse(make_scan([1.5] * 200, x=2.05, y=2.05, angle_min=-0.2, angle_increment=0.002))
    lo = b.raw_log_odds()
    assert lo[20, 20] == pytest.approx(M.l_miss)  # the sensor's own cell
    assert lo[20, 21] == pytest.approx(M.l_miss)
    touched = lo != 0.0
    values = lo[touched]
    once = np.isclose(values, M.l_miss) | np.isclose(values, M.l_hit)
    assert once.all(), values[~once]


@pytest.mark.parametrize("order", ["hit_first", "pass_first"])
def test_a_hit_beats_a_pass_in_the_same_scan(order):
    b = BeliefGrid(GridGeometry(12, 1, 1.0), M, Policy.STICKY)
    ranges = [3.0, 9.0] if order == "hit_first" else [9.0, 3.0]
    b.fuse(make_scan(ranges, angle_increment=1e-6))  # both beams along the row
    lo = b.raw_log_odds()[0]
    assert lo[3] == pytest.approx(M.l_hit)  # endpoint of one beam, crossed by the other
    assert lo[9] == pytest.approx(M.l_hit)
    assert lo[:3] == pytest.approx([M.l_miss] * 3)
    assert lo[4:9] == pytest.approx([M.l_miss] * 5)


# No-return beams as strong as returns, out to range_max (the rule before docs/no-return.md)
AS_RETURNS = SensorModel(p_miss_no_return=M.p_miss, no_return_range=None)


def test_no_return_beams_clear_to_the_clearing_range_and_mark_nothing():
    b = BeliefGrid(GridGeometry(30, 1, 1.0), AS_RETURNS)
    b.fuse(make_scan([math.inf, 25.0], range_max=10.0, angle_increment=1e-6))
    lo = b.raw_log_odds()[0]
    assert lo[:11] == pytest.approx([M.l_miss] * 11)  # out to x = 10.5: cells 0..10
    assert np.all(lo[11:] == 0.0)
    assert not np.any(lo > 0.0)


def test_the_clearing_range_can_be_capped():
    b = BeliefGrid(GridGeometry(30, 1, 1.0), AS_RETURNS, max_clearing_range=3.0)
    b.fuse(make_scan([math.inf], range_max=10.0))
    assert np.count_nonzero(b.raw_log_odds()) == 4  # cells 0..3 (to x = 3.5)


def test_invalid_ranges_change_nothing():
    b = row_grid()
    result = b.fuse(make_scan([math.nan, -1.0, 0.01, -math.inf], range_min=0.05))
    assert result.cells == 0
    assert result.box.empty
    assert np.all(b.raw_log_odds() == 0.0)
    assert np.all(np.isnan(b.last_observed()))


def test_beams_are_clipped_at_the_map_edge_without_marking_an_endpoint_off_the_map():
    b = row_grid(width=6)
    b.fuse(make_scan([8.0]))  # endpoint at x = 8.5, off the 6 m map
    lo = b.raw_log_odds()[0]
    assert lo == pytest.approx([M.l_miss] * 6)


def test_a_sensor_off_the_map_still_observes_the_cells_its_beam_crosses():
    b = row_grid(width=6)
    b.fuse(make_scan([5.0], x=-2.5))  # enters at x = 0, ends at x = 2.5 (cell 2)
    lo = b.raw_log_odds()[0]
    assert lo[:2] == pytest.approx([M.l_miss] * 2)
    assert lo[2] == pytest.approx(M.l_hit)
    assert np.all(lo[3:] == 0.0)


def test_a_scan_that_misses_the_map_entirely_changes_nothing():
    b = row_grid(width=6)
    result = b.fuse(make_scan([5.0], x=-2.5, yaw=math.pi))
    assert result.cells == 0 and result.box.empty
    assert np.all(b.raw_log_odds() == 0.0)


def test_pose_uncertainty_weakens_the_update_by_the_documented_rule():
    b = BeliefGrid(GridGeometry(12, 1, 1.0), M, Policy.STICKY)
    # xy std of one cell: w = res^2 / (res^2 + var_xy + d^2 var_yaw) = 1 / (1 + 1 + d^2 / 100)
    b.fuse(make_scan([5.0], pose_std=PoseStd(xy=1.0, yaw=0.1)))
    lo = b.raw_log_odds()[0]
    for col in range(6):
        d = float(col)  # cell centre col + 0.5 minus sensor x 0.5
        w = 1.0 / (2.0 + d * d * 0.01)
        expected = (M.l_hit if col == 5 else M.l_miss) * w
        assert lo[col] == pytest.approx(expected, rel=1e-6)


def test_poorly_localised_scans_move_beliefs_less():
    good = BeliefGrid(GridGeometry(12, 1, 1.0), M)
    poor = BeliefGrid(GridGeometry(12, 1, 1.0), M)
    good.fuse(make_scan([5.0], pose_std=PoseStd(xy=0.0, yaw=0.0)))
    poor.fuse(make_scan([5.0], pose_std=PoseStd(xy=0.5, yaw=0.02)))
    assert np.all(np.abs(poor.raw_log_odds()) <= np.abs(good.raw_log_odds()))
    assert abs(poor.raw_log_odds()[0, 5]) < abs(good.raw_log_odds()[0, 5])


def test_binary_policy_ignores_pose_uncertainty_as_nav2_does():
    b = BeliefGrid(GridGeometry(12, 1, 1.0), M, Policy.BINARY)
    b.fuse(make_scan([5.0], pose_std=PoseStd(xy=1.0, yaw=0.1)))
    lo = b.raw_log_odds()[0]
    assert lo[:6].tolist() == [-5.0] * 5 + [5.0]


def test_last_observed_is_the_latest_stamp_even_when_scans_arrive_out_of_order():
    b = row_grid()
    b.fuse(make_scan([5.0], stamp=10.0, unit_id="a"))
    b.fuse(make_scan([5.0], stamp=9.5, unit_id="b"))
    assert np.all(b.last_observed()[0, :6] == 10.0)
    assert b.stamp == 10.0
