"""Grid A* and Dijkstra: optimal costs (checked against networkx), safety, unknown."""

import networkx as nx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from planner.grid_reference import networkx_grid
from planner.grid_search import GridPlanner, PlanRequestError

RES = 0.5


def reference_cost(costs: np.ndarray, start, goal, allow_unknown: bool) -> float | None:
    """networkx Dijkstra on the same 8-connected weighted grid (no corner cutting)."""
    graph = networkx_grid(costs, RES, allow_unknown)
    if start not in graph or goal not in graph:
        return None
    try:
        return nx.dijkstra_path_length(graph, start, goal)
    except nx.NetworkXNoPath:
        return None


def centre(row: int, col: int) -> tuple[float, float]:
    return ((col + 0.5) * RES, (row + 0.5) * RES)


cost_values = st.sampled_from([FREE, FREE, FREE, 10, 100, 252, INSCRIBED, LETHAL, UNKNOWN])


@settings(max_examples=120)
@given(
    grid=st.integers(3, 9).flatmap(
        lambda n: st.lists(st.lists(cost_values, min_size=n, max_size=n), min_size=n, max_size=n)
    ),
    data=st.data(),
    allow_unknown=st.booleans(),
)
def test_astar_and_dijkstra_find_the_networkx_optimum(grid, data, allow_unknown):
    costs = np.array(grid, dtype=np.uint8)
    n = costs.shape[0]
    start = (data.draw(st.integers(0, n - 1)), data.draw(st.integers(0, n - 1)))
    goal = (data.draw(st.integers(0, n - 1)), data.draw(st.integers(0, n - 1)))
    planner = GridPlanner(GridGeometry(n, n, RES))
    expected = reference_cost(costs, start, goal, allow_unknown)
    for algorithm in ("astar", "dijkstra"):
        result = planner.plan(costs, centre(*start), centre(*goal), algorithm, allow_unknown)
        if expected is None:
            assert not result.found and result.path == []
            continue
        assert result.found
        assert result.cost == pytest.approx(expected, rel=1e-9)
        cells = {(int(y / RES), int(x / RES)) for x, y in result.path}
        values = {int(costs[c]) for c in cells}
        assert LETHAL not in values and INSCRIBED not in values
        assert allow_unknown or UNKNOWN not in values
        assert result.path[0] == centre(*start) and result.path[-1] == centre(*goal)


def test_unknown_is_crossed_only_when_allowed():
    costs = np.zeros((5, 9), np.uint8)
    costs[:, 4] = UNKNOWN  # a wall of unknown between the two halves
    planner = GridPlanner(GridGeometry(9, 5, RES))
    assert planner.plan(costs, centre(2, 0), centre(2, 8), allow_unknown=True).found
    blocked = planner.plan(costs, centre(2, 0), centre(2, 8), allow_unknown=False)
    assert not blocked.found and blocked.min_clearance is None


def test_an_unreachable_goal_is_reported_after_exploring_only_its_side():
    costs = np.zeros((50, 50), np.uint8)
    costs[:, 10] = LETHAL
    planner = GridPlanner(GridGeometry(50, 50, RES))
    result = planner.plan(costs, centre(25, 2), centre(25, 40))
    assert not result.found
    assert result.expanded == 50 * 10  # every cell left of the wall, none beyond


def test_length_cost_and_clearance_of_a_straight_path():
    costs = np.zeros((5, 20), np.uint8)
    costs[0, :] = LETHAL
    planner = GridPlanner(GridGeometry(20, 5, RES))
    result = planner.plan(costs, centre(3, 1), centre(3, 18))
    assert result.length == pytest.approx(17 * RES)
    assert result.cost == pytest.approx(17 * RES)  # free cells weigh 1
    assert result.min_clearance == pytest.approx(3 * RES)  # row 3 to the lethal row 0


