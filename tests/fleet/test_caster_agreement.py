"""The ``grid`` LiDAR caster against the reference, PyBullet's ray test, on random worlds:
the same first body (or none) and ranges within 1 mm; and both go through the same flaws.

Bullet counts a ray that passes a triangle's edge within 1e-4 of the triangle's height
over that edge as a hit (``btTriangleRaycastCallback``'s edge tolerance): a beam passing
within that distance of a body's vertical edge may hit it in Bullet and miss it in the
planar caster, or hit it a few millimetres early. Those beams (``near_a_vertex``) are left
out of the comparison, and no more: the property still fails when any other beam differs.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fleet.boxworld import warehouse_layout
from fleet.footprint_index import FootprintIndex
from fleet.layout import Kind, Layout, Obstacle
from fleet.lidar import Lidar, LidarConfig
from fleet.shapes import PRISM_SIDES, Box, Cylinder
from fleet.world import World
from mapserver.core.scan import Pose2D

FLOOR_M = 20.0
UNIT_RADIUS = 0.3
UNIT_HEIGHT = 0.4
SENSOR_Z = 0.2
EDGE_TOLERANCE = 1e-4
"""Bullet's relative edge tolerance (module docstring)."""


def vertices_and_reach(world: World, units: list[str]) -> list[tuple[np.ndarray, float]]:
    """Each body's vertical edges (k, 2) [m] and the distance [m] around them within which
    Bullet's edge tolerance may change a beam's first hit (three times the tolerance
    times the body's widest side face, plus 1 um)."""
    out = []
    for obstacle in world.obstacles.values():
        shape = obstacle.shape
        if isinstance(shape, Box):
            c, s = math.cos(shape.yaw), math.sin(shape.yaw)
            hx, hy = shape.size_x / 2, shape.size_y / 2
            corners = [(shape.x + c * u - s * v, shape.y + s * u + c * v)
                       for u, v in ((hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy))]  # fmt: skip
            out.append((np.array(corners), 3 * EDGE_TOLERANCE * max(shape.size_x, shape.size_y)))
        else:
            out.append(prism_vertices(shape.x, shape.y, 0.0, shape.radius))
    for unit_id in units:
        pose = world.unit_pose(unit_id)
        out.append(prism_vertices(pose.x, pose.y, pose.yaw, UNIT_RADIUS))
    return out


def prism_vertices(x: float, y: float, yaw: float, radius: float) -> tuple[np.ndarray, float]:
    angles = yaw + 2 * math.pi * np.arange(PRISM_SIDES) / PRISM_SIDES
    side = 2 * radius * math.sin(math.pi / PRISM_SIDES)
    xy = np.stack([x + radius * np.cos(angles), y + radius * np.sin(angles)], axis=1)
    return xy, 3 * EDGE_TOLERANCE * side + 1e-6


def near_a_vertex(
    world: World, units: list[str], pose: Pose2D, angles: np.ndarray, stop: float
) -> np.ndarray:
    """Beams from ``pose`` at ``angles`` [rad, map frame] that pass, within ``stop`` [m],
    closer to a vertical edge of an obstacle or of one of ``units`` than Bullet's edge
    tolerance reaches."""
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    near = np.zeros(angles.size, dtype=bool)
    for xy, reach in vertices_and_reach(world, units):
        dx, dy = xy[:, 0] - pose.x, xy[:, 1] - pose.y
        along, across = c * dx + s * dy, np.abs(-s * dx + c * dy)
        near |= ((along > -reach) & (along < stop + reach) & (across <= reach)).any(axis=1)
    return near


def single_body_range(world: World, body: str, pose: Pose2D, angle: float, start: float) -> float:
    """[m] where the beam at map-frame ``angle`` from ``pose`` crosses ``body`` alone."""
    index = FootprintIndex(FLOOR_M, FLOOR_M)
    if body in world.obstacles:
        obstacle = world.obstacle(body)
        index.put_obstacle(body, obstacle.shape, obstacle.height)
    else:
        other = world.unit_pose(body)
        index.put_unit(body, UNIT_RADIUS, 0.005, 0.005 + UNIT_HEIGHT)
        index.move_unit(body, other.x, other.y, other.yaw)
    ranges, _ = index.cast_fans(
        np.array([pose.x, pose.y, 0.0]), np.array([math.cos(angle)]),
        np.array([math.sin(angle)]), SENSOR_Z, start, 1e9,
    )  # fmt: skip
    return float(ranges[0, 0])


