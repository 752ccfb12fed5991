"""Unsafe plans: the cells a plan's legs cross that are lethal or inscribed in ground
truth (``planner.plan_safety``), on hand-made grids of 1 m cells."""

import numpy as np

from mapserver.core.costvalues import INSCRIBED, LETHAL
from mapserver.core.geometry import GridGeometry
from planner.plan_safety import PlanSafety, leg_cells, plan_safety

GEOMETRY = GridGeometry(10, 10, 1.0)


def test_a_leg_crosses_every_cell_it_touches_both_beside_a_corner():
    assert leg_cells(0, 0, 3, 0).tolist() == [[0, 0], [1, 0], [2, 0], [3, 0]]
    # the diagonal passes through the corners: both side cells touch it
    assert leg_cells(0, 0, 2, 2).tolist() == [
        [0, 0], [1, 0], [0, 1], [1, 1], [2, 1], [1, 2], [2, 2],
    ]  # fmt: skip


def test_a_leg_between_waypoints_through_a_lethal_cell_is_stale_free():
    """Only the waypoints are on free cells: the leg between them crosses the obstacle."""
    truth = np.zeros(GEOMETRY.shape, np.uint8)
    truth[5, 5] = LETHAL
    truth[5, 4] = truth[5, 6] = INSCRIBED
    safety = plan_safety([(1.5, 5.5), (8.5, 5.5)], truth, GEOMETRY, radius=0.3)
    assert safety == PlanSafety(lethal=((5.5, 5.5),), inscribed=((4.5, 5.5), (6.5, 5.5)))


def test_inscribed_cells_alone_are_named_and_the_start_under_the_body_is_not():
    truth = np.zeros(GEOMETRY.shape, np.uint8)
    truth[2, 1:9] = INSCRIBED  # along a rack face
    # leaving from beside the face, straight away from it: safe
    assert plan_safety([(1.5, 2.5), (1.5, 8.5)], truth, GEOMETRY, radius=0.6) == PlanSafety()
    # driving along it: every inscribed cell past the start is named, in order
    along = plan_safety([(1.5, 2.5), (4.5, 2.5)], truth, GEOMETRY, radius=0.6)
    assert along == PlanSafety((), ((2.5, 2.5), (3.5, 2.5), (4.5, 2.5)))


def test_an_empty_path_and_points_off_the_grid_are_safe():
    truth = np.full(GEOMETRY.shape, LETHAL, np.uint8)
    assert plan_safety([], truth, GEOMETRY, 0.3) == PlanSafety()
    assert plan_safety([(99.0, 0.0)], truth, GEOMETRY, 0.3) == PlanSafety()
