"""Cost values and their OccupancyGrid translation (Nav2 Costmap2DPublisher table)."""

import numpy as np
import pytest

from mapserver.core import costvalues as cv


def test_cost_values_are_nav2s():
    assert (cv.FREE, cv.MAX_GRADED, cv.INSCRIBED, cv.LETHAL, cv.UNKNOWN) == (0, 252, 253, 254, 255)
    for value in (cv.FREE, cv.MAX_GRADED, cv.INSCRIBED, cv.LETHAL, cv.UNKNOWN):
        assert value.dtype == np.uint8


def test_special_costs_translate_to_occupancy_special_values():
    costs = np.array([0, 253, 254, 255], dtype=np.uint8)
    assert cv.costs_to_occupancy(costs).tolist() == [0, 99, 100, -1]


def test_graded_costs_scale_to_1_to_98_with_c_integer_division():
    occ = cv.costs_to_occupancy(np.arange(1, 253, dtype=np.uint8)).astype(int)
    # 1 + (97 * (i - 1)) / 251 in C integer division, written out at a few points
    assert occ[0] == 1  # i = 1
    assert occ[2] == 1  # i = 3: 1 + 194 // 251
    assert occ[3] == 2  # i = 4: 1 + 291 // 251
    assert occ[126] == 49  # i = 127: 1 + 12222 // 251 = 1 + 48
    assert occ[250] == 97  # i = 251: 1 + 24250 // 251 = 1 + 96
    assert occ[251] == 98  # i = 252: 1 + 97
    assert np.all(np.diff(occ) >= 0)
    for i, value in enumerate(occ, start=1):
        assert value == 1 + (97 * (i - 1)) // 251


def test_translation_keeps_shape_and_returns_int8():
    costs = np.array([[0, 128], [254, 255]], dtype=np.uint8)
    occ = cv.costs_to_occupancy(costs)
    assert occ.dtype == np.int8
    assert occ.shape == (2, 2)
    assert occ.tolist() == [[0, 1 + 97 * 127 // 251], [100, -1]]


def test_translation_rejects_non_uint8_costs():
    with pytest.raises(TypeError, match="int64"):
        cv.costs_to_occupancy(np.array([0, 254]))


def test_translation_table_is_read_only():
    with pytest.raises(ValueError):
        cv.COST_TO_OCCUPANCY[0] = 5
