"""Blocked work goes back (scenarios.run.trip_queue): a trip with no route is returned
after ``return_after``, held while its goal stays blocked, and retried; a run with a tote
on a pick spot, end to end."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from lane_helpers import grid_graph

from mapserver.core.costvalues import FREE, LETHAL
from mapserver.core.geometry import GridGeometry
from scenarios.run.dispatch import Dispatcher
from scenarios.run.runner import run
from scenarios.run.trip_queue import GOAL_BLOCKED, NO_ROUTE, ReturnWatch, TripQueue
from scenarios.score.trips_json import write_trips
from scenarios.spec.scenario import parse_scenario
from scenarios.spec.tasks import Task

TINY = Path(__file__).resolve().parents[2] / "scenarios" / "tiny.yaml"
GEOMETRY = GridGeometry(40, 10, 0.25)  # 10 m x 2.5 m: the 4 x 1 grid graph's nodes, 3 m apart


def trip(task_id: str, pickup=(9.0, 0.0), release: float = 0.0) -> Task:
    return Task(task_id, pickup, (0.0, 0.0), 1.0, release, "s", "pick-1")


def agent(task: Task | None = None, carrying=False, broken_until=-math.inf, dwell_until=None):
    return SimpleNamespace(
        task=task, carrying=carrying, broken_until=broken_until, dwell_until=dwell_until
    )


def status(state: str = "waiting", node: str | None = "n0_0", target=None, goal="n3_0"):
    return SimpleNamespace(state=state, node=node, target=target, goal=goal)


def block(graph, node: str, blocked: bool = True) -> None:
    """Every lane into and out of ``node`` (un)blocked, as a lane refresh would."""
    for u, v in [*graph.graph.in_edges(node), *graph.graph.out_edges(node)]:
        graph.graph.edges[u, v]["blocked"] = blocked


# ------------------------------------------------------------------------ returning
def test_a_trip_with_no_route_goes_back_after_the_wait_and_not_before():
    graph = grid_graph(4, 1)
    watch = ReturnWatch(30.0, graph, GEOMETRY)
    costs = np.full((10, 40), FREE, dtype=np.uint8)
    unit = agent(trip("t1"))
    stuck = status("no_route")
    assert watch.due(10.0, "u1", unit, stuck, costs) is None  # the count starts
    assert watch.due(39.9, "u1", unit, stuck, costs) is None
    assert watch.due(40.0, "u1", unit, stuck, costs) == NO_ROUTE
    assert watch.due(40.1, "u1", unit, stuck, costs) is None  # counted again from here


def test_a_tick_with_a_route_starts_the_count_again():
    graph = grid_graph(4, 1)
    watch = ReturnWatch(30.0, graph, GEOMETRY)
    costs = np.full((10, 40), FREE, dtype=np.uint8)
    unit = agent(trip("t1"))
    watch.due(0.0, "u1", unit, status("no_route"), costs)
    assert watch.due(20.0, "u1", unit, status("moving", None, "n1_0"), costs) is None
    watch.due(20.1, "u1", unit, status("no_route"), costs)
    assert watch.due(50.0, "u1", unit, status("no_route"), costs) is None
    assert watch.due(50.1, "u1", unit, status("no_route"), costs) == NO_ROUTE


def test_a_goal_cell_blocked_in_the_map_has_no_route_and_goes_back_at_a_node():
    graph = grid_graph(4, 1)
    watch = ReturnWatch(5.0, graph, GEOMETRY)
    costs = np.full((10, 40), FREE, dtype=np.uint8)
    col, row = GEOMETRY.world_to_cell(*graph.position("n3_0"))
    costs[row, col] = LETHAL
    unit = agent(trip("t1"))
    turning_back = status("stranded", node=None, target=None)
    assert watch.cause(0.0, unit, turning_back, costs) == GOAL_BLOCKED
    watch.due(0.0, "u1", unit, turning_back, costs)
    assert watch.due(6.0, "u1", unit, turning_back, costs) is None  # on a lane, no node
    driving = status("moving", node=None, target="n2_0")
    assert watch.due(6.1, "u1", unit, driving, costs) == GOAL_BLOCKED  # parks at n2_0


@pytest.mark.parametrize(
    "who",
    [
        agent(None),  # no trip
        agent(trip("t1"), carrying=True),  # picked up: it keeps the load
        agent(trip("t1"), broken_until=100.0),
        agent(trip("t1"), dwell_until=100.0),
    ],
)
def test_the_rule_leaves_units_without_a_trip_to_return(who):
    graph = grid_graph(4, 1)
    watch = ReturnWatch(5.0, graph, GEOMETRY)
    costs = np.full((10, 40), FREE, dtype=np.uint8)
    assert all(watch.due(t, "u1", who, status("no_route"), costs) is None for t in (0, 10, 20))


def test_without_a_return_after_trips_are_never_returned():
    watch = ReturnWatch(None, grid_graph(4, 1), GEOMETRY)
    costs = np.full((10, 40), FREE, dtype=np.uint8)
    unit = agent(trip("t1"))
    assert all(watch.due(t, "u1", unit, status("no_route"), costs) is None for t in (0, 99, 999))


# ------------------------------------------------------------------------ the queue
def test_a_returned_trip_goes_behind_the_trips_released_before_its_return():
    queue = TripQueue(grid_graph(4, 1), retry_after=0.0)
    for task in (trip("t1", (0, 0)), trip("t2", (3, 0)), trip("t3", (6, 0), release=50.0)):
        queue.add(task)
    queue.take(trip("t1", (0, 0)), 0.0)
    queue.give_back(trip("t1", (0, 0)), "u1", 40.0)
    assert [t.task_id for t in queue.released(60.0)] == ["t2", "t1", "t3"]


def test_a_blocked_goal_holds_its_trips_until_it_clears():
    graph = grid_graph(4, 1)
    dispatcher = Dispatcher(iter([trip("t1"), trip("t2"), trip("t3", (0.0, 0.0))]), graph, "first")
    dispatcher.queue.retry_after = 60.0
    idle = {"u1": "n0_0", "u2": "n1_0", "u3": "n2_0"}
    pairs = dispatcher.match(0.0, {"u1": "n0_0"})
    assert [(u, t.task_id) for u, t in pairs] == [("u1", "t1")]
    block(graph, "n3_0")
    dispatcher.give_back(trip("t1"), "u1", 30.0)
    # t1 and t2 go to the held goal n3_0: only t3 goes out, to the first idle unit
    assert [(u, t.task_id) for u, t in dispatcher.match(30.0, idle)] == [("u1", "t3")]
    assert dispatcher.match(40.0, idle) == []
    block(graph, "n3_0", blocked=False)  # its lanes read clear: the hold is lifted
    pairs = dispatcher.match(41.0, {"u1": "n0_0", "u2": "n1_0"})
    assert [(u, t.task_id) for u, t in pairs] == [("u1", "t2"), ("u2", "t1")]


def test_a_goal_blocked_for_good_lets_one_trip_go_per_retry_after():
    graph = grid_graph(4, 1)
    block(graph, "n3_0")
    dispatcher = Dispatcher(iter([trip("t1"), trip("t2")]), graph, "first")
    dispatcher.queue.retry_after = 60.0
    idle = {"u1": "n0_0", "u2": "n1_0"}
    (_, first), (_, second) = dispatcher.match(0.0, idle)  # nothing learnt yet: both go
    dispatcher.give_back(first, "u1", 30.0)
    dispatcher.give_back(second, "u2", 31.0)
    assert dispatcher.match(90.0, idle) == []  # held until 31 + 60
    pairs = dispatcher.match(91.0, idle)
    assert len(pairs) == 1  # one probe; the other waits for the next hold to time out
    assert dispatcher.match(150.0, idle) == []
    assert len(dispatcher.match(151.0, {"u3": "n0_0"})) == 1


def test_the_unit_that_returned_a_trip_gets_it_back_only_after_retry_after():
    graph = grid_graph(4, 1)  # the goal is reachable: the unit's own position was not
    dispatcher = Dispatcher(iter([trip("t1")]), graph, "first")
    dispatcher.queue.retry_after = 60.0
    ((_, task),) = dispatcher.match(0.0, {"u1": "n0_0"})
    dispatcher.give_back(task, "u1", 30.0)
    assert dispatcher.match(31.0, {"u1": "n0_0"}) == []
    assert [u for u, _ in dispatcher.match(31.0, {"u1": "n0_0", "u2": "n1_0"})] == ["u2"]


# ------------------------------------------------------------------------ a run
DROP_AT, REMOVE_AT, RETURN_AFTER = 0.0, 12.0, 5.0


def tote_on_a_pick_spot(seed: int = 3):
    """tiny.yaml with one unit and two trips (seed 3: t1 to s-2, then t2 to s-1); a tote
    lies on s-2 from the start and is taken away at 12 s; trips go back after 5 s, their
    goal held 10 s."""
    text = (
        TINY.read_text()
        .replace("count: 2\n  lidar", "count: 1\n  lidar")
        .replace(
            "  dwell: 1.0",
            f"  dwell: 1.0\n  return_after: {RETURN_AFTER}\n  retry_after: 10.0",
        )
        .replace("duration: 20.0", "duration: 45.0")
        .replace(
            "{at: 4.0, drop: tote-1, x: 1.5, y: 4.0}",
            f"{{at: {DROP_AT}, drop: tote-1, x: 8.0, y: 6.5}}",
        )  # fmt: skip
        .replace("at: 12.0", f"at: {REMOVE_AT}")
    )
    return parse_scenario(text, "tote_on_s2.yaml").with_seed(seed)


def trips_json(record, folder: Path) -> list[dict]:
    return json.loads(write_trips(record, folder / "trips.json").read_text())


def test_a_blocked_trip_is_returned_the_unit_works_on_and_the_trip_is_retried(tmp_path):
    scenario = tote_on_a_pick_spot()
    assert [(t.task_id, t.pickup_id) for t in scenario.task_stream()] == [
        ("t1", "s-2"), ("t2", "s-1")
    ]  # fmt: skip
    record = run(scenario)
    trips = {t["task"]: t for t in trips_json(record, tmp_path)}
    blocked, other = trips["t1"], trips["t2"]
    returned, completed = blocked["attempts"][0], blocked["attempts"][-1]
    assert returned["outcome"] == "returned" and returned["unit"] == "u1"
    assert returned["cause"] in (NO_ROUTE, GOAL_BLOCKED)
    assert returned["end"] - returned["start"] >= RETURN_AFTER
    assert returned["end"] < REMOVE_AT  # went back while the tote still lay there
    # the unit took other work at once, and finished it
    assert (other["unit"], other["assigned"]) == ("u1", returned["end"])
    assert [a["outcome"] for a in other["attempts"]] == ["completed"]
    # the returned trip was done later, after the tote had gone
    assert completed["outcome"] == "completed" and completed["start"] >= REMOVE_AT
    assert blocked["done"] is not None and blocked["done"] > other["done"]
    # its ideal and actual times are the completing attempt's alone
    assert blocked["assigned"] == completed["start"]
    assert blocked["actual_s"] == pytest.approx(blocked["done"] - completed["start"])
    metrics = record.metrics
    assert metrics["tasks_completed"] == 2
    assert (metrics["trips_returned"], metrics["trips_retried"]) == (1, 1)
    assert metrics["returned_s"] == pytest.approx(returned["end"] - returned["start"])
    # same seed, same trips.json
    again = run(tote_on_a_pick_spot())
    assert trips_json(again, tmp_path) == list(trips.values())
