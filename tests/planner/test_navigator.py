"""Unit behaviour on the way: local detours, the recovery sequence, recorded causes."""

import numpy as np
import pytest

from mapserver.core.costvalues import LETHAL
from mapserver.core.geometry import GridGeometry
from planner.grid_search import GridPlanner
from planner.navigator import RecoveryConfig, UnitNavigator

GEOMETRY = GridGeometry(60, 20, 0.1)  # a 6 m x 2 m aisle
CONFIG = RecoveryConfig(wait_s=1.0, rotate_s=2.0, max_wait_s=4.0)


def navigator(**kwargs) -> UnitNavigator:
    return UnitNavigator("u1", GEOMETRY, GridPlanner(GEOMETRY), CONFIG, **kwargs)


def test_a_unit_follows_its_route_and_is_idle_once_there():
    nav = navigator()
    free = np.zeros(GEOMETRY.shape, np.uint8)
    nav.set_route([(5.0, 1.0)], stamp=0.0)
    command = nav.step(0.0, (0.5, 1.0), free)
    assert command.kind == "follow" and command.moving
    assert command.path[-1] == pytest.approx((5.05, 1.05))
    assert nav.step(1.0, (5.0, 1.0), free).kind == "idle"


def test_a_unit_blocked_by_a_tote_detours_around_it_on_the_costmap():
    costs = np.zeros(GEOMETRY.shape, np.uint8)
    costs[6:12, 28:32] = LETHAL  # a tote in the middle of the aisle, room on both sides
    nav = navigator()
    nav.set_route([(5.5, 1.0)], stamp=0.0)
    command = nav.step(0.0, (0.5, 1.0), costs)
    assert command.kind == "follow"
    cells = {GEOMETRY.world_to_cell(x, y) for x, y in command.path}
    assert not any(costs[r, c] == LETHAL for c, r in cells)
    assert nav.last_plan.length > 5.0 + 1e-6  # longer than the straight line


def test_a_blocked_unit_waits_turns_replans_then_asks_for_another_route():
    wall = np.zeros(GEOMETRY.shape, np.uint8)
    wall[:, 30] = LETHAL  # the aisle is closed
    asked = []

    def reroute(unit_id, position):
        asked.append((unit_id, position))
        return [(0.5, 0.5)]  # back the way it came

    nav = navigator(reroute=reroute)
    nav.set_route([(5.5, 1.0)], stamp=0.0)
    kinds = [nav.step(t, (1.0, 1.0), wall).kind for t in (0.0, 0.5, 1.0, 1.5, 3.0)]
    assert kinds == ["stop", "stop", "rotate", "rotate", "stop"]
    assert [a.action for a in nav.actions] == ["route", "wait", "rotate", "replan", "reroute"]
    assert nav.actions[1].blocking == (pytest.approx((3.05, 1.05)),)
    assert "no path to (5.50, 1.00)" in nav.actions[1].cause
    assert asked == [("u1", (1.0, 1.0))]
    assert nav.route == ((0.5, 0.5),)
    assert nav.step(3.1, (1.0, 1.0), wall).kind == "follow"  # the new route is open


def test_a_phantom_that_clears_while_waiting_lets_the_unit_resume():
    wall = np.zeros(GEOMETRY.shape, np.uint8)
    wall[:, 30] = LETHAL
    nav = navigator()
    nav.set_route([(5.5, 1.0)], stamp=0.0)
    assert nav.step(0.0, (1.0, 1.0), wall).kind == "stop"
    assert nav.step(0.5, (1.0, 1.0), np.zeros_like(wall)).kind == "follow"
    assert [a.action for a in nav.actions] == ["route", "wait", "resume"]


def test_with_no_other_route_the_wait_doubles_up_to_the_cap():
    wall = np.zeros(GEOMETRY.shape, np.uint8)
    wall[:, 30] = LETHAL
    nav = navigator()
    nav.set_route([(5.5, 1.0)], stamp=0.0)
    t, rotations = 0.0, []
    while t < 30.0:
        if nav.step(t, (1.0, 1.0), wall).kind == "rotate" and (
            not rotations or t - rotations[-1] > 2.5
        ):
            rotations.append(t)
        t += 0.25
    gaps = np.diff(rotations)
    assert gaps.tolist() == [4.0, 6.0, 6.0, 6.0, 6.0]  # turn 2 s + wait 2, then 4 (cap) s


def test_bad_recovery_settings_are_refused():
    with pytest.raises(ValueError, match="wait_s"):
        RecoveryConfig(wait_s=0.0)
