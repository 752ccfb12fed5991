"""A blocking cell that is INSCRIBED names the LETHAL cells that inscribe it
(scenarios.score.inscribing), checked against the server's own inflation."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams, Inflator, merge_inflation
from scenarios.score.inscribing import inscribing_cells

GEOMETRY = GridGeometry(20, 10, 0.1)  # 2 m x 1 m
PARAMS = InflationParams()  # inscribed radius 0.3 m: 3 cells


def costmap(lethal_cells, unknown=()) -> np.ndarray:
    master = np.full(GEOMETRY.shape, FREE, dtype=np.uint8)
    for col, row in unknown:
        master[row, col] = UNKNOWN
    for col, row in lethal_cells:
        master[row, col] = LETHAL
    inflation = Inflator(PARAMS, GEOMETRY.resolution).inflate(master == LETHAL)
    return merge_inflation(master, inflation)


def centre(col: int, row: int) -> tuple[float, float]:
    return GEOMETRY.cell_to_world(col, row)


def test_an_inscribed_cell_names_the_lethal_cells_within_the_radius_nearest_first():
    costs = costmap([(10, 5), (12, 5), (16, 5)], unknown=[(9, 5)])
    assert costs[5, 9] == INSCRIBED  # unknown itself, inscribed by (10, 5)
    assert inscribing_cells(costs, GEOMETRY, centre(9, 5), 0.3) == (centre(10, 5), centre(12, 5))
    assert inscribing_cells(costs, GEOMETRY, centre(11, 5), 0.3, limit=1) == (centre(10, 5),)
    # from (13, 5): (12, 5) at 0.1 m, then (10, 5) and (16, 5) both at 0.3 m (row-major)
    expected = (centre(12, 5), centre(10, 5), centre(16, 5))
    assert inscribing_cells(costs, GEOMETRY, centre(13, 5), 0.3) == expected
    assert inscribing_cells(costs, GEOMETRY, centre(14, 5), 0.3) == (centre(12, 5), centre(16, 5))


def test_a_lethal_free_or_off_map_cell_names_none():
    costs = costmap([(10, 5)])
    assert inscribing_cells(costs, GEOMETRY, centre(10, 5), 0.3) == ()  # blocks by itself
    assert costs[5, 15] < INSCRIBED
    assert inscribing_cells(costs, GEOMETRY, centre(15, 5), 0.3) == ()
    assert inscribing_cells(costs, GEOMETRY, (-1.0, 0.5), 0.3) == ()


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 19), st.integers(0, 9)), min_size=1, max_size=8),
    st.integers(0, 19),
    st.integers(0, 9),
)
def test_every_inscribed_cell_has_a_source_within_the_radius(lethal, col, row):
    costs = costmap(lethal)
    sources = inscribing_cells(costs, GEOMETRY, centre(col, row), PARAMS.inscribed_radius)
    assert bool(sources) == (costs[row, col] == INSCRIBED)
    for x, y in sources:
        assert GEOMETRY.world_to_cell(x, y) in set(lethal)
        assert np.hypot(x - centre(col, row)[0], y - centre(col, row)[1]) <= 0.3 + 1e-9