coordinate = st.floats(1.0, FLOOR_M - 1.0)
size = st.floats(0.05, 6.0)
height = st.sampled_from([0.1, 1.0, 2.5])  # 0.1: below the scan plane, never seen
boxes = st.builds(
    lambda x, y, sx, sy, yaw, h: (Box(x, y, sx, sy, yaw), h),
    coordinate, coordinate, size, size, st.floats(-math.pi, math.pi), height,
)  # fmt: skip
cylinders = st.builds(
    lambda x, y, r, h: (Cylinder(x, y, r), h), coordinate, coordinate, st.floats(0.05, 2.0), height
)
unit_poses = st.builds(
    Pose2D, st.floats(-2.0, FLOOR_M + 2.0), st.floats(-2.0, FLOOR_M + 2.0),
    st.floats(-math.pi, math.pi),
)  # fmt: skip


def apart(poses: list[Pose2D]) -> bool:
    """No two units overlap (the sim never lets them)."""
    return all(
        math.hypot(a.x - b.x, a.y - b.y) > 2 * UNIT_RADIUS for i, a in enumerate(poses)
        for b in poses[i + 1 :]
    )  # fmt: skip


def clipped(shape, h):
    """``shape`` cut to the floor when it sticks out (the layout keeps obstacles on it)."""
    xmin, ymin, xmax, ymax = shape.bounds()
    if xmin >= 0 and ymin >= 0 and xmax <= FLOOR_M and ymax <= FLOOR_M:
        return shape
    if isinstance(shape, Cylinder):
        r = min(shape.radius, shape.x, shape.y, FLOOR_M - shape.x, FLOOR_M - shape.y)
        return Cylinder(shape.x, shape.y, r)
    return Box(shape.x, shape.y, 0.05, 0.05, 0.0)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(boxes, max_size=6),
    st.lists(cylinders, max_size=4),
    st.lists(unit_poses, min_size=1, max_size=4).filter(apart),
    st.integers(8, 90),
    st.floats(1.0, 25.0),
)
def test_grid_and_bullet_see_the_same_first_body_within_a_millimetre(
    box_list, cylinder_list, poses, beams, range_max
):
    obstacles = [
        Obstacle(f"o{k}", Kind.POD, clipped(shape, h), h)
        for k, (shape, h) in enumerate(box_list + cylinder_list)
    ]
    config = LidarConfig(beams=beams, range_max=range_max, height=SENSOR_Z)
    start = UNIT_RADIUS + 0.001
    angles = config.angles()
    c, s = np.cos(angles), np.sin(angles)
    z = np.full(beams, SENSOR_Z)
    ray_from = np.stack([start * c, start * s, z], axis=1).tolist()
    ray_to = np.stack([range_max * c, range_max * s, z], axis=1).tolist()
    with World(Layout(FLOOR_M, FLOOR_M, tuple(obstacles))) as world:
        units = [f"u{k}" for k in range(len(poses))]
        for unit_id, pose in zip(units, poses, strict=True):
            world.add_unit(unit_id, UNIT_RADIUS, UNIT_HEIGHT, pose)
        for k, pose in enumerate(poses):
            fractions, bullet_ids = world.ray_hits(ray_from, ray_to, frame_unit=f"u{k}")
            bullet = start + fractions * (range_max - start)
            grid, hits = world.footprints.cast_fans(
                np.array([pose.x, pose.y, pose.yaw]), c, s, SENSOR_Z, start, range_max
            )
            grid_ids = [world.footprints.object_id(h) for h in hits[0]]
            others = units[:k] + units[k + 1 :]  # its own body is behind its beams' starts
            skip = near_a_vertex(world, others, pose, pose.yaw + angles, range_max)
            for i in np.flatnonzero(~skip):
                assert np.isfinite(bullet[i]) == np.isfinite(grid[0, i]), (i, bullet[i], grid[0, i])
                if not np.isfinite(bullet[i]):
                    continue
                assert abs(bullet[i] - grid[0, i]) <= 1e-3, (i, bullet[i], grid[0, i])
                if bullet_ids[i] != grid_ids[i]:  # a tie: both surfaces at that range
                    own = single_body_range(world, bullet_ids[i], pose, pose.yaw + angles[i], start)
                    assert abs(own - grid[0, i]) <= 1e-9, (i, bullet_ids[i], grid_ids[i])


