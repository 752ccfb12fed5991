"""Inflation: Nav2's cost formula on exact Euclidean distances, full and incremental."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from mapserver.core.belief import CellBox
from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.inflation import InflationParams, Inflator, inflation_cost, merge_inflation

RES = 0.05  # [m/cell]
DEFAULTS = InflationParams()  # 0.55 m radius, k = 10 /m, 0.3 m inscribed


def nav2_graded(distance_m: float, params: InflationParams = DEFAULTS) -> int:
    """floor(252 * exp(-k * (d - r_inscribed))), written independently of the module."""
    return math.floor(252 * math.exp(-params.cost_scaling_factor * (distance_m - 0.3)))


def single_obstacle_costs(size: int = 41) -> np.ndarray:
    lethal = np.zeros((size, size), dtype=bool)
    lethal[size // 2, size // 2] = True
    return Inflator(DEFAULTS, RES).inflate(lethal)


def reference_costs(lethal: np.ndarray, params: InflationParams, resolution: float) -> np.ndarray:
    """Brute force: scipy's exact EDT, then the formula per cell."""
    if not lethal.any():
        return np.zeros(lethal.shape, dtype=np.uint8)
    dist = ndimage.distance_transform_edt(~lethal) * resolution
    return np.vectorize(lambda d: inflation_cost(float(d), params), otypes=[np.uint8])(dist)


def distance_to_lethal(lethal: np.ndarray) -> np.ndarray:
    """[cells] distance to the nearest lethal cell (inf when there is none)."""
    if not lethal.any():
        return np.full(lethal.shape, np.inf)
    return ndimage.distance_transform_edt(~lethal)


params_strategy = st.builds(
    lambda radius, inscribed_share, k, unknown: InflationParams(
        inflation_radius=radius,
        inscribed_radius=radius * inscribed_share,
        cost_scaling_factor=k,
        inflate_unknown=unknown,
    ),
    st.floats(0.0, 0.6),
    st.floats(0.0, 1.0),
    st.floats(0.5, 30.0),
    st.booleans(),
)
resolution_strategy = st.sampled_from([0.05, 0.1, 0.025, 0.07])


@st.composite
def sparse_lethal(draw, max_side: int = 24) -> np.ndarray:
    height = draw(st.integers(1, max_side))
    width = draw(st.integers(1, max_side))
    density = draw(st.sampled_from([0.0, 0.02, 0.05, 0.15, 0.5]))
    seed = draw(st.integers(0, 2**32 - 1))
    return np.random.default_rng(seed).random((height, width)) < density


@st.composite
def boxes(draw, shape: tuple[int, int]) -> CellBox:
    height, width = shape
    c0, c1 = sorted(draw(st.lists(st.integers(0, width - 1), min_size=2, max_size=2)))
    r0, r1 = sorted(draw(st.lists(st.integers(0, height - 1), min_size=2, max_size=2)))
    return CellBox(c0, r0, c1, r1)


# ------------------------------------------------------------------ the formula
def test_cost_on_obstacle_is_lethal():
    costs = single_obstacle_costs()
    assert costs[20, 20] == LETHAL
    assert np.count_nonzero(costs == LETHAL) == 1


def test_cost_within_inscribed_radius_is_inscribed():
    costs = single_obstacle_costs()
    for dr, dc in [(0, 1), (1, 1), (0, 5), (3, 4), (0, 6), (4, 4)]:  # up to 6 cells = 0.3 m
        assert costs[20 + dr, 20 + dc] == INSCRIBED, (dr, dc)


def test_costs_at_known_distances_match_nav2_formula():
    costs = single_obstacle_costs()
    # straight offsets: 7..11 cells = 0.35..0.55 m
    for cells in range(7, 12):
        assert costs[20, 20 + cells] == nav2_graded(cells * RES), cells
        assert costs[20 - cells, 20] == nav2_graded(cells * RES), cells
    # diagonal offsets: exact Euclidean distances
    assert costs[25, 25] == nav2_graded(math.sqrt(50) * RES)  # 7.07 cells
    assert costs[20 + 6, 20 + 8] == nav2_graded(10 * RES)  # 6-8-10 triangle
    # written out for the defaults: 252 * exp(-0.5) = 152.8..., 252 * exp(-2.5) = 20.68...
    assert costs[20, 27] == 152
    assert costs[20, 31] == 20


