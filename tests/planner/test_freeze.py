"""Freeze detection and classification exactly as docs/files.md defines them."""

import numpy as np
import pytest

from mapserver.core.costvalues import LETHAL
from mapserver.core.geometry import GridGeometry
from planner.freeze import (
    Freeze,
    FreezeDetector,
    LaneBlock,
    TruthLanes,
    UnitObservation,
    classify,
    stale_free_cells,
)
from planner.grid_search import GridPlanner
from planner.lane_graph import LaneGraph


def feed(detector, states, dt=0.25, unit="u1"):
    """states: per tick (has_task, moving, reason) -> freezes ended during the feed."""
    ended = []
    for i, (task, moving, reason) in enumerate(states):
        obs = UnitObservation(
            unit, i * dt, task, moving, reason, ((1.0, 2.0),), (5.0, 5.0), (0.5, 0.5)
        )
        freeze = detector.observe(obs)
        if freeze:
            ended.append(freeze)
    return ended


def test_a_unit_blocked_with_a_task_for_a_second_is_a_freeze():
    blocked = (True, False, "no path")
    ended = feed(FreezeDetector(), [blocked] * 5 + [(True, True, None)])
    assert len(ended) == 1
    freeze = ended[0]
    assert (freeze.start, freeze.end, freeze.duration) == (0.0, 1.25, 1.25)
    assert freeze.reason == "no path" and freeze.blocking_points == [(1.0, 2.0)]


def test_shorter_stops_and_stops_without_a_task_or_a_block_reason_are_not_freezes():
    detector = FreezeDetector()
    stop = [(True, False, "no path")] * 3 + [(True, True, None)]  # still from 0 to 0.75 s
    assert feed(detector, stop) == []
    assert feed(detector, [(False, False, "no path")] * 10 + [(True, True, None)], unit="u2") == []
    assert feed(detector, [(True, False, None)] * 10 + [(True, True, None)], unit="u3") == []
    assert detector.freezes == []


def test_a_freeze_still_open_at_the_end_of_the_run_is_counted():
    detector = FreezeDetector()
    feed(detector, [(True, False, "no lane")] * 3)
    (freeze,) = detector.finish(10.0)
    assert (freeze.start, freeze.end) == (0.0, 10.0) and detector.freezes == [freeze]


def test_a_freeze_is_phantom_when_the_planner_finds_a_path_on_ground_truth():
    geometry = GridGeometry(20, 5, 0.5)
    planner = GridPlanner(geometry)
    open_floor = np.zeros(geometry.shape, np.uint8)
    walled = open_floor.copy()
    walled[:, 10] = LETHAL

    def plan(costs, start, goal):
        return planner.plan(costs, start, goal).found

    freeze = Freeze("u1", 0.0, 3.0, "no path", (0.5, 1.0), (9.0, 1.0))
    assert classify(freeze, lambda t: open_floor, plan) is True and freeze.phantom
    assert classify(freeze, lambda t: walled, plan) is False and freeze.phantom is False
    # the obstacle is removed during the freeze: phantom from then on
    assert classify(freeze, lambda t: walled if t < 2.0 else open_floor, plan) is True


def test_stale_free_plans_cross_cells_lethal_in_ground_truth():
    geometry = GridGeometry(10, 10, 1.0)
    truth = np.zeros(geometry.shape, np.uint8)
    truth[5, 5] = LETHAL
    assert stale_free_cells([(4.5, 5.5), (5.5, 5.5), (6.5, 5.5)], truth, geometry) == [(5.5, 5.5)]
    assert stale_free_cells([(0.5, 0.5), (99.0, 0.0)], truth, geometry) == []


def test_a_bad_minimum_is_refused():
    with pytest.raises(ValueError, match="min_freeze_s"):
        FreezeDetector(0.0)


# ------------------------------------------------------------------ lane freezes
LANE_GEOMETRY = GridGeometry(80, 40, 0.1)  # 8 m x 4 m
LINE = {"a": (0.55, 1.05), "b": (3.55, 1.05), "c": (6.55, 1.05)}


def lane_world():
    """A lane a - b - c along y = 1.05 m on open floor, and the same floor with a small
    box standing on the lane line between b and c (x 4.5 .. 4.7 m): the lane is truly
    blocked, yet the floor beside the box is wide open."""
    graph = LaneGraph(LINE, [("a", "b"), ("b", "c")])
    open_floor = np.zeros(LANE_GEOMETRY.shape, np.uint8)
    boxed = open_floor.copy()
    boxed[9:12, 45:47] = LETHAL
    return graph, open_floor, boxed


