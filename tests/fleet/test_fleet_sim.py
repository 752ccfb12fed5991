"""The fleet simulation: seeded and repeatable, scans on schedule, collisions, noise."""

import math

import numpy as np
import pytest

from fleet.boxworld import warehouse_layout
from fleet.casters import CASTERS, BeamFan, fan_caster
from fleet.ground_truth import GroundTruth
from fleet.layout import Kind, Layout, Obstacle
from fleet.lidar import LidarConfig
from fleet.localization import PoseNoise
from fleet.shapes import Box, Cylinder
from fleet.sim import FleetSim, UnitSpec
from fleet.world import World
from mapserver.core.costvalues import FREE, LETHAL
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams
from mapserver.core.scan import Pose2D, PoseStd

WAREHOUSE = warehouse_layout(30.0, 20.0, seed=3, cross_aisle_every_m=10.0)
LAYOUT = Layout.from_warehouse(WAREHOUSE)
FLAWED = LidarConfig(beams=180, range_noise=0.02, dropout_prob=0.02, spurious_prob=0.005)
NOISY = PoseNoise(bias_x=0.02, std_xy=0.03, std_yaw=0.01)


def fleet_specs():
    x0, x1 = WAREHOUSE.lane_x[0], WAREHOUSE.lane_x[1]
    y0, y1 = WAREHOUSE.lane_y[0], WAREHOUSE.lane_y[1]
    return [
        UnitSpec("u1", Pose2D(x0, y0, 0.0), lidar=FLAWED, pose_noise=NOISY),
        UnitSpec("u2", Pose2D(x1, y1, math.pi), lidar=FLAWED, pose_noise=NOISY),
    ], [[(x1, y0), (x1, y1)], [(x0, y1), (x0, y0)]]


def run(seed: int, steps: int = 25, dt: float = 0.1):
    specs, paths = fleet_specs()
    with World(LAYOUT) as world:
        sim = FleetSim(world, specs, seed=seed)
        for spec, path in zip(specs, paths, strict=True):
            sim.unit(spec.unit_id).follow(path)
        return [sim.step(dt).scans for _ in range(steps)]


def same_scans(a, b) -> bool:
    return len(a) == len(b) and all(
        x.unit_id == y.unit_id
        and x.stamp == y.stamp
        and x.pose == y.pose
        and x.pose_std == y.pose_std
        and np.array_equal(x.ranges, y.ranges)
        for x, y in zip(a, b, strict=True)
    )


def test_two_worlds_with_one_seed_give_identical_scans_step_for_step():
    first, second = run(seed=11), run(seed=11)
    assert sum(len(s) for s in first) == 50
    assert all(same_scans(a, b) for a, b in zip(first, second, strict=True))
    other = run(seed=12)
    assert not all(same_scans(a, b) for a, b in zip(first, other, strict=True))


def test_reset_with_the_seed_replays_the_episode():
    specs, paths = fleet_specs()
    with World(LAYOUT) as world:
        sim = FleetSim(world, specs, seed=5)
        episodes = []
        for _ in range(2):
            for spec, path in zip(specs, paths, strict=True):
                sim.unit(spec.unit_id).follow(path)
            world.add(Obstacle("tote-1", Kind.TOTE, Box(5.0, 4.8, 0.6, 0.4)))
            episodes.append([sim.step(0.1).scans for _ in range(10)])
            sim.reset(seed=5)
            assert sim.time == 0.0 and "tote-1" not in world.obstacles
    assert all(same_scans(a, b) for a, b in zip(*episodes, strict=True))


def test_scans_come_at_the_lidar_rate_stamped_with_sim_time():
    slow = LidarConfig(beams=90, rate_hz=5.0)
    specs = [UnitSpec("u1", Pose2D(1.83, 4.83, 0.0), lidar=slow)]
    with World(LAYOUT) as world:
        sim = FleetSim(world, specs, seed=0)
        stamps = [s.stamp for _ in range(40) for s in sim.step(0.05).scans]
    assert stamps == pytest.approx([0.05, *np.arange(1, 11) * 0.2])  # slot 0 at the first step


