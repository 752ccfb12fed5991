"""ALT landmark heuristic: admissible and consistent bounds, exact plans, the cache."""

import networkx as nx
import numpy as np
import pytest

from mapserver.core.costvalues import FREE, LETHAL, UNKNOWN
from mapserver.core.errors import FieldError
from mapserver.core.geometry import GridGeometry
from planner.grid_reference import networkx_grid
from planner.grid_search import GridPlanner, PlanRequestError, _heuristic
from tests.planner.test_grid_search import RES, centre, reference_cost


def graded_grid(seed: int, n: int = 40) -> np.ndarray:
    rng = np.random.default_rng(seed)
    costs = rng.choice(np.array([FREE, FREE, 3, 40, 128, 252, LETHAL, UNKNOWN], np.uint8), (n, n))
    costs[rng.random((n, n)) < 0.5] = FREE
    return costs


def bounds_to(planner: GridPlanner, costs: np.ndarray, goal: tuple[int, int]) -> dict:
    """The planner's heuristic [m] at every passable cell (row, col) towards ``goal``."""
    planner.plan(costs, centre(*goal), centre(*goal))  # builds the tables for ``costs``
    wp = planner.geometry.width + 2
    lm, margin = planner.landmarks._distances, planner.landmarks._margin
    at_goal = lm[:, (goal[0] + 1) * wp + goal[1] + 1]
    lm_goal = np.where(np.isfinite(at_goal), at_goal, -np.inf)
    rows, cols = costs.shape
    return {
        (r, c): _heuristic(
            r + 1,
            c + 1,
            (r + 1) * wp + c + 1,
            goal[0] + 1,
            goal[1] + 1,
            RES,
            1.0,
            lm,
            lm_goal,
            margin,
        )  # fmt: skip
        for r in range(rows)
        for c in range(cols)
    }


@pytest.mark.parametrize("seed", range(4))
def test_landmark_bounds_are_admissible_and_consistent(seed):
    costs = graded_grid(seed)
    goal = (30, 33)
    costs[goal] = FREE
    graph = networkx_grid(costs, RES)
    to_goal = nx.single_source_dijkstra_path_length(graph.reverse(), goal)
    h = bounds_to(GridPlanner(GridGeometry(40, 40, RES), landmarks=3), costs, goal)
    beaten = 0
    for cell, exact in to_goal.items():
        assert h[cell] <= exact + 1e-12
        beaten += h[cell] > exact * 0.999 and cell != goal
    assert beaten > 0  # the landmarks do tighten the bound somewhere
    for u, v, weight in graph.edges(data="weight"):
        if u in to_goal:
            assert h[u] <= weight + h[v] + 1e-12


@pytest.mark.parametrize("seed", range(6))
def test_astar_with_landmarks_finds_the_networkx_optimum(seed):
    costs = graded_grid(seed + 10)
    planner = GridPlanner(GridGeometry(40, 40, RES), landmarks=4)
    rng = np.random.default_rng(seed)
    for _ in range(5):
        start, goal = tuple(rng.integers(0, 40, 2)), tuple(rng.integers(0, 40, 2))
        expected = reference_cost(costs, start, goal, True)
        result = planner.plan(costs, centre(*start), centre(*goal))
        if expected is None:
            assert not result.found
        else:
            assert result.cost == pytest.approx(expected, rel=1e-9)
    assert planner.landmarks.builds == 1  # one costmap: its tables built once


def test_landmarks_cut_expansions_and_keep_the_path_cost():
    costs = np.zeros((60, 60), np.uint8)
    costs[10:50, 20] = costs[10:50, 40] = LETHAL  # two walls to go round
    plain = GridPlanner(GridGeometry(60, 60, RES)).plan(costs, centre(30, 2), centre(30, 57))
    alt = GridPlanner(GridGeometry(60, 60, RES), landmarks=4)
    result = alt.plan(costs, centre(30, 2), centre(30, 57))
    assert result.cost == pytest.approx(plain.cost, rel=1e-12)
    assert result.expanded < plain.expanded


def test_a_changed_costmap_rebuilds_the_tables():
    costs = np.zeros((20, 20), np.uint8)
    planner = GridPlanner(GridGeometry(20, 20, RES), landmarks=2)
    before = planner.plan(costs, centre(10, 1), centre(10, 18))
    planner.plan(costs.copy(), centre(10, 1), centre(10, 18))
    assert planner.landmarks.builds == 1  # same content: reused
    walled = costs.copy()
    walled[2:20, 9] = LETHAL  # a wall across the way
    after = planner.plan(walled, centre(10, 1), centre(10, 18))
    assert planner.landmarks.builds == 2
    expected = reference_cost(walled, (10, 1), (10, 18), True)
    assert after.cost == pytest.approx(expected, rel=1e-9) and after.cost > before.cost
    planner.plan(walled, centre(10, 1), centre(10, 18), allow_unknown=False)
    assert planner.landmarks.builds == 3  # other weights: other distances


