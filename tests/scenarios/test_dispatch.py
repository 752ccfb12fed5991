"""Dispatch: which idle unit gets a released trip."""

import pytest
from lane_helpers import grid_graph

from scenarios.run.dispatch import Dispatcher
from scenarios.spec.tasks import Task


def trip(task_id: str, release: float, pickup, unit: str | None = None) -> Task:
    return Task(task_id, pickup, (0.0, 0.0), 3.0, release, "s-1", "pick-1", unit)


def test_a_released_trip_goes_to_the_idle_unit_nearest_its_pickup():
    graph = grid_graph(4, 1)  # n0_0 - n1_0 - n2_0 - n3_0, 3 m apart
    dispatcher = Dispatcher(iter([trip("t1", 0.0, (9.0, 0.0))]), graph)
    idle = {"u1": "n0_0", "u2": "n2_0", "u3": "n1_0"}
    assert dispatcher.match(0.0, idle) == [("u2", trip("t1", 0.0, (9.0, 0.0)))]
    assert dispatcher.match(1.0, idle) == []  # handed out once


def test_first_rule_hands_trips_out_in_unit_order_and_only_once_released():
    graph = grid_graph(4, 1)
    stream = iter([trip("t1", 0.0, (9.0, 0.0)), trip("t2", 5.0, (0.0, 0.0))])
    dispatcher = Dispatcher(stream, graph, "first")
    idle = {"u10": "n3_0", "u2": "n0_0"}
    assert [(u, t.task_id) for u, t in dispatcher.match(0.0, idle)] == [("u2", "t1")]
    assert [(u, t.task_id) for u, t in dispatcher.match(5.0, idle)] == [("u2", "t2")]


def test_a_trip_meant_for_one_unit_waits_for_it():
    graph = grid_graph(4, 1)
    dispatcher = Dispatcher(iter([trip("t1", 0.0, (9.0, 0.0), unit="u1")]), graph)
    assert dispatcher.match(0.0, {"u2": "n3_0"}) == []
    assert [u for u, _ in dispatcher.match(1.0, {"u1": "n0_0", "u2": "n3_0"})] == ["u1"]


def test_an_unknown_rule_is_refused_by_name():
    with pytest.raises(ValueError, match="dispatch rule must be one of .*got 'random'"):
        Dispatcher(iter([]), grid_graph(2, 1), "random")