def test_a_unit_driven_into_a_rack_reports_one_collision_and_halts():
    rack = LAYOUT.obstacle("rack-1")
    xmin, ymin, _, ymax = rack.shape.bounds()
    start = Pose2D(xmin - 1.5, (ymin + ymax) / 2, 0.0)
    with World(LAYOUT) as world:
        sim = FleetSim(world, [UnitSpec("u1", start)], seed=0)
        sim.unit("u1").follow([(xmin + 2.0, start.y)])
        events = [e for _ in range(40) for e in sim.step(0.1).collisions]
        assert [(e.unit_id, e.other_id, e.other_kind, e.cause) for e in events] == [
            ("u1", "rack-1", "rack", "fleet")  # it drove into the rack: the fleet's
        ]
        assert events[0].x == pytest.approx(xmin - 0.3, abs=1e-6)  # put back where it touched
        assert sim.unit("u1").idle and sim.unit("u1").pose.x == events[0].x
        assert world.unit_pose("u1").x == events[0].x
        sim.unit("u1").follow([(xmin + 2.0, start.y)])  # into it again: a new collision
        assert [e.other_id for _ in range(5) for e in sim.step(0.1).collisions] == ["rack-1"]


def test_moving_an_object_changes_the_scans_and_the_truth_at_that_time():
    specs = [UnitSpec("u1", Pose2D(1.83, 4.83, 0.0), lidar=LidarConfig(beams=360))]
    grid = GridGeometry(300, 200, 0.1)
    tote = Obstacle("tote-1", Kind.TOTE, Box(4.0, 4.83, 0.4, 0.4))
    with World(LAYOUT) as world:
        sim = FleetSim(world, specs, seed=0)
        truth = GroundTruth(world, grid, InflationParams())
        sim.schedule(0.1, lambda w: w.add(tote))
        sim.schedule(0.2, lambda w: w.move("tote-1", 4.0, 2.0))
        sim.schedule(0.3, lambda w: w.remove("tote-1"))
        ahead = [sim.step(0.1).scans[0].ranges[180] for _ in range(3)]  # beam 180: +x
        assert ahead[0] == pytest.approx(4.0 - 0.2 - 1.83)
        assert ahead[1] > 5.0 and ahead[2] == ahead[1]
        at = np.array([[4.0, 4.83], [4.0, 2.0]])
        assert truth.is_occupied(at, at=0.05).tolist() == [False, False]
        assert truth.is_occupied(at, at=0.1).tolist() == [True, False]
        assert truth.is_occupied(at, at=0.2).tolist() == [False, True]
        assert truth.is_occupied(at).tolist() == [False, False]
        assert truth.costmap(at=0.1)[48, 40] == LETHAL and truth.costmap()[48, 40] == FREE


def test_reported_poses_carry_the_configured_bias_and_noise_and_honest_std():
    noise = PoseNoise(bias_x=0.1, bias_y=-0.05, bias_yaw=0.02, std_xy=0.03, std_yaw=0.01)
    start = Pose2D(1.83, 4.83, 0.0)
    specs = [UnitSpec("u1", start, lidar=LidarConfig(beams=8), pose_noise=noise)]
    with World(LAYOUT) as world:
        sim = FleetSim(world, specs, seed=2)
        scans = [s for _ in range(400) for s in sim.step(0.1).scans]
    errors = np.array([[s.pose.x - 1.83, s.pose.y - 4.83, s.pose.yaw] for s in scans])
    assert errors.mean(axis=0) == pytest.approx([0.1, -0.05, 0.02], abs=0.005)
    assert errors.std(axis=0) == pytest.approx([0.03, 0.03, 0.01], rel=0.12)
    assert {s.pose_std for s in scans} == {PoseStd(xy=0.03, yaw=0.01)}


def test_unit_ids_must_be_unique():
    with World(LAYOUT) as world, pytest.raises(ValueError, match=r"duplicates \['u1'\]"):
        FleetSim(world, [UnitSpec("u1", Pose2D(1.83, 4.83, 0)), UnitSpec("u1", Pose2D(1.83, 9, 0))])


def test_units_driving_head_on_both_report_the_collision():
    y = WAREHOUSE.lane_y[0]
    specs = [UnitSpec("u1", Pose2D(5.0, y, 0.0)), UnitSpec("u2", Pose2D(9.0, y, math.pi))]
    with World(LAYOUT) as world:
        sim = FleetSim(world, specs, seed=0)
        sim.unit("u1").follow([(12.0, y)])
        sim.unit("u2").follow([(2.0, y)])
        events = [e for _ in range(40) for e in sim.step(0.1).collisions]
        assert sorted((e.unit_id, e.other_id, e.other_kind) for e in events) == [
            ("u1", "u2", "unit"),
            ("u2", "u1", "unit"),
        ]
        gap = world.unit_pose("u2").x - world.unit_pose("u1").x
        assert gap == pytest.approx(0.6, abs=1e-6)  # both put back to where they touched
        assert sim.unit("u1").idle and sim.unit("u2").idle