def test_in_a_warehouse_the_casters_differ_only_on_beams_grazing_an_edge():
    """100 m x 50 m, 107 walls, racks and pallets, 24 units: one beam in a few hundred
    grazes an edge; every other beam agrees on body and range (to 1e-9 m here)."""
    warehouse = warehouse_layout()
    lanes = warehouse.lane_y
    poses = [
        Pose2D(warehouse.lane_x[0] + 7.0 * (k // len(lanes)), lanes[k % len(lanes)], 0.5 * k)
        for k in range(24)
    ]
    units = [f"u{k}" for k in range(len(poses))]
    casters = {
        name: Lidar(LidarConfig(beams=1080), UNIT_RADIUS, np.random.default_rng(0), name)
        for name in ("bullet", "grid")
    }
    with World(Layout.from_warehouse(warehouse)) as world:
        for unit_id, pose in zip(units, poses, strict=True):
            world.add_unit(unit_id, UNIT_RADIUS, UNIT_HEIGHT, pose)
        skipped = hits = 0
        for k, (unit_id, pose) in enumerate(zip(units, poses, strict=True)):
            bullet, grid = (casters[n].true_ranges(world, unit_id) for n in ("bullet", "grid"))
            angles = pose.yaw + casters["grid"].config.angles()
            skip = near_a_vertex(world, units[:k] + units[k + 1 :], pose, angles, 20.0)
            assert np.array_equal(np.isfinite(bullet[~skip]), np.isfinite(grid[~skip]))
            both = ~skip & np.isfinite(bullet)
            np.testing.assert_allclose(bullet[both], grid[both], atol=1e-9)
            skipped += skip.sum()
            hits += both.sum()
    assert hits > 10_000
    assert skipped < 0.01 * len(units) * 1080


def test_flaws_fall_on_the_same_beams_whichever_caster():
    """Same seed, same world: the same beams drop out or return spuriously, with the same
    noise, under both casters (flaws are drawn after the cast, the same way)."""
    obstacles = (
        Obstacle("pod", Kind.POD, Box(6.0, 5.0, 1.0, 1.0, 0.4)),
        Obstacle("alice", Kind.PERSON, Cylinder(3.0, 7.0, 0.25)),
    )
    config = LidarConfig(
        beams=720, range_noise=0.02, dropout_prob=0.2, spurious_prob=0.1, range_max=8.0
    )
    with World(Layout(10.0, 10.0, obstacles)) as world:
        world.add_unit("u1", UNIT_RADIUS, UNIT_HEIGHT, Pose2D(2.0, 3.0, 0.3))
        pose = world.unit_pose("u1")
        ranges = {
            name: Lidar(config, UNIT_RADIUS, np.random.default_rng(7), name).measure(world, "u1")
            for name in ("bullet", "grid")
        }
        skip = near_a_vertex(world, [], pose, pose.yaw + config.angles(), config.range_max)
    bullet, grid = ranges["bullet"][~skip], ranges["grid"][~skip]
    assert np.array_equal(np.isfinite(bullet), np.isfinite(grid))
    assert (~np.isfinite(bullet)).sum() > 100  # dropouts, and the open floor's no returns
    np.testing.assert_allclose(bullet[np.isfinite(bullet)], grid[np.isfinite(grid)], atol=1e-3)


def test_an_unknown_caster_is_refused_with_the_choices():
    expected = r"caster must be one of \['grid', 'bullet'\], got 'fast'"
    with pytest.raises(ValueError, match=expected):
        Lidar(LidarConfig(), UNIT_RADIUS, np.random.default_rng(0), "fast")