def grid_plan(costs, start, goal):
    return GridPlanner(LANE_GEOMETRY).plan(costs, start, goal).found


def test_a_lane_freeze_is_judged_by_the_lane_router_on_ground_truth_not_the_grid_planner():
    graph, open_floor, boxed = lane_world()
    lanes = TruthLanes(graph, LANE_GEOMETRY)
    block = LaneBlock(("a",), "c", (("b", "c"),), ((4.55, 1.05),))
    freeze = Freeze(
        "u1", 0.0, 3.0, "no lane to (6.55, 1.05)", LINE["a"], LINE["c"], lane_block=block
    )
    # The box truly blocks the lane: a true block, although the grid planner goes round it
    # (the old rule called this a phantom).
    assert grid_plan(boxed, LINE["a"], LINE["c"]) is True
    assert classify(freeze, lambda t: boxed, grid_plan, lane_plan=lanes) is False
    assert classify(freeze, lambda t: open_floor, grid_plan, lane_plan=lanes) is True
    # removed during the freeze: phantom from then on
    assert classify(freeze, lambda t: boxed if t < 2 else open_floor, grid_plan, lane_plan=lanes)
    assert not graph.is_blocked("b", "c") and graph.version == 0  # the live graph untouched


def test_a_lane_freeze_goal_off_the_lanes_does_not_make_it_a_true_block():
    """The router drives to the goal's node; a goal point the grid planner cannot reach
    (inside a rack beside the lane) says nothing about the lanes."""
    graph, open_floor, _ = lane_world()
    walled_goal = open_floor.copy()
    walled_goal[20:40, 60:70] = LETHAL  # the goal point (6.5, 3.0) is in here
    freeze = Freeze(
        "u1",
        0.0,
        3.0,
        "no lane to (6.50, 3.00)",
        LINE["a"],
        (6.5, 3.0),
        lane_block=LaneBlock(("a",), "c"),
    )
    assert grid_plan(walled_goal, LINE["a"], (6.5, 3.0)) is False
    assert (
        classify(
            freeze, lambda t: walled_goal, grid_plan, lane_plan=TruthLanes(graph, LANE_GEOMETRY)
        )
        is True
    )


def test_a_stranded_unit_gets_through_only_if_its_lane_is_truly_clear_ahead_of_it():
    graph, open_floor, boxed = lane_world()
    lanes = TruthLanes(graph, LANE_GEOMETRY)
    block = LaneBlock(("b", "c"), "c", (("b", "c"),))

    def stranded_at(x):
        return Freeze(
            "u1", 0.0, 2.0, "stranded on a blocked lane", (x, 1.05), LINE["c"], lane_block=block
        )

    assert classify(stranded_at(4.0), lambda t: boxed, grid_plan, lane_plan=lanes) is False
    assert classify(stranded_at(4.0), lambda t: open_floor, grid_plan, lane_plan=lanes) is True
    # past the box already: the coordinator's own rule lets it carry on
    assert classify(stranded_at(5.5), lambda t: boxed, grid_plan, lane_plan=lanes) is True


def test_a_lane_freeze_must_be_classified_with_the_lane_router():
    freeze = Freeze(
        "u1", 0.0, 2.0, "no lane", (0.5, 0.5), (5.0, 5.0), lane_block=LaneBlock(("a",), "c")
    )
    with pytest.raises(ValueError, match="lane freeze"):
        classify(freeze, lambda t: np.zeros((5, 5), np.uint8), grid_plan)


def test_a_freeze_keeps_its_first_lane_block_and_every_lane_named_during_it():
    detector = FreezeDetector()
    first = LaneBlock(("a",), "c", (("b", "c"),), ((4.5, 1.0),))
    later = LaneBlock(("a",), "c", (("b", "c"), ("a9", "c")), ((4.5, 1.0), (6.0, 1.5)))
    for i, block in enumerate([first, first, later, later, later]):
        detector.observe(
            UnitObservation(
                "u1",
                i * 0.25,
                True,
                False,
                "no lane",
                block.points,
                (6.0, 0.0),
                (0.0, 0.0),
                lane_block=block,
            )
        )
    (freeze,) = detector.finish(2.0)
    assert freeze.lane_block == first
    assert freeze.lanes == [("b", "c"), ("a9", "c")]
    assert freeze.blocking_points == [(4.5, 1.0), (6.0, 1.5)]