def test_a_person_walking_into_a_standing_unit_is_a_collision():
    y = WAREHOUSE.lane_y[0]
    person = Obstacle("bob", Kind.PERSON, Cylinder(6.0, y, 0.25))
    with World(LAYOUT) as world:
        sim = FleetSim(world, [UnitSpec("u1", Pose2D(5.0, y, 0.0))], seed=0)
        sim.schedule(0.2, lambda w: w.add(person))
        sim.schedule(0.4, lambda w: w.move("bob", 5.4, y))
        events = [e for _ in range(6) for e in sim.step(0.1).collisions]
        assert [(e.time, e.other_id, e.other_kind, e.cause) for e in events] == [
            (pytest.approx(0.4), "bob", "person", "scenario")
        ]
        assert world.unit_pose("u1").x == 5.0  # it stood still: nowhere to be put back to


# ------------------------------------------------------------------ collision causes
def _rack_row():
    rack = LAYOUT.obstacle("rack-1")
    xmin, ymin, _, ymax = rack.shape.bounds()
    return xmin, (ymin + ymax) / 2


def test_objects_dropped_or_moved_onto_a_standing_unit_are_the_scenarios_collisions():
    y = WAREHOUSE.lane_y[0]
    tote = Obstacle("tote-1", Kind.TOTE, Box(5.1, y, 0.6, 0.4))
    pod = Obstacle("pod-1", Kind.POD, Box(9.0, y, 1.0, 1.0))
    with World(LAYOUT) as world:
        sim = FleetSim(world, [UnitSpec("u1", Pose2D(5.0, y, 0.0))], seed=0)
        sim.schedule(0.3, lambda w: w.add(tote))  # dropped onto the unit
        sim.schedule(0.5, lambda w: w.remove("tote-1"))
        sim.schedule(0.5, lambda w: w.add(pod))  # clear of the unit: no contact
        results = [sim.step(0.1) for _ in range(8)]
        events = [e for r in results for e in r.collisions]
        # held while the tote lies on it (0.3 and 0.4 s), not after it is taken away
        held = (("u1", "tote-1"),)
        assert [r.contacts for r in results[1:5]] == [(), held, held, ()]
        world.move("pod-1", 5.4, y)  # moved onto it between steps, at run time
        events += [e for _ in range(3) for e in sim.step(0.1).collisions]
        assert world.unit_pose("u1") == Pose2D(5.0, y, 0.0)  # never moved, never put back
    assert [(e.time, e.other_id, e.other_kind, e.cause) for e in events] == [
        (pytest.approx(0.3), "tote-1", "tote", "scenario"),
        (pytest.approx(0.9), "pod-1", "pod", "scenario"),
    ]
    assert (events[0].x, events[0].y) == (5.0, y)


def test_an_object_that_appears_ahead_of_a_driving_unit_is_the_fleets_collision():
    """Placed in its way, not on it: the unit was clear of it at the step's start and
    drove into it."""
    y = WAREHOUSE.lane_y[0]
    tote = Obstacle("tote-1", Kind.TOTE, Box(6.0, y, 0.4, 0.4))
    with World(LAYOUT) as world:
        sim = FleetSim(world, [UnitSpec("u1", Pose2D(5.0, y, 0.0))], seed=0)
        sim.unit("u1").follow([(12.0, y)])
        sim.schedule(0.5, lambda w: w.add(tote))
        events = [e for _ in range(30) for e in sim.step(0.1).collisions]
        x = world.unit_pose("u1").x
    assert [(e.other_id, e.cause) for e in events] == [("tote-1", "fleet")]
    assert x == pytest.approx(6.0 - 0.2 - 0.3, abs=1e-6)  # put back where it touched


def test_unit_contacts_are_the_fleets_whether_both_or_one_moved():
    y = WAREHOUSE.lane_y[0]
    specs = [UnitSpec("u1", Pose2D(5.0, y, 0.0)), UnitSpec("u2", Pose2D(9.0, y, math.pi))]
    with World(LAYOUT) as world:  # head-on, both moving
        sim = FleetSim(world, specs, seed=0)
        sim.unit("u1").follow([(12.0, y)])
        sim.unit("u2").follow([(2.0, y)])
        head_on = [e for _ in range(40) for e in sim.step(0.1).collisions]
    with World(LAYOUT) as world:  # u1 drives into u2, which stands still
        sim = FleetSim(world, specs, seed=0)
        sim.unit("u1").follow([(12.0, y)])
        rear = [e for _ in range(60) for e in sim.step(0.1).collisions]
        assert world.unit_pose("u2").x == 9.0
    for events in (head_on, rear):
        assert sorted((e.unit_id, e.other_id, e.cause) for e in events) == [
            ("u1", "u2", "fleet"),
            ("u2", "u1", "fleet"),
        ]


