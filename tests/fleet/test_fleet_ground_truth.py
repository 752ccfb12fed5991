"""Ground truth: cell-centre rasterisation, inflated with the map server's own code."""

import math

import numpy as np
import pytest

from fleet.ground_truth import GroundTruth, rasterise
from fleet.layout import Kind, Layout, Obstacle
from fleet.shapes import Box, Cylinder
from fleet.world import World
from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams, Inflator, inflation_cost

GRID = GridGeometry(100, 80, 0.1)  # 10 m x 8 m
PARAMS = InflationParams()


@pytest.fixture
def world():
    rack = Obstacle("rack-1", Kind.RACK, Box.from_bounds(2.02, 3.0, 4.0, 3.96))
    bob = Obstacle("bob", Kind.PERSON, Cylinder(7.0, 6.0, 0.25))
    with World(Layout(10.0, 8.0, (rack, bob))) as w:
        yield w


def test_a_cell_is_occupied_when_its_centre_lies_inside_a_shape(world):
    occupied = GroundTruth(world, GRID, PARAMS).occupied()
    rows, cols = np.nonzero(occupied[:, :60])
    # centres x = 0.05 + 0.1 col in [2.02, 4.0] -> cols 20..39; y in [3.0, 3.96] -> rows 30..39
    assert (cols.min(), cols.max(), rows.min(), rows.max()) == (20, 39, 30, 39)
    assert occupied[30:40, 20:40].all() and occupied[:, :60].sum() == 20 * 10
    centres = np.stack(np.meshgrid(np.arange(60, 100) * 0.1 + 0.05, np.arange(80) * 0.1 + 0.05), -1)
    expected = np.hypot(centres[..., 0] - 7.0, centres[..., 1] - 6.0) <= 0.25
    assert np.array_equal(occupied[:, 60:], expected)


def test_the_costmap_is_the_servers_inflation_of_the_occupied_cells(world):
    truth = GroundTruth(world, GRID, PARAMS)
    occupied, costs = truth.occupied(), truth.costmap()
    expected = np.where(occupied, LETHAL, FREE).astype(np.uint8)
    Inflator(PARAMS, GRID.resolution).apply(expected)
    assert np.array_equal(costs, expected)
    assert costs.dtype == np.uint8 and set(np.unique(costs)) >= {FREE, INSCRIBED, LETHAL}
    for gap in range(1, 7):  # cells straight left of the rack's left column (col 20)
        assert costs[34, 20 - gap] == inflation_cost(gap * 0.1, PARAMS)


def test_moving_or_removing_an_object_changes_the_truth_at_that_time(world):
    truth = GroundTruth(world, GRID, PARAMS)
    before = truth.costmap()
    world.advance_to(5.0)
    world.move("bob", 5.0, 1.5)
    world.advance_to(6.0)
    world.remove("rack-1")
    points = np.array([[7.0, 6.0], [5.0, 1.5], [3.0, 3.5], [-1.0, 0.0]])
    assert truth.is_occupied(points, at=4.9).tolist() == [True, False, True, False]
    assert truth.is_occupied(points, at=5.0).tolist() == [False, True, True, False]
    assert truth.is_occupied(points).tolist() == [False, True, False, False]
    assert np.array_equal(truth.costmap(at=1.0), before)
    assert before[35, 30] == LETHAL  # a snapshot handed out earlier stays as it was


def test_incremental_updates_equal_a_full_rebuild(world):
    truth = GroundTruth(world, GRID, PARAMS)
    truth.costmap()
    rng = np.random.default_rng(4)
    for step in range(30):
        world.advance_to(float(step))
        x, y = rng.uniform(1.0, 9.0), rng.uniform(1.0, 7.0)
        action = step % 3
        if action == 0:
            world.move("bob", x, y)
        elif action == 1:
            world.add(Obstacle(f"tote-{step}", Kind.TOTE, Box(x, y, 0.6, 0.4, rng.uniform(-3, 3))))
        elif len(world.obstacles) > 2:
            world.remove(sorted(i for i in world.obstacles if i.startswith("tote"))[0])
        if step % 4 == 0:
            fresh = GroundTruth(world, GRID, PARAMS)
            assert np.array_equal(truth.costmap(), fresh.costmap())
    assert np.array_equal(truth.occupied(), rasterise(world.obstacles.values(), GRID))


def test_a_walk_through_time_gives_each_change_and_equals_a_full_rebuild(world):
    """``states(start, end)``: the truth at the start, then one state per change time
    strictly inside, each patched from the last and equal to a rebuild at that time."""
    truth = GroundTruth(world, GRID, PARAMS)
    for step in range(1, 8):  # bob walks one step a second; a tote comes and goes
        world.advance_to(float(step))
        world.move("bob", 7.0 - 0.5 * step, 6.0)
        if step == 3:
            world.add(Obstacle("tote-1", Kind.TOTE, Box(5.0, 2.0, 0.6, 0.4, 0.3)))
        if step == 5:
            world.remove("tote-1")
    steps = list(truth.states(2.5, 6.0))
    assert [s.time for s in steps] == [2.5, 3.0, 4.0, 5.0]
    assert [[(c.id, c.before is None, c.after is None) for c in s.changes] for s in steps] == [
        [], [("bob", False, False), ("tote-1", True, False)], [("bob", False, False)],
        [("bob", False, False), ("tote-1", False, True)],
    ]  # fmt: skip
    for state in steps:
        assert np.array_equal(state.costs, truth.costmap(at=state.time))
        assert np.array_equal(state.mask, rasterise(world.obstacles_at(state.time).values(), GRID))
        assert set(state.obstacles) == set(world.obstacles_at(state.time))
        assert not state.costs.flags.writeable


def test_a_rotated_box_is_rasterised_by_its_own_axes():
    box = Box(5.0, 4.0, 3.0, 0.5, yaw=math.pi / 4)
    mask = rasterise([Obstacle("p", Kind.POD, box)], GRID)
    xs, ys = np.meshgrid(np.arange(100) * 0.1 + 0.05, np.arange(80) * 0.1 + 0.05)
    assert np.array_equal(mask, box.contains(xs, ys))
    assert mask.sum() == pytest.approx(3.0 * 0.5 / 0.01, rel=0.1)
