"""Cell and segment queries on hand-made costmaps."""

import numpy as np
import pytest
from conftest import make_scan

from mapserver.core.belief import BeliefGrid
from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.queries import query_cells, query_segments
from mapserver.core.sensor_model import SensorModel

GEOMETRY = GridGeometry(20, 10, 1.0)


def costs_with(**cells) -> np.ndarray:
    costs = np.full(GEOMETRY.shape, FREE, dtype=np.uint8)
    for name, (col, row) in cells.items():
        costs[row, col] = {"lethal": LETHAL, "inscribed": INSCRIBED, "unknown": UNKNOWN}[
            name.rstrip("0123456789")
        ]
    return costs


def test_segment_reports_the_first_blocked_cell_from_its_start_and_the_max_cost():
    costs = costs_with(inscribed=(12, 5), lethal=(15, 5), unknown1=(3, 5))
    (forward,) = query_segments(GEOMETRY, costs, [[0.5, 5.5, 19.5, 5.5]])
    (backward,) = query_segments(GEOMETRY, costs, [[19.5, 5.5, 0.5, 5.5]])
    assert forward.blocked and forward.first_blocked == (12.5, 5.5)
    assert backward.first_blocked == (15.5, 5.5)
    assert forward.max_cost == LETHAL
    assert forward.unknown_fraction == pytest.approx(1 / 20)


def test_cells_off_the_map_count_as_unknown_and_huge_segments_are_answered():
    costs = costs_with()
    half_off, huge, outside = query_segments(
        GEOMETRY, costs, [[10.5, 2.5, 29.5, 2.5], [-1e300, 2.5, 1e300, 2.5], [-9, -9, -5, -5]]
    )
    assert half_off.unknown_fraction == pytest.approx(0.5) and not half_off.blocked
    assert half_off.max_cost == FREE
    assert huge.unknown_fraction == 1.0 and huge.max_cost == FREE
    assert outside.unknown_fraction == 1.0 and outside.max_cost is None


def test_cells_report_state_probability_cost_and_age_and_outside_points():
    belief = BeliefGrid(GEOMETRY)
    for _ in range(3):
        belief.fuse(make_scan([5.0], x=0.5, y=2.5, stamp=10.0))
    costs = costs_with(lethal=(5, 2))
    free, hit, never, off = query_cells(
        belief, costs, [[1.5, 2.5], [5.5, 2.5], [5.5, 8.5], [99.0, 0.0]], at=12.0
    )
    assert (free.state, free.cost, free.last_observed, free.age) == ("free", FREE, 10.0, 2.0)
    faded = 3 * SensorModel().l_miss * 2 ** (-2 / 120)  # three passes, 2 s of a 120 s half life
    assert free.p_occ == pytest.approx(1 / (1 + np.exp(-faded)), abs=1e-6)
    assert (hit.state, hit.cost) == ("occupied", LETHAL)
    assert (never.state, never.p_occ, never.age) == ("unknown", None, None)
    assert (off.state, off.cost, off.p_occ) == ("outside", None, None)