def test_a_unit_put_back_from_a_rack_and_run_into_by_its_follower_reports_both():
    """The follower's step ends on the leader only once the leader is put back: still a
    collision, reported, and the follower is put back too (it never drives through)."""
    xmin, y = _rack_row()
    specs = [
        UnitSpec("a", Pose2D(xmin - 1.5, y, 0.0)),
        UnitSpec("b", Pose2D(xmin - 1.5 - 0.62, y, 0.0)),  # 2 cm behind a
    ]
    with World(LAYOUT) as world:
        sim = FleetSim(world, specs, seed=0)
        for spec in specs:
            sim.unit(spec.unit_id).follow([(xmin + 2.0, y)])
        events = [e for _ in range(40) for e in sim.step(0.1).collisions]
        gap = world.unit_pose("a").x - world.unit_pose("b").x
    assert sorted((e.unit_id, e.other_id, e.cause) for e in events) == [
        ("a", "b", "fleet"),
        ("a", "rack-1", "fleet"),
        ("b", "a", "fleet"),
    ]
    assert len({e.time for e in events}) == 1  # all in the step a touched the rack
    assert gap == pytest.approx(0.6, abs=1e-6)  # b stopped where it touched a


@pytest.mark.parametrize("caster", CASTERS)
def test_a_still_unit_among_still_things_reuses_its_last_cast_and_anything_moving_recasts(
    caster, monkeypatch
):
    specs = [
        UnitSpec("u1", Pose2D(1.83, 4.83, 0.0), lidar=LidarConfig(beams=90), caster=caster),
        UnitSpec("u2", Pose2D(8.0, 4.83, 0.0), lidar=LidarConfig(beams=90), caster=caster),
    ]
    with World(LAYOUT) as world:
        sim = FleetSim(world, specs, seed=0)
        casts = []
        kind = type(fan_caster(caster, BeamFan(np.zeros(1), 0.5, 1.0, 0.2)))
        cast = kind.cast

        def counting(self, world, unit_id):
            casts.append(unit_id)
            return cast(self, world, unit_id)

        monkeypatch.setattr(kind, "cast", counting)  # a spy on this caster's casts
        first = {s.unit_id: s for s in sim.step(0.1).scans}
        assert sorted(casts) == ["u1", "u2"]
        casts.clear()
        still = {s.unit_id: s for s in sim.step(0.1).scans}
        assert casts == []  # nothing moved: no rays cast, the same true ranges
        assert np.array_equal(still["u1"].ranges, first["u1"].ranges)
        sim.unit("u2").follow([(9.0, 4.83)])  # u2 drives: both see a changed scene
        sim.step(0.1)
        assert sorted(casts) == ["u1", "u2"]
        casts.clear()
        sim.unit("u2").halt()
        sim.step(0.1)
        casts.clear()
        world.add(Obstacle("tote-1", Kind.TOTE, Box(5.0, 4.8, 0.6, 0.4)))  # the world changes
        sim.step(0.1)
        assert sorted(casts) == ["u1", "u2"]


def scenes_unit_by_unit(sim: FleetSim, due) -> dict[str, tuple]:
    """The reference: each due unit's scene key with its own distances to every unit."""
    ids = list(sim._units)
    poses = np.array([(q.x, q.y, q.yaw) for q in map(sim.world.unit_pose, ids)])
    widest = max(u.spec.drive.radius for u in sim._units.values())
    scenes = {}
    for unit_id, unit in due:
        k = ids.index(unit_id)
        x, y, yaw = poses[k]
        near = np.hypot(poses[:, 0] - x, poses[:, 1] - y) <= unit.spec.lidar.range_max + widest
        near[k] = False
        others = np.flatnonzero(near)
        scene = (sim.world.revision, x, y, yaw, others.tobytes(), poses[others].tobytes())
        scenes[unit_id] = scene
    return scenes


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_each_units_scene_holds_the_units_within_its_lidars_reach(seed):
    rng = np.random.default_rng(seed)
    specs = [
        UnitSpec(
            f"u{i}",
            Pose2D(*rng.uniform((1.0, 1.0), (29.0, 19.0)), rng.uniform(-math.pi, math.pi)),
            lidar=LidarConfig(beams=90, range_max=float(rng.choice([2.0, 5.0, 12.0]))),
        )
        for i in range(12)
    ]
    with World(Layout(30.0, 20.0)) as world:
        sim = FleetSim(world, specs, seed=seed)
        units = list(sim._units.items())
        for due in (units, units[::3], units[5:6], []):
            assert sim._scenes(due) == scenes_unit_by_unit(sim, due)
        some = sim._scenes(units)
        assert any(len(key[4]) for key in some.values())  # some units see others
        assert any(not len(key[4]) for key in some.values())  # and some see none
