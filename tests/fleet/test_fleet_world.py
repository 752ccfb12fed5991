"""The PyBullet world: its own client, obstacles changed at run time, contacts, history."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.layout import Kind, Layout, LayoutError, Obstacle
from fleet.lidar import Lidar, LidarConfig
from fleet.shapes import Box, Cylinder
from fleet.world import UNIT_KIND, World
from mapserver.core.scan import Pose2D

RACK = Obstacle("rack-1", Kind.RACK, Box(6.0, 5.0, 2.0, 1.0))


def scan(world: World, beams: int = 360) -> np.ndarray:
    return Lidar(LidarConfig(beams=beams), 0.3, np.random.default_rng(0)).true_ranges(world, "u1")


@pytest.fixture
def world():
    with World(Layout(10.0, 10.0, (RACK,))) as w:
        w.add_unit("u1", 0.3, 0.4, Pose2D(2.0, 5.0, 0.0))
        yield w


def test_two_worlds_are_separate_physics_clients():
    a = World(Layout(10.0, 10.0, (RACK,)))
    b = World(Layout(10.0, 10.0))
    try:
        assert a.client_id != b.client_id
        for w in (a, b):
            w.add_unit("u1", 0.3, 0.4, Pose2D(2.0, 5.0, 0.0))
        assert scan(a)[180] == pytest.approx(3.0)  # beam 180 of 360 looks ahead, +x
        assert np.isposinf(scan(b)[180])
        a.close()
        assert np.isposinf(scan(b)[180])  # closing one leaves the other working
    finally:
        a.close()
        b.close()


def test_moving_adding_and_removing_obstacles_changes_the_scans(world):
    assert scan(world)[180] == pytest.approx(3.0)
    world.advance_to(1.0)
    world.move("rack-1", 8.0, 5.0)
    assert scan(world)[180] == pytest.approx(5.0)
    world.advance_to(2.0)
    world.add(Obstacle("tote-1", Kind.TOTE, Box(4.0, 5.0, 0.4, 0.4)))
    assert scan(world)[180] == pytest.approx(1.8)
    world.advance_to(3.0)
    world.remove("tote-1")
    world.remove("rack-1")
    assert np.all(np.isposinf(scan(world)))


def test_the_change_log_gives_the_obstacles_at_any_past_time(world):
    world.advance_to(1.0)
    world.move("rack-1", 8.0, 5.0, yaw=0.5)
    world.advance_to(2.0)
    world.add(Obstacle("bob", Kind.PERSON, Cylinder(3.0, 3.0, 0.25)))
    world.advance_to(3.0)
    world.remove("rack-1")
    assert world.obstacles_at(0.5) == {"rack-1": RACK}
    assert world.obstacles_at(1.0)["rack-1"].shape == Box(8.0, 5.0, 2.0, 1.0, 0.5)
    assert sorted(world.obstacles_at(2.5)) == ["bob", "rack-1"]
    assert sorted(world.obstacles_at(3.0)) == ["bob"] == sorted(world.obstacles)
    assert [c.id for c in world.changes_since(1)] == ["bob", "rack-1"]
    assert world.revision_at(1.5) == 1 and world.revision_at(99.0) == world.revision == 3


@settings(max_examples=40, deadline=None)
@given(
    before_reset=st.lists(st.floats(0.0, 3.0), max_size=6),
    steps=st.lists(st.floats(0.0, 3.0), min_size=1, max_size=25),
    probes=st.lists(st.floats(-1.0, 80.0), min_size=1, max_size=10),
)
def test_revisions_and_changes_since_are_those_of_the_log_read_in_order(
    before_reset, steps, probes
):
    """``revision_at`` and ``changes_since`` search the log; here they are held to reading
    it change by change, on logs with several changes at one time, after a reset."""
    with World(Layout(40.0, 10.0)) as world:
        for i, dt in enumerate(before_reset):
            world.advance_to(world.time + dt)
            world.add(Obstacle(f"old-{i}", Kind.TOTE, Box(1.0 + i, 1.0, 0.4, 0.4)))
        world.reset()
        start = world.revision
        for i, dt in enumerate(steps):  # dt 0: a second change at the same time
            world.advance_to(world.time + dt)
            world.add(Obstacle(f"tote-{i}", Kind.TOTE, Box(1.0 + i, 5.0, 0.4, 0.4)))
        log = world.changes_since(start)
        assert [c.id for c in log] == [f"tote-{i}" for i in range(len(steps))]
        for time in [*probes, *(c.time for c in log)]:
            read = [c.revision for c in log if c.time <= time]
            assert world.revision_at(time) == (read[-1] if read else start)
        for revision in range(start, world.revision + 1):
            assert world.changes_since(revision) == [c for c in log if c.revision > revision]
        assert world.changes_since(start - 1) is None  # before the reset


def test_reset_restores_the_layout_and_the_clock(world):
    world.advance_to(4.0)
    world.remove("rack-1")
    before = world.revision
    world.reset()
    assert world.time == 0.0 and dict(world.obstacles) == {"rack-1": RACK}
    assert world.changes_since(before) is None
    assert scan(world)[180] == pytest.approx(3.0)


def test_contacts_with_obstacles_and_units_are_exact(world):
    world.set_unit_pose("u1", Pose2D(4.69, 5.0, 0.0))  # 1 cm short of the rack face at x = 5
    assert world.contacts("u1") == []
    world.set_unit_pose("u1", Pose2D(4.71, 5.0, 0.0))  # 1 cm into it
    assert [(c.other_id, c.other_kind) for c in world.contacts("u1")] == [("rack-1", "rack")]
    world.set_unit_pose("u1", Pose2D(6.0, 5.0, 0.0))  # deep inside: no surface touches
    assert [c.other_id for c in world.contacts("u1")] == ["rack-1"]
    world.set_unit_pose("u1", Pose2D(2.0, 2.0, 0.0))
    world.add_unit("u2", 0.25, 0.4, Pose2D(2.5, 2.0, 0.0))
    assert [(c.other_id, c.other_kind) for c in world.contacts("u1")] == [("u2", UNIT_KIND)]
    assert [c.other_id for c in world.contacts("u2")] == ["u1"]


def test_errors_name_the_object_and_the_value(world):
    with pytest.raises(KeyError, match="'nope'"):
        world.move("nope", 1.0, 1.0)
    with pytest.raises(ValueError, match="'rack-1' is already"):
        world.add(RACK)
    with pytest.raises(LayoutError, match="obstacle 'rack-1': must lie within the floor"):
        world.move("rack-1", 9.8, 5.0)
    world.advance_to(2.0)
    with pytest.raises(ValueError, match="time must not go back from 2.0 s, got 1.0"):
        world.advance_to(1.0)
    with pytest.raises(ValueError, match="ray_threads must be an integer >= 0, got -1"):
        World(Layout(1.0, 1.0), ray_threads=-1)
