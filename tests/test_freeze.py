"""Freeze detection and classification exactly as CONTRACT section 3 defines them."""

import numpy as np
import pytest

from mapserver.costvalues import LETHAL
from mapserver.geometry import GridGeometry
from planner.freeze import Freeze, FreezeDetector, UnitObservation, classify, stale_free_cells
from planner.grid_search import GridPlanner


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
