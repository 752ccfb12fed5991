"""The PyBullet LiDAR against analytic geometry, and its configured flaws."""

import math

import numpy as np
import pytest

from fleet.boxworld import BoxWorld, warehouse_layout
from fleet.layout import Kind, Layout, Obstacle
from fleet.lidar import Lidar, LidarConfig
from fleet.shapes import Box, Cylinder
from fleet.world import RAY_BATCH_MAX, World
from mapserver.core.scan import Pose2D

RADIUS = 0.3  # [m] the unit's body


def world_of(*obstacles, width=20.0, height=20.0):
    return World(Layout(width, height, tuple(obstacles)))


def lidar(seed=0, **config):
    return Lidar(LidarConfig(**config), RADIUS, np.random.default_rng(seed))


def passes_near_a_corner(pose: Pose2D, angles, boxes, eps: float) -> np.ndarray:
    """Beams that pass within eps [m] of a box corner (ahead of the sensor)."""
    corners = np.concatenate(
        [boxes[:, [0, 1]], boxes[:, [0, 3]], boxes[:, [2, 1]], boxes[:, [2, 3]]]
    )
    dx, dy = corners[:, 0] - pose.x, corners[:, 1] - pose.y
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    along, across = c * dx + s * dy, np.abs(-s * dx + c * dy)
    return ((along > 0) & (across < eps)).any(axis=1)


def test_ranges_match_the_analytic_box_world_in_a_warehouse():
    warehouse = warehouse_layout(30.0, 20.0, seed=3, cross_aisle_every_m=10.0)
    sensor = lidar(beams=1440)
    angles = sensor.config.angles()
    spots = [(1.83, 4.9, 0.3), (10.4, 9.1, -2.0), (27.9, 14.2, 1.1), (16.0, 5.0, 3.0)]
    poses = [Pose2D(x, y, yaw) for x, y, yaw in spots]
    with World(Layout.from_warehouse(warehouse)) as world:
        for k, pose in enumerate(poses):
            assert warehouse.world.is_free(pose.x, pose.y, RADIUS)
            world.add_unit(f"u{k}", RADIUS, 0.4, pose)
            measured = sensor.true_ranges(world, f"u{k}")
            world.set_unit_pose(f"u{k}", Pose2D(-5.0, -5.0, 0.0))  # out of the others' way
            truth = warehouse.world.cast(pose.x, pose.y, pose.yaw + angles, 20.0)
            # Bullet counts a ray passing an edge of a triangle within ~1e-4 of the
            # triangle's size as a hit: away from box corners the ranges are exact.
            clear = ~passes_near_a_corner(pose, pose.yaw + angles, warehouse.world.boxes, 0.01)
            assert clear.mean() > 0.9
            assert np.array_equal(np.isfinite(measured[clear]), np.isfinite(truth[clear]))
            hits = clear & np.isfinite(truth)
            assert hits.sum() > 100
            np.testing.assert_allclose(measured[hits], truth[hits], atol=1e-6)


def test_ranges_match_the_analytic_distance_to_a_cylinder():
    person = Cylinder(6.0, 5.0, 0.25)
    sensor = lidar(beams=3600)
    pose = Pose2D(3.0, 4.4, 0.2)
    with world_of(Obstacle("p", Kind.PERSON, person)) as world:
        world.add_unit("u1", RADIUS, 0.4, pose)
        measured = sensor.true_ranges(world, "u1")
    angles = pose.yaw + sensor.config.angles()
    # ray p + t d meets |q - c| = r at t = b - sqrt(b^2 - |p - c|^2 + r^2), b = d . (c - p)
    cx, cy = person.x - pose.x, person.y - pose.y
    b = np.cos(angles) * cx + np.sin(angles) * cy
    disc = b * b - (cx * cx + cy * cy) + person.radius**2
    truth = np.where((disc >= 0) & (b > 0), b - np.sqrt(np.maximum(disc, 0)), np.inf)
    assert np.isfinite(truth).sum() > 50
    # The world's cylinder is a 64-gon prism inscribed in it: hit and miss agree but for
    # beams within 1 mm of tangent, and every hit lies between the polygon and the circle.
    tangent = np.abs(np.cos(angles) * cy - np.sin(angles) * cx) > person.radius - 0.001
    sure = ~tangent | (b < 0)
    assert np.array_equal(np.isfinite(measured[sure]), np.isfinite(truth[sure]))
    hit = np.isfinite(measured)
    hx = pose.x + measured[hit] * np.cos(angles[hit]) - person.x
    hy = pose.y + measured[hit] * np.sin(angles[hit]) - person.y
    reach = np.hypot(hx, hy)
    inner = person.radius * math.cos(math.pi / 64)
    assert np.all((reach >= inner - 1e-9) & (reach <= person.radius + 1e-9))
    assert np.all(measured[hit] >= truth[hit] - 1e-9)


def test_a_beam_that_hits_nothing_reads_no_return():
    box = Box(10.0, 10.0, 2.0, 2.0)
    with world_of(Obstacle("r", Kind.RACK, box)) as world:
        world.add_unit("u1", RADIUS, 0.4, Pose2D(5.0, 10.0, 0.0))
        ranges = lidar(beams=8, range_max=12.0).true_ranges(world, "u1")
    assert ranges[4] == pytest.approx(4.0)  # beam 4 of 8 points straight ahead
    assert np.all(np.isposinf(np.delete(ranges, 4)))