def test_cells_beyond_inflation_radius_are_untouched():
    costs = single_obstacle_costs()
    dist = distance_to_lethal(costs == LETHAL)
    assert np.all(costs[dist > 11] == FREE)
    assert np.all(costs[dist <= 11] > FREE)
    assert costs[20, 32] == FREE  # 12 cells = 0.6 m
    assert costs[20 + 8, 20 + 8] == FREE  # 11.3 cells


def test_inflation_cost_boundaries_are_inclusive():
    assert inflation_cost(0.0, DEFAULTS) == LETHAL
    assert inflation_cost(6 * RES, DEFAULTS) == INSCRIBED  # 0.30000000000000004 m
    assert inflation_cost(11 * RES, DEFAULTS) == nav2_graded(0.55) == 20
    assert inflation_cost(0.5500001, DEFAULTS) == FREE


def test_cost_table_is_indexed_by_squared_cell_distance():
    inflator = Inflator(DEFAULTS, RES)
    assert inflator.radius_cells == 11
    table = inflator.cost_by_sq_distance
    assert len(table) == 11 * 11 + 1
    assert table[0] == LETHAL
    assert table[36] == INSCRIBED
    assert table[49] == nav2_graded(7 * RES)
    assert table[50] == nav2_graded(math.sqrt(50) * RES)
    assert np.all(np.diff(table.astype(int)) <= 0)


def test_zero_radius_inflates_nothing_but_keeps_obstacles():
    params = InflationParams(inflation_radius=0.0, inscribed_radius=0.0)
    lethal = np.zeros((5, 5), dtype=bool)
    lethal[2, 2] = True
    costs = Inflator(params, RES).inflate(lethal)
    assert costs[2, 2] == LETHAL
    assert np.count_nonzero(costs) == 1


# --------------------------------------------------------------- properties
@settings(max_examples=150, deadline=None)
@given(sparse_lethal(), params_strategy, resolution_strategy)
def test_inflation_equals_brute_force_reference(lethal, params, resolution):
    got = Inflator(params, resolution).inflate(lethal)
    np.testing.assert_array_equal(got, reference_costs(lethal, params, resolution))


@settings(max_examples=150, deadline=None)
@given(st.data(), sparse_lethal(), params_strategy)
def test_incremental_window_inflation_equals_full_inflation(data, before, params):
    inflator = Inflator(params, RES)
    costs = inflator.inflate(before)
    changed = data.draw(boxes(before.shape))
    after = before.copy()
    region = after[changed.slices]
    region[...] = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1))).random(
        region.shape
    ) < data.draw(st.sampled_from([0.0, 0.1, 0.5, 1.0]))
    inflator.inflate_window(after, costs, inflator.affected_box(changed, after.shape))
    np.testing.assert_array_equal(costs, inflator.inflate(after))


@settings(max_examples=100, deadline=None)
@given(st.data(), sparse_lethal())
def test_window_inflation_writes_only_inside_the_box(data, lethal):
    inflator = Inflator(DEFAULTS, RES)
    box = data.draw(boxes(lethal.shape))
    out = np.full(lethal.shape, 7, dtype=np.uint8)
    inflator.inflate_window(lethal, out, box)
    outside = np.ones(lethal.shape, dtype=bool)
    outside[box.slices] = False
    assert np.all(out[outside] == 7)
    np.testing.assert_array_equal(out[box.slices], inflator.inflate(lethal)[box.slices])


@st.composite
def master_grids(draw, max_side: int = 24) -> np.ndarray:
    height = draw(st.integers(1, max_side))
    width = draw(st.integers(1, max_side))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    p_lethal = draw(st.sampled_from([0.0, 0.03, 0.1, 0.3]))
    p_unknown = draw(st.sampled_from([0.0, 0.2, 0.5, 0.9]))
    u = rng.random((height, width))
    master = np.full((height, width), FREE, dtype=np.uint8)
    master[u < p_unknown] = UNKNOWN
    master[u > 1.0 - p_lethal] = LETHAL
    return master


@settings(max_examples=150, deadline=None)
@given(master_grids(), params_strategy)
def test_inflation_never_creates_unknown(master, params):
    before = master.copy()
    Inflator(params, RES).apply(master)
    assert np.all((master == UNKNOWN) <= (before == UNKNOWN))
    np.testing.assert_array_equal(master == LETHAL, before == LETHAL)


