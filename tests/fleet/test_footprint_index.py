"""The planar footprint index and its numba caster: exact ranges from the geometry, and
the index kept in step with the PyBullet world as bodies are added, moved and removed."""

import math

import numpy as np
import pytest

from fleet.footprint_index import FootprintIndex
from fleet.layout import Kind, Layout, Obstacle
from fleet.lidar import Lidar, LidarConfig
from fleet.shapes import PRISM_SIDES, Box, Cylinder
from fleet.world import World
from mapserver.core.scan import Pose2D

Z = 0.2  # [m] the scan plane


def cast(index, x, y, angle, start=0.0, stop=50.0, z=Z):
    """(range [m], hit id) of one beam from (x, y) at map-frame ``angle`` [rad]."""
    ranges, hits = index.cast_fans(np.array([x, y, angle]), np.ones(1), np.zeros(1), z, start, stop)
    return float(ranges[0, 0]), index.object_id(int(hits[0, 0]))


def test_a_turned_box_is_met_where_the_geometry_says():
    index = FootprintIndex(20.0, 20.0)
    index.put_obstacle("pod", Box(10.0, 10.0, 2.0, 1.0, math.pi / 4), 2.0)
    # along the box's own x axis from 5 m away: its face at 1 m from the centre
    r, hit = cast(index, 10.0 - 5 / math.sqrt(2), 10.0 - 5 / math.sqrt(2), math.pi / 4)
    assert (r, hit) == (pytest.approx(4.0, abs=1e-12), "pod")
    # from inside, the beam reads where it leaves (0.5 m, along the box's y axis)
    r, hit = cast(index, 10.0, 10.0, 3 * math.pi / 4)
    assert (r, hit) == (pytest.approx(0.5, abs=1e-12), "pod")


def test_a_cylinder_is_the_inscribed_prism_bullet_builds():
    index = FootprintIndex(20.0, 20.0)
    index.put_obstacle("alice", Cylinder(10.0, 10.0, 1.0), 1.75)
    apothem = math.cos(math.pi / PRISM_SIDES)
    normal = 2.5 * 2 * math.pi / PRISM_SIDES  # the normal of side 2 (between vertices 2, 3)
    x, y = 10.0 + 5 * math.cos(normal), 10.0 + 5 * math.sin(normal)
    r, hit = cast(index, x, y, normal + math.pi)  # straight at that side's middle
    assert (r, hit) == (pytest.approx(5.0 - apothem, abs=1e-12), "alice")
    vertex = 3 * 2 * math.pi / PRISM_SIDES  # beams just either side of a vertex's tangent
    tangent = vertex + math.pi / 2
    px, py = 10.0 + math.cos(vertex) - 5 * math.cos(tangent), 10.0 + math.sin(vertex)
    py -= 5 * math.sin(tangent)
    for offset, seen in ((-1e-6, "alice"), (1e-6, None)):
        ox, oy = px + offset * math.cos(vertex), py + offset * math.sin(vertex)
        assert cast(index, ox, oy, tangent)[1] == seen


def test_heights_the_range_window_and_bodies_off_the_grid():
    index = FootprintIndex(20.0, 20.0)
    index.put_obstacle("tote", Box(5.0, 10.0, 0.6, 0.4), 0.1)  # below the scan plane
    index.put_obstacle("wall", Box(15.0, 10.0, 0.2, 19.0), 3.0)
    assert cast(index, 1.0, 10.0, 0.0) == (pytest.approx(13.9, abs=1e-12), "wall")
    assert cast(index, 1.0, 10.0, 0.0, z=0.05) == (pytest.approx(3.7, abs=1e-12), "tote")
    assert cast(index, 1.0, 10.0, 0.0, stop=13.9) == (math.inf, None)  # at the end: none
    assert cast(index, 1.0, 10.0, 0.0, start=14.0)[1] == "wall"  # starts inside: its exit
    index.put_unit("u9", 0.3, 0.005, 0.405)
    index.move_unit("u9", -30.0, 10.0, 0.0)  # far off the floor, outside the grid
    assert cast(index, 1.0, 10.0, math.pi) == (pytest.approx(30.7, abs=1e-12), "u9")
    with pytest.raises(KeyError, match="no body 'ghost'"):
        index.move_unit("ghost", 1.0, 1.0, 0.0)  # a unit is put before it is moved


def test_a_long_wall_across_many_cells_is_met_in_each():
    index = FootprintIndex(100.0, 10.0, cell=1.0)
    index.put_obstacle("wall", Box(50.0, 9.0, 96.0, 0.2), 3.0)
    for x in np.linspace(3.0, 97.0, 23):
        assert cast(index, x, 1.0, math.pi / 2) == (pytest.approx(7.9, abs=1e-12), "wall")


def test_the_index_follows_the_world_as_bodies_come_move_and_go():
    layout = Layout(20.0, 20.0, (Obstacle("pod", Kind.POD, Box(10.0, 5.0, 1.0, 1.0)),))
    sensors = {
        name: Lidar(LidarConfig(beams=720), 0.3, np.random.default_rng(0), name)
        for name in ("bullet", "grid")
    }

    def agree(world):
        bullet, grid = (sensors[n].true_ranges(world, "u1") for n in ("bullet", "grid"))
        assert np.array_equal(np.isfinite(bullet), np.isfinite(grid))
        assert np.isfinite(grid).sum() > 10
        np.testing.assert_allclose(bullet[np.isfinite(bullet)], grid[np.isfinite(grid)], atol=1e-3)
        return grid

    with World(layout) as world:
        world.add_unit("u1", 0.3, 0.4, Pose2D(4.0, 5.0, 0.1))
        world.add_unit("u2", 0.3, 0.4, Pose2D(4.0, 9.0, 0.0))
        first = agree(world)  # the index is made here
        world.add(Obstacle("alice", Kind.PERSON, Cylinder(6.0, 3.0, 0.25)))
        world.move("pod", 12.0, 14.0, 0.7)
        world.set_unit_pose("u2", Pose2D(7.0, 7.0, 1.0))
        world.set_unit_pose("u1", Pose2D(4.5, 5.5, -0.4))
        assert not np.array_equal(agree(world), first)
        world.remove("alice")
        world.reset()  # the layout again
        world.set_unit_pose("u1", Pose2D(4.0, 5.0, 0.1))
        world.set_unit_pose("u2", Pose2D(4.0, 9.0, 0.0))
        np.testing.assert_array_equal(agree(world), first)
