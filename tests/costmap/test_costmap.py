"""The layered costmap: combination rules, decay without timers, versions and patches."""

import math

import numpy as np
from conftest import make_scan
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core.belief import BeliefGrid, CellBox
from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams
from mapserver.core.sensor_model import DecayParams, Policy, SensorModel
from mapserver.costmap.layered import LayeredCostmap
from mapserver.costmap.layers import InflationLayer, ObstacleLayer, StaticLayer
from mapserver.store.mapfiles import RosMap

GEOMETRY = GridGeometry(40, 24, 0.1)
INFLATION = InflationParams(inflation_radius=0.35, cost_scaling_factor=10.0, inscribed_radius=0.15)
DECAY = DecayParams(half_life_occupied=2.0, half_life_free=8.0)


def static_layer(occupancy: np.ndarray) -> StaticLayer:
    return StaticLayer(RosMap(GEOMETRY, occupancy, "trinary", False, 0.65, 0.196, None))


def costmap(belief: BeliefGrid, static: StaticLayer | None = None, tile: int = 8) -> LayeredCostmap:
    layers = [ObstacleLayer(belief, tile=tile), InflationLayer(INFLATION, GEOMETRY)]
    return LayeredCostmap(GEOMETRY, ([static] if static else []) + layers, history=8)


def test_a_fresh_costmap_without_evidence_is_all_unknown():
    cm = costmap(BeliefGrid(GEOMETRY))
    assert np.all(cm.costs == UNKNOWN)


def test_scans_give_lethal_endpoints_free_passes_and_inflation_around_lethal():
    belief = BeliefGrid(GEOMETRY, policy=Policy.BINARY)
    cm = costmap(belief)
    box = belief.fuse(
        make_scan([2.0] * 50, x=0.55, y=1.25, angle_min=-0.3, angle_increment=0.012)
    ).box
    cm.update(belief.stamp, [box])
    row, col = 12, 25  # the endpoint of the beam along +x: x = 2.55
    assert cm.costs[row, col] == LETHAL
    assert cm.costs[row, col - 1] == INSCRIBED
    assert cm.costs[row, 5] == FREE
    assert cm.costs[0, 39] == UNKNOWN  # never observed, far from any lethal cell


def test_unknown_in_the_obstacle_layer_never_overwrites_known_static_cells():
    occupancy = np.zeros(GEOMETRY.shape, np.int8)  # static: all free ...
    occupancy[20, 30] = 100  # ... with one wall cell
    cm = costmap(BeliefGrid(GEOMETRY), static_layer(occupancy))
    assert cm.costs[5, 5] == FREE  # the obstacle layer knows nothing here
    assert cm.costs[20, 30] == LETHAL
    assert not np.any(cm.costs == UNKNOWN)


def test_known_obstacle_cells_overwrite_unknown_static_cells_and_lethal_wins():
    occupancy = np.full(GEOMETRY.shape, -1, np.int8)
    occupancy[12, 10] = 100
    belief = BeliefGrid(GEOMETRY, policy=Policy.BINARY)
    cm = costmap(belief, static_layer(occupancy))
    box = belief.fuse(make_scan([1.0], x=0.55, y=1.25)).box  # clears cells 5..10, hit 15
    cm.update(belief.stamp, [box])
    assert cm.costs[12, 6] == FREE  # observed free beats static unknown (0.4 m from lethal)
    assert cm.costs[12, 8] == 152  # inflated: floor(252 * exp(-10 * (0.2 - 0.15)))
    assert cm.costs[12, 7] == 56  # floor(252 * exp(-10 * (0.3 - 0.15)))
    assert cm.costs[12, 10] == LETHAL  # static lethal is never cleared by a pass


def test_occupied_evidence_fades_to_unknown_without_a_scan_and_bumps_the_version():
    belief = BeliefGrid(GEOMETRY, policy=Policy.DECAY, decay=DECAY)
    cm = costmap(belief)
    for _ in range(3):
        box = belief.fuse(make_scan([1.0], x=0.55, y=1.25, stamp=0.0)).box
        cm.update(belief.stamp, [box])
    assert cm.costs[12, 15] == LETHAL and cm.costs[12, 6] == FREE
    version = cm.version
    # Free cells: 3 * -0.405 = -1.216 rises above logit(0.25) = -1.099 after
    # 8 * log2(1.216 / 1.099) = 1.17 s; they turn unknown with no scan.
    cm.update(1.1)
    assert cm.costs[12, 6] == FREE and cm.version == version
    cm.update(1.2)
    assert cm.costs[12, 6] == UNKNOWN and cm.version == version + 1
    # Occupied: L = 3 * 0.847 = 2.54 falls below logit(0.65) = 0.619 after
    # 2 * log2(2.54 / 0.619) = 4.07 s.
    version = cm.version
    cm.update(4.0)
    assert cm.costs[12, 15] == LETHAL and cm.version == version
    cm.update(4.1)
    assert cm.costs[12, 15] == UNKNOWN
    assert cm.version == version + 1
    assert np.array_equal(cm.costs, cm.build_costs(4.1))