@settings(max_examples=150, deadline=None)
@given(master_grids(), params_strategy)
def test_cost_never_increases_with_distance_from_nearest_lethal_cell(master, params):
    dist = distance_to_lethal(master == LETHAL)
    Inflator(params, RES).apply(master)
    known = master != UNKNOWN
    d, cost = dist[known], master[known].astype(int)
    order = np.argsort(d, kind="stable")
    d, cost = d[order], cost[order]
    # among known cells, a farther cell never costs more than a nearer one
    assert np.all(np.maximum.accumulate(cost[::-1])[::-1] == cost)
    # and cells at equal distance cost the same
    for value in np.unique(d):
        assert len(np.unique(cost[d == value])) == 1


def test_unknown_stays_unknown_unless_inscribed_by_default():
    master = np.full((1, 15), UNKNOWN, dtype=np.uint8)
    master[0, 0] = LETHAL
    Inflator(DEFAULTS, RES).apply(master)
    assert master[0, 0] == LETHAL
    assert np.all(master[0, 1:7] == INSCRIBED)  # 1..6 cells, within 0.3 m
    assert np.all(master[0, 7:] == UNKNOWN)  # graded cost never overrides unknown


def test_inflate_unknown_lets_graded_cost_override_unknown():
    params = InflationParams(inflate_unknown=True)
    master = np.full((1, 15), UNKNOWN, dtype=np.uint8)
    master[0, 0] = LETHAL
    Inflator(params, RES).apply(master)
    assert np.all(master[0, 1:7] == INSCRIBED)
    assert master[0, 7:12].tolist() == [nav2_graded(c * RES) for c in range(7, 12)]
    assert np.all(master[0, 12:] == UNKNOWN)  # beyond the radius, nothing to inflate


def test_merge_keeps_higher_master_costs():
    master = np.array([[0, 200, 255, 254]], dtype=np.uint8)
    inflation = np.array([[100, 100, 100, 254]], dtype=np.uint8)
    assert merge_inflation(master, inflation).tolist() == [[100, 200, 255, 254]]
    assert merge_inflation(master, inflation, inflate_unknown=True).tolist() == [
        [100, 200, 100, 254]
    ]


def test_apply_is_idempotent_and_limited_to_the_box():
    master = np.zeros((30, 30), dtype=np.uint8)
    master[10, 10] = LETHAL
    inflator = Inflator(DEFAULTS, RES)
    box = CellBox(5, 5, 12, 12)
    inflator.apply(master, box)
    once = master.copy()
    inflator.apply(master, box)
    np.testing.assert_array_equal(master, once)
    assert master[10, 14] == FREE  # inside the radius but outside the box
    assert master[10, 12] == INSCRIBED


def test_affected_box_grows_by_radius_and_clips():
    inflator = Inflator(DEFAULTS, RES)
    assert inflator.affected_box(CellBox(20, 30, 25, 35), (100, 100)) == CellBox(9, 19, 36, 46)
    assert inflator.affected_box(CellBox(0, 0, 3, 3), (10, 8)) == CellBox(0, 0, 7, 9)


# --------------------------------------------------------------- validation
@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"inflation_radius": 0.2, "inscribed_radius": 0.3}, "inflation_radius"),
        ({"inscribed_radius": -0.1}, "inscribed_radius"),
        ({"cost_scaling_factor": 0.0}, "cost_scaling_factor"),
        ({"cost_scaling_factor": -1.0}, "cost_scaling_factor"),
        ({"inflation_radius": float("nan")}, "inflation_radius"),
        ({"inflation_radius": "wide"}, "inflation_radius"),
        ({"inflate_unknown": "yes"}, "inflate_unknown"),
    ],
)
def test_bad_params_name_the_field_and_value(kwargs, field):
    with pytest.raises(ValueError, match=field) as err:
        InflationParams(**kwargs)
    assert repr(next(iter(kwargs.values()))) in str(err.value)


def test_bad_resolution_and_masks_are_rejected():
    with pytest.raises(ValueError, match="resolution"):
        Inflator(DEFAULTS, 0.0)
    with pytest.raises(ValueError, match="inflation_radius"):
        Inflator(InflationParams(inflation_radius=100.0), 0.01)
    with pytest.raises(ValueError, match="lethal"):
        Inflator(DEFAULTS, RES).inflate(np.zeros((3, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="out_costs"):
        Inflator(DEFAULTS, RES).inflate_window(
            np.zeros((3, 3), dtype=bool), np.zeros((3, 4), dtype=np.uint8), CellBox(0, 0, 1, 1)
        )