def test_objects_below_the_scan_plane_and_beyond_range_max_are_not_seen():
    low = Obstacle("t", Kind.TOTE, Box(7.0, 5.0, 0.6, 0.4), height=0.1)
    far = Obstacle("r", Kind.RACK, Box(5.0, 9.5, 1.0, 1.0))
    with world_of(low, far, width=10, height=10) as world:
        world.add_unit("u1", RADIUS, 0.4, Pose2D(5.0, 5.0, 0.0))
        ranges = lidar(beams=4, range_max=3.0, height=0.2).true_ranges(world, "u1")
    assert np.all(np.isposinf(ranges))


def test_a_unit_never_sees_itself_but_sees_another_unit():
    with world_of() as world:
        world.add_unit("u1", RADIUS, 0.4, Pose2D(5.0, 5.0, 0.7))
        alone = lidar(beams=720).true_ranges(world, "u1")
        assert np.all(np.isposinf(alone))
        world.add_unit("u2", 0.4, 0.4, Pose2D(8.0, 5.0, 0.0))
        ranges = lidar(beams=720).true_ranges(world, "u1")
    ahead = np.argmin(np.abs(np.angle(np.exp(1j * (0.7 + LidarConfig(beams=720).angles())))))
    assert ranges[ahead] == pytest.approx(3.0 - 0.4, abs=1e-3)


def test_more_rays_than_one_batch_are_cast_in_chunks():
    n = 2 * RAY_BATCH_MAX + 7
    angles = np.linspace(0, 2 * math.pi, n, endpoint=False)
    ends = np.stack([5 + 20 * np.cos(angles), 5 + 20 * np.sin(angles), np.full(n, 0.2)], 1)
    starts = np.tile([5.0, 5.0, 0.2], (n, 1))
    walls = BoxWorld(np.array([[0, -1, 10, 0], [0, 10, 10, 11], [-1, 0, 0, 10], [10, 0, 11, 10]]))
    obstacles = [
        Obstacle(f"w{i}", Kind.WALL, Box.from_bounds(*(b + 1))) for i, b in enumerate(walls.boxes)
    ]
    with World(Layout(12, 12, tuple(obstacles))) as world:
        fractions = world.cast_rays((starts + 1).tolist(), (ends + 1).tolist())
    truth = walls.cast(5.0, 5.0, angles, 20.0)
    corner = np.abs(np.abs(np.cos(angles)) - np.abs(np.sin(angles))) < 1e-3
    np.testing.assert_allclose((fractions * 20.0)[~corner], truth[~corner], atol=1e-6)


def test_range_noise_has_the_configured_mean_and_std():
    sensor = lidar(seed=7, beams=360, range_noise=0.03)
    true = np.full(360, 4.0)
    errors = np.concatenate([sensor.corrupt(true) - true for _ in range(100)])
    assert abs(errors.mean()) < 0.001  # 36000 samples: std of the mean 0.00016
    assert errors.std() == pytest.approx(0.03, rel=0.03)


def test_dropouts_occur_at_the_configured_rate_and_read_no_return():
    sensor = lidar(seed=8, beams=1000, dropout_prob=0.05)
    out = np.concatenate([sensor.corrupt(np.full(1000, 4.0)) for _ in range(40)])
    dropped = np.isposinf(out)
    assert dropped.mean() == pytest.approx(0.05, abs=0.005)
    assert np.all(out[~dropped] == 4.0)


def test_spurious_returns_are_rare_short_and_valid():
    sensor = lidar(seed=9, beams=1000, spurious_prob=0.01, range_min=0.1)
    true = np.where(np.arange(1000) % 2 == 0, 6.0, np.inf)
    out = np.concatenate([sensor.corrupt(true) for _ in range(40)])
    expected = np.tile(true, 40)
    fake = out != expected
    assert fake.mean() == pytest.approx(0.01, abs=0.003)
    assert np.all((out[fake] >= 0.1) & (out[fake] <= np.minimum(expected[fake], 20.0)))


def test_noise_never_turns_a_miss_into_a_return():
    sensor = lidar(seed=1, beams=100, range_noise=0.5)
    out = sensor.corrupt(np.full(100, np.inf))
    assert np.all(np.isposinf(out))


def test_flaws_draw_the_same_variates_whatever_the_scene():
    a = lidar(seed=3, range_noise=0.02, dropout_prob=0.1, spurious_prob=0.01)
    b = lidar(seed=3, range_noise=0.02, dropout_prob=0.1, spurious_prob=0.01)
    a.corrupt(np.full(360, np.inf))
    b.corrupt(np.full(360, 2.0))
    assert np.array_equal(a.corrupt(np.full(360, 5.0)), b.corrupt(np.full(360, 5.0)))


@pytest.mark.parametrize(
    ("field", "value"),
    [("beams", 0), ("fov", 7.0), ("range_min", -0.1), ("rate_hz", 0.0), ("height", -1.0),
     ("range_noise", -0.01), ("dropout_prob", 1.5), ("spurious_prob", -0.1)],
)  # fmt: skip
def test_config_errors_name_the_field_and_value(field, value):
    with pytest.raises(ValueError, match=rf"{field} must .*{value!r}"):
        LidarConfig(**{field: value})


def test_range_max_must_reach_beyond_the_body():
    with pytest.raises(ValueError, match="range_max must exceed"):
        Lidar(LidarConfig(range_min=0.0, range_max=0.2), RADIUS, np.random.default_rng(0))