def test_graded_costs_add_the_navfn_weight():
    costs = np.full((1, 3), 100, np.uint8)
    result = GridPlanner(GridGeometry(3, 1, 1.0)).plan(costs, (0.5, 0.5), (2.5, 0.5))
    assert result.cost == pytest.approx(2 * (50 + 0.8 * 100) / 50)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"start": (-1.0, 0.5)}, "start"),
        ({"goal": (0.5, 99.0)}, "goal"),
        ({"algorithm": "theta*"}, "algorithm"),
    ],
)
def test_bad_requests_name_the_field(kwargs, field):
    planner = GridPlanner(GridGeometry(4, 4, 1.0))
    args = {"start": (0.5, 0.5), "goal": (3.5, 3.5), **kwargs}
    with pytest.raises(PlanRequestError, match=f"^{field}: "):
        planner.plan(np.zeros((4, 4), np.uint8), **args)


def test_planning_from_an_impassable_start_finds_nothing():
    costs = np.zeros((4, 4), np.uint8)
    costs[0, 0] = LETHAL
    result = GridPlanner(GridGeometry(4, 4, 1.0)).plan(costs, (0.5, 0.5), (3.5, 3.5))
    assert not result.found and result.expanded == 0


@pytest.mark.parametrize("seed", range(6))
def test_larger_graded_grids_match_the_networkx_optimum(seed):
    """Long paths over many graded costs: nodes of one bucket reach each other, so the
    queue's reopening and its stopping rule are what keep the cost optimal."""
    rng = np.random.default_rng(seed)
    n = 48
    costs = rng.choice(np.array([FREE, FREE, 3, 40, 128, 252, LETHAL], np.uint8), (n, n))
    costs[rng.random((n, n)) < 0.5] = FREE
    start, goal = (1, 2), (n - 2, n - 3)
    costs[start] = costs[goal] = FREE
    expected = reference_cost(costs, start, goal, True)
    planner = GridPlanner(GridGeometry(n, n, RES))
    for algorithm in ("astar", "dijkstra"):
        result = planner.plan(costs, centre(*start), centre(*goal), algorithm)
        if expected is None:
            assert not result.found
        else:
            assert result.cost == pytest.approx(expected, rel=1e-9)


def test_plans_are_deterministic_and_buffers_are_reset():
    rng = np.random.default_rng(7)
    costs = rng.choice(np.array([FREE, FREE, FREE, 90, LETHAL], np.uint8), (60, 60))
    costs[2, 2] = costs[57, 57] = FREE
    planner = GridPlanner(GridGeometry(60, 60, RES))
    first = planner.plan(costs, centre(2, 2), centre(57, 57))
    planner.plan(costs, centre(57, 57), centre(2, 2), "dijkstra")  # another search between
    again = planner.plan(costs, centre(2, 2), centre(57, 57))
    fresh = GridPlanner(GridGeometry(60, 60, RES)).plan(costs, centre(2, 2), centre(57, 57))
    for other in (again, fresh):
        assert (other.path, other.cost, other.expanded) == (first.path, first.cost, first.expanded)


def test_a_search_that_runs_out_of_queue_entries_grows_them_and_finds_the_same_plan():
    """The search returns when its entry pool is full; the planner doubles the pool and
    searches again from scratch: the same path, cost and expansions as with room."""
    rng = np.random.default_rng(3)
    costs = rng.choice(np.array([FREE, FREE, 40, 252, LETHAL], np.uint8), (60, 60))
    costs[2, 2] = costs[57, 57] = FREE
    roomy = GridPlanner(GridGeometry(60, 60, RES))
    tight = GridPlanner(GridGeometry(60, 60, RES))
    tight._grow_entries(16)
    for algorithm in ("astar", "dijkstra"):
        expected = roomy.plan(costs, centre(2, 2), centre(57, 57), algorithm)
        result = tight.plan(costs, centre(2, 2), centre(57, 57), algorithm)
        assert (result.path, result.cost, result.expanded) == (
            expected.path,
            expected.cost,
            expected.expanded,
        )
    assert tight._entry_node.shape[0] > 16
    assert np.isinf(tight._g).all() and not tight._info.any()  # reset after the retries