def test_an_opened_wall_is_not_hidden_by_stale_tables():
    """Tables built with a wall would overestimate once it is gone: they must be rebuilt."""
    walled = np.zeros((20, 20), np.uint8)
    walled[0:18, 9] = LETHAL
    planner = GridPlanner(GridGeometry(20, 20, RES), landmarks=2)
    planner.plan(walled, centre(2, 1), centre(2, 18))
    opened = np.zeros((20, 20), np.uint8)
    result = planner.plan(opened, centre(2, 1), centre(2, 18))
    assert result.cost == pytest.approx(17 * RES)


def test_dijkstra_ignores_the_landmarks():
    costs = np.zeros((10, 10), np.uint8)
    planner = GridPlanner(GridGeometry(10, 10, RES), landmarks=2)
    result = planner.plan(costs, centre(0, 0), centre(9, 9), "dijkstra")
    assert result.found and planner.landmarks.builds == 0


def test_a_negative_landmark_count_names_the_argument():
    with pytest.raises(FieldError, match="^landmarks must be >= 0, got -1$"):
        GridPlanner(GridGeometry(4, 4, 1.0), landmarks=-1)


def below(costs: np.ndarray, seed: int) -> np.ndarray:
    """A lower bound of ``costs``: the same grid with some lethal cells freed and some
    graded costs lowered (as a static map is below the live costmap)."""
    rng = np.random.default_rng(seed)
    lower = costs.copy()
    lower[(costs == LETHAL) & (rng.random(costs.shape) < 0.5)] = FREE
    graded = costs <= 252
    lower[graded] = (costs[graded] * rng.random(costs.shape)[graded]).astype(np.uint8)
    lower[costs == UNKNOWN] = FREE
    return lower


@pytest.mark.parametrize("seed", range(4))
def test_landmarks_on_a_lower_bound_give_optimal_plans_on_every_costmap_above_it(seed):
    costs = graded_grid(seed)
    lower = below(costs, seed)
    planner = GridPlanner(GridGeometry(40, 40, RES), landmarks=4)
    rng = np.random.default_rng(100 + seed)
    free = np.argwhere(lower == FREE)
    found = 0
    for step in range(4):
        live = costs.copy()
        live[rng.random(costs.shape) < 0.05 * step] = LETHAL  # obstacles come and go above
        live = np.maximum(live, lower)  # as the live costmap keeps the static map's costs
        for _ in range(4):
            start, goal = (tuple(int(v) for v in free[rng.integers(len(free))]) for _ in "ab")
            live[start] = live[goal] = FREE
            result = planner.plan(live, centre(*start), centre(*goal), bounds=lower)
            expected = reference_cost(live, start, goal, True)
            assert result.found == (expected is not None)
            if result.found:
                found += 1
                assert result.cost == pytest.approx(expected, rel=1e-9)
    assert (planner.landmarks.builds, planner.bounded_plans) == (1, 16)
    assert found > 0


def test_tables_on_bounds_survive_changes_of_the_costmap_above_them():
    costs = graded_grid(7)
    lower = below(costs, 7)
    planner = GridPlanner(GridGeometry(40, 40, RES), landmarks=3)
    live = np.maximum(costs, lower)
    lower[0, 0] = lower[39, 39] = FREE
    live[0, 0] = live[39, 39] = FREE
    planner.plan(live, centre(0, 0), centre(39, 39), bounds=lower)
    live[20, 5:15] = LETHAL  # a new obstacle in the live costmap only
    result = planner.plan(live, centre(0, 0), centre(39, 39), bounds=lower)
    assert planner.landmarks.builds == 1
    expected = reference_cost(live, (0, 0), (39, 39), True)
    assert result.found == (expected is not None)
    if expected is not None:
        assert result.cost == pytest.approx(expected, rel=1e-9)


def test_bounds_dearer_than_the_costmap_somewhere_are_not_used():
    costs = np.full((20, 20), FREE, np.uint8)
    lower = costs.copy()
    lower[10, 10] = LETHAL  # impassable in the bound, free in the costmap: not a lower bound
    planner = GridPlanner(GridGeometry(20, 20, RES), landmarks=2)
    result = planner.plan(costs, centre(0, 0), centre(19, 19), bounds=lower)
    assert (planner.landmarks.builds, planner.bounded_plans) == (0, 0)
    assert result.cost == pytest.approx(reference_cost(costs, (0, 0), (19, 19), True), rel=1e-9)
    with pytest.raises(PlanRequestError, match=r"bounds: must have shape \(20, 20\), got"):
        planner.plan(costs, centre(0, 0), centre(1, 1), bounds=lower[:5])
