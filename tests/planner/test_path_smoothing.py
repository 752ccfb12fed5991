"""Line-of-sight shortcuts of a grid plan: fewer points, never less safe than the plan."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from planner.grid_search import GridPlanner
from planner.path_smoothing import smooth_path

RES = 0.1  # [m]


def touched_cells(a, b, geometry: GridGeometry, step_m: float = RES / 50) -> set:
    """Cells a segment passes through, by dense sampling (an independent check)."""
    n = max(1, math.ceil(math.dist(a, b) / step_m))
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    pts = np.asarray(a) + t * (np.asarray(b) - np.asarray(a))
    cols, rows, _ = geometry.points_to_cells(pts)
    return set(zip(rows.tolist(), cols.tolist(), strict=True))


def worst(costs: np.ndarray, cells) -> int:
    """The highest cost of ``cells``, unknown counted above every graded cost."""
    return max(int(costs[r, c]) for r, c in cells)


@st.composite
def floors(draw):
    """A 40 x 30 grid with random boxes of lethal cells ringed by inscribed and graded
    cells, some unknown patches, and a start and goal on free cells."""
    h, w = 30, 40
    costs = np.full((h, w), FREE, dtype=np.uint8)
    for _ in range(draw(st.integers(0, 8))):
        r, c = draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))
        dr, dc = draw(st.integers(1, 8)), draw(st.integers(1, 8))
        ring = draw(st.sampled_from([INSCRIBED, 200, 60]))
        costs[max(r - 1, 0) : r + dr + 1, max(c - 1, 0) : c + dc + 1] = np.maximum(
            costs[max(r - 1, 0) : r + dr + 1, max(c - 1, 0) : c + dc + 1], ring
        )
        costs[r : r + dr, c : c + dc] = draw(st.sampled_from([LETHAL, UNKNOWN]))
    free = np.argwhere(costs == FREE)
    if len(free) < 2:
        costs[0, 0] = costs[-1, -1] = FREE
        free = np.array([[0, 0], [h - 1, w - 1]])
    i, j = draw(st.integers(0, len(free) - 1)), draw(st.integers(0, len(free) - 1))
    return costs, tuple(free[i]), tuple(free[j]), draw(st.booleans())


@settings(max_examples=150, deadline=None)
@given(floors())
def test_a_smoothed_path_never_enters_an_inscribed_cell_nor_a_costlier_one(floor):
    costs, (r0, c0), (r1, c1), allow_unknown = floor
    geometry = GridGeometry(costs.shape[1], costs.shape[0], RES)
    start, goal = geometry.cell_to_world(c0, r0), geometry.cell_to_world(c1, r1)
    plan = GridPlanner(geometry).plan(costs, start, goal, "astar", allow_unknown)
    if not plan.found:
        return
    path = smooth_path(plan.path, costs, geometry)
    assert path[0] == plan.path[0] and path[-1] == plan.path[-1]
    assert all(p in plan.path for p in path)  # a subsequence of the plan's points ...
    indices = [plan.path.index(p) for p in path]
    assert indices == sorted(indices)  # ... in its order
    for k, (a, b) in enumerate(zip(path, path[1:], strict=False)):
        cells = touched_cells(a, b, geometry)
        assert all(costs[r, c] not in (INSCRIBED, LETHAL) for r, c in cells), (a, b)
        stretch = {
            geometry.world_to_cell(*p)[::-1] for p in plan.path[indices[k] : indices[k + 1] + 1]
        }
        assert worst(costs, cells) <= worst(costs, stretch), (a, b)
    length = sum(math.dist(a, b) for a, b in zip(path, path[1:], strict=False))
    assert length <= plan.length + 1e-9


def test_a_staircase_across_an_open_floor_becomes_one_straight_leg():
    geometry = GridGeometry(60, 40, RES)
    costs = np.zeros((40, 60), dtype=np.uint8)
    plan = GridPlanner(geometry).plan(costs, (0.55, 0.55), (5.55, 2.05), "astar", False)
    assert len(plan.path) > 10
    assert smooth_path(plan.path, costs, geometry) == [plan.path[0], plan.path[-1]]


def test_a_corner_around_a_wall_keeps_the_wall_out_of_every_leg():
    #   goal
    #   ####|      A wall (lethal, ringed by inscribed cells) between start and goal: the
    #       |      smoothed path goes around its end, with a bend there, not through it.
    geometry = GridGeometry(60, 40, RES)
    costs = np.zeros((40, 60), dtype=np.uint8)
    costs[19:22, 0:41] = INSCRIBED
    costs[20, 0:40] = LETHAL
    start, goal = (0.55, 0.55), (0.55, 3.55)
    plan = GridPlanner(geometry).plan(costs, start, goal, "astar", False)
    path = smooth_path(plan.path, costs, geometry)
    assert 3 <= len(path) < len(plan.path) / 5
    for a, b in zip(path, path[1:], strict=False):
        assert all(costs[r, c] < INSCRIBED for r, c in touched_cells(a, b, geometry))
