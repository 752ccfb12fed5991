"""Freeze detection and classification exactly as docs/files.md defines them."""

import math

import numpy as np
import pytest

from mapserver.core.costvalues import LETHAL
from mapserver.core.geometry import GridGeometry
from planner.freeze import (
    Freeze,
    FreezeDetector,
    LaneBlock,
    Segment,
    TruthLanes,
    TruthState,
    UnitObservation,
    classify,
    split,
)
from planner.grid_search import GridPlanner
from planner.lane_graph import LaneGraph


def timeline(*states):
    """A hand-made truth: (time [s], costs, change) from each time on, the first at 0."""

    def states_between(start, end):
        ordered = sorted(states, key=lambda s: s[0])
        first = max((s for s in ordered if s[0] <= start), key=lambda s: s[0])
        yield TruthState(start, first[1])
        for time, costs, change in ordered:
            if start < time < end:
                yield TruthState(time, costs, change)

    return states_between


def always(costs):
    return timeline((0.0, costs, ""))


def kinds(segments):
    return [(s.start, s.end, s.kind) for s in segments]


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


def test_a_freeze_is_phantom_while_the_planner_finds_a_path_on_ground_truth():
    geometry = GridGeometry(20, 5, 0.5)
    planner = GridPlanner(geometry)
    open_floor = np.zeros(geometry.shape, np.uint8)
    walled = open_floor.copy()
    walled[:, 10] = LETHAL

    def plan(costs, start, goal):
        return planner.plan(costs, start, goal).found

    freeze = Freeze("u1", 0.0, 3.0, "no path", (0.5, 1.0), (9.0, 1.0))
    assert kinds(classify(freeze, always(open_floor), plan)) == [(0.0, 3.0, "phantom")]
    assert freeze.seconds("phantom") == 3.0 and freeze.seconds("true_block") == 0.0
    assert kinds(classify(freeze, always(walled), plan)) == [(0.0, 3.0, "true_block")]
    assert freeze.segments[0].cause == "no path on ground truth"
    # the wall is removed during the freeze: true block until then, phantom from then on
    moved = timeline((0.0, walled, ""), (2.0, open_floor, "wall-1 removed"))
    assert classify(freeze, moved, plan) == [
        Segment(0.0, 2.0, "true_block", "no path on ground truth"),
        Segment(2.0, 3.0, "phantom", "ground truth has a path (wall-1 removed at 2 s)"),
    ]


def test_the_split_of_a_hand_made_timeline_is_exact():
    """A unit frozen from 35.8 s to 107.1 s: truly blocked until its pod moves at 60 s,
    then the map alone holds it; a person crossing at 80-81.5 s changes the truth twice
    without changing the verdict; a tote dropped at 100 s blocks it again."""
    verdicts = [
        (35.8, "true_block", "no lane route on ground truth"),
        (60.0, "phantom", "ground truth has a lane route (pod-9 moved at 60 s)"),
        (80.0, "phantom", "ground truth has a lane route (ann moved at 80 s)"),
        (81.5, "phantom", "ground truth has a lane route (ann removed at 81.5 s)"),
        (100.0, "true_block", "no lane route on ground truth (tote-1 added at 100 s)"),
        (107.1, "phantom", "after the end: dropped"),
    ]
    segments = split(35.8, 107.1, verdicts)
    assert segments == [
        Segment(35.8, 60.0, "true_block", "no lane route on ground truth"),
        Segment(60.0, 100.0, "phantom", "ground truth has a lane route (pod-9 moved at 60 s)"),
        Segment(100.0, 107.1, "true_block",
                "no lane route on ground truth (tote-1 added at 100 s)"),
    ]  # fmt: skip
    freeze = Freeze("u5", 35.8, 107.1, "no lane", (16.0, 16.3), (33.0, 16.3), segments=segments)
    assert math.isclose(freeze.seconds("true_block"), 24.2 + 7.1)
    assert math.isclose(freeze.seconds("phantom"), 40.0)
    assert math.isclose(freeze.seconds("phantom") + freeze.seconds("true_block"), 71.3)
    with pytest.raises(ValueError, match="at the start"):
        split(0.0, 5.0, [(1.0, "phantom", "late")])
    with pytest.raises(ValueError, match="kind"):
        split(0.0, 5.0, [(0.0, "ghost", "?")])


def test_a_goal_inside_an_obstacle_is_named_as_the_cause():
    geometry = GridGeometry(20, 5, 0.5)
    planner = GridPlanner(geometry)
    boxed = np.zeros(geometry.shape, np.uint8)
    boxed[1:4, 17:20] = LETHAL  # the goal (9.0, 1.0) is in it

    def plan(costs, start, goal):
        return planner.plan(costs, start, goal).found

    def states(start, end):
        yield TruthState(start, boxed, "", lambda x, y: "lies in tote-1" if x > 8 else None)

    freeze = Freeze("u1", 12.0, 40.0, "no path", (0.5, 1.0), (9.0, 1.0))
    (segment,) = classify(freeze, states, plan)
    assert (segment.kind, segment.cause) == ("true_block", "its goal lies in tote-1")
    lost = Freeze("u2", 1.0, 3.0, "no path", None, (9.0, 1.0))
    assert classify(lost, states, plan) == [
        Segment(1.0, 3.0, "true_block", "its position or goal is not known")
    ]


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
    assert kinds(classify(freeze, always(boxed), grid_plan, lane_plan=lanes)) == [
        (0.0, 3.0, "true_block")
    ]
    assert kinds(classify(freeze, always(open_floor), grid_plan, lane_plan=lanes)) == [
        (0.0, 3.0, "phantom")
    ]
    # removed during the freeze: phantom from then on
    removed = timeline((0.0, boxed, ""), (2.0, open_floor, "box removed"))
    assert kinds(classify(freeze, removed, grid_plan, lane_plan=lanes)) == [
        (0.0, 2.0, "true_block"),
        (2.0, 3.0, "phantom"),
    ]
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
    lanes = TruthLanes(graph, LANE_GEOMETRY)
    assert kinds(classify(freeze, always(walled_goal), grid_plan, lane_plan=lanes)) == [
        (0.0, 3.0, "phantom")
    ]


def test_a_stranded_unit_gets_through_only_if_its_lane_is_truly_clear_ahead_of_it():
    graph, open_floor, boxed = lane_world()
    lanes = TruthLanes(graph, LANE_GEOMETRY)
    block = LaneBlock(("b", "c"), "c", (("b", "c"),))

    def stranded_at(x):
        return Freeze(
            "u1", 0.0, 2.0, "stranded on a blocked lane", (x, 1.05), LINE["c"], lane_block=block
        )

    def verdict(x, truth):
        (segment,) = classify(stranded_at(x), always(truth), grid_plan, lane_plan=lanes)
        return segment.kind

    assert verdict(4.0, boxed) == "true_block" and verdict(4.0, open_floor) == "phantom"
    # past the box already: the coordinator's own rule lets it carry on
    assert verdict(5.5, boxed) == "phantom"


def test_a_lane_freeze_must_be_classified_with_the_lane_router():
    freeze = Freeze(
        "u1", 0.0, 2.0, "no lane", (0.5, 0.5), (5.0, 5.0), lane_block=LaneBlock(("a",), "c")
    )
    with pytest.raises(ValueError, match="lane freeze"):
        classify(freeze, always(np.zeros((5, 5), np.uint8)), grid_plan)


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
