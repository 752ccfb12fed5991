import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mapserver.core.geometry import GridGeometry, OutsideMapError


def test_world_to_cell_uses_outer_corner_origin_and_bottom_row_zero():
    g = GridGeometry(10, 5, 0.5, origin_x=-1.0, origin_y=2.0)
    assert g.world_to_cell(-1.0, 2.0) == (0, 0)
    assert g.world_to_cell(-0.51, 2.49) == (0, 0)
    assert g.world_to_cell(3.99, 4.49) == (9, 4)
    assert g.cell_to_world(0, 0) == (-0.75, 2.25)
    assert g.index(3, 2) == 23


def test_checked_conversion_rejects_points_off_the_map():
    g = GridGeometry(10, 5, 0.5)
    assert g.world_to_cell_checked(4.99, 2.49) == (9, 4)
    outside = [(5.0, 1.0), (-0.01, 1.0), (1.0, 2.5), (math.nan, 1.0), (math.inf, 0.0), (1e308, 0)]
    for x, y in outside:
        with pytest.raises(OutsideMapError, match="outside the map"):
            g.world_to_cell_checked(x, y)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"width": 0, "height": 1, "resolution": 1.0}, "width"),
        ({"width": 1, "height": -2, "resolution": 1.0}, "height"),
        ({"width": 1, "height": 1, "resolution": 0.0}, "resolution"),
        ({"width": 1, "height": 1, "resolution": math.nan}, "resolution"),
        ({"width": 1, "height": 1, "resolution": 1.0, "origin_x": math.inf}, "origin_x"),
    ],
)
def test_bad_geometry_is_rejected_naming_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        GridGeometry(**kwargs)


@given(
    col=st.integers(0, 99),
    row=st.integers(0, 49),
    res=st.sampled_from([0.05, 0.1, 0.25, 1.0]),
    ox=st.floats(-100, 100),
    oy=st.floats(-100, 100),
)
def test_cell_centre_maps_back_to_its_cell(col, row, res, ox, oy):
    g = GridGeometry(100, 50, res, ox, oy)
    x, y = g.cell_to_world(col, row)
    assert g.world_to_cell(x, y) == (col, row)
    cols, rows, inside = g.points_to_cells(np.array([[x, y]]))
    assert (cols[0], rows[0], inside[0]) == (col, row, True)


def test_vectorised_conversion_flags_outside_and_non_finite_points():
    g = GridGeometry(4, 4, 1.0)
    cols, rows, inside = g.points_to_cells(np.array([[0.5, 0.5], [4.0, 0.0], [np.nan, 1.0]]))
    assert inside.tolist() == [True, False, False]
    assert (cols[2], rows[2]) == (-1, -1)