def test_under_dual_new_evidence_fades_on_schedule_and_structure_does_not():
    model = SensorModel(transient_half_life=2.0)  # decay's is 2 s here too (DECAY)
    belief = BeliefGrid(GEOMETRY, model, policy=Policy.DUAL, decay=DECAY)
    cm = costmap(belief)
    for k in range(10):  # a face hit by 10 scans in a row: structure at (12, 15)
        box = belief.fuse(make_scan([1.0], x=0.55, y=1.25, stamp=k / 10)).box
        cm.update(belief.stamp, [box])
    for _ in range(3):  # a person at (3, 25): 3 scans (at one stamp), a new cell
        box = belief.fuse(make_scan([2.0], x=0.55, y=0.35, stamp=1.0)).box
        cm.update(belief.stamp, [box])
    assert cm.costs[3, 25] == LETHAL and cm.costs[12, 15] == LETHAL
    # The person's cell: 3 * 0.847 = 2.54 falls below 0.619 after 4.07 s (2 s half life);
    cm.update(1.0 + 4.0)
    assert cm.costs[3, 25] == LETHAL
    cm.update(1.0 + 4.1)
    assert cm.costs[3, 25] == UNKNOWN
    assert cm.costs[12, 15] == LETHAL  # structure: no fade, no schedule
    cm.update(600.0)
    assert cm.costs[12, 15] == LETHAL
    assert np.array_equal(cm.costs, cm.build_costs(600.0))


def test_patches_are_gone_once_the_history_is():
    belief = BeliefGrid(GEOMETRY, policy=Policy.BINARY)
    cm = costmap(belief)
    v0 = cm.version
    for i in range(12):
        box = belief.fuse(make_scan([1.0 + 0.1 * i], x=0.55, y=1.25, stamp=float(i))).box
        cm.update(belief.stamp, [box])
    assert cm.patches_since(cm.version) == []
    assert cm.patches_since(v0) is None  # history holds 8 versions
    assert cm.patches_since(cm.version + 1) is None
    assert cm.patches_since(cm.version - 8) is not None


scan_strategy = st.builds(
    lambda x, y, yaw, ranges, dt: (make_scan(ranges, x=x, y=y, yaw=yaw, angle_min=-1.0,
                                             angle_increment=0.1), dt),
    x=st.floats(0.0, 4.0),
    y=st.floats(0.0, 2.4),
    yaw=st.floats(-math.pi, math.pi),
    ranges=st.lists(st.one_of(st.floats(0.05, 3.0), st.just(math.inf)), min_size=1, max_size=20),
    dt=st.floats(0.0, 3.0),
)  # fmt: skip
events = st.lists(st.one_of(scan_strategy, st.floats(0.0, 6.0)), min_size=1, max_size=12)


def run_events(belief: BeliefGrid, cm: LayeredCostmap, sequence, check) -> None:
    """Feed scans (with time steps) and pure time passing; ``check`` after each event."""
    t = 0.0
    for event in sequence:
        if isinstance(event, tuple):
            scan, dt = event
            t += dt
            scan = make_scan(scan.ranges, x=scan.pose.x, y=scan.pose.y, yaw=scan.pose.yaw,
                             angle_min=scan.angle_min, angle_increment=scan.angle_increment,
                             stamp=t)  # fmt: skip
            cm.update(t, [belief.fuse(scan).box])
        else:
            t += event
            cm.update(t)
        check(t)


@settings(max_examples=60)
@given(sequence=events, policy=st.sampled_from(list(Policy)), with_static=st.booleans())
def test_the_incremental_costmap_equals_a_from_scratch_build_at_every_stamp(
    sequence, policy, with_static
):
    belief = BeliefGrid(GEOMETRY, SensorModel(), policy, DECAY)
    occupancy = np.full(GEOMETRY.shape, -1, np.int8)
    occupancy[:, :3] = 0
    occupancy[0, :] = 100
    cm = costmap(belief, static_layer(occupancy) if with_static else None)

    def check(t):
        assert np.array_equal(cm.costs, cm.build_costs(t))

    run_events(belief, cm, sequence, check)


@settings(max_examples=60)
@given(sequence=events, policy=st.sampled_from(list(Policy)))
def test_patches_applied_to_an_old_copy_reproduce_the_current_costmap(sequence, policy):
    belief = BeliefGrid(GEOMETRY, SensorModel(), policy, DECAY)
    cm = costmap(belief)
    copies = {cm.version: cm.costs.copy()}

    def check(t):
        for version, old in list(copies.items()):
            patches = cm.patches_since(version)
            if patches is None:
                assert version < cm.oldest_patch_version
                continue
            replica = old.copy()
            for patch in patches:
                patch.apply_to(replica)
            assert np.array_equal(replica, cm.costs)
        copies[cm.version] = cm.costs.copy()

    run_events(belief, cm, sequence, check)


def test_inflation_never_creates_unknown_through_the_layered_costmap():
    belief = BeliefGrid(GEOMETRY, policy=Policy.BINARY)
    cm = costmap(belief)
    box = belief.fuse(make_scan([1.0] * 30, x=2.0, y=1.2, angle_min=-0.5, angle_increment=0.03)).box
    obstacle_only = LayeredCostmap(GEOMETRY, [ObstacleLayer(belief)]).costs
    cm.update(belief.stamp, [box])
    assert np.all((cm.costs == UNKNOWN) <= (obstacle_only == UNKNOWN))


def test_region_of_changed_cells_is_reported():
    belief = BeliefGrid(GEOMETRY, policy=Policy.BINARY)
    cm = costmap(belief)
    changed = cm.update(0.0, [belief.fuse(make_scan([1.0], x=0.55, y=1.25)).box])
    # Free cells 5..14 and the endpoint 15; its neighbours are unknown, and inflation
    # (inflate_unknown false) raises unknown cells only to INSCRIBED: within 0.15 m.
    assert changed == CellBox(5, 11, 16, 13)
    assert cm.costs[11, 16] == INSCRIBED and cm.costs[10, 15] == UNKNOWN
