"""Throughput metrics (scenarios.score.throughput): ideal trip times worked out by hand, and the
aggregation of a hand-built sequence of unit-ticks."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import pytest

from fleet.unit import DriveLimits
from mapserver.core.geometry import GridGeometry
from planner.lane_graph import LaneGraph
from planner.navigator import Command
from scenarios.run.agents import AgentState
from scenarios.run.record import Attempt, RunRecord, TripRecord, UnfinishedTrip
from scenarios.score.throughput import ThroughputTracker, ideal_trip_s, segment_s
from scenarios.score.trips_json import write_trips

LIMITS = DriveLimits(max_speed=1.5, max_accel=1.0, max_turn_rate=1.5)


def _task(pickup, dropoff, dwell: float, task_id: str = "t1"):
    return SimpleNamespace(task_id=task_id, pickup=pickup, dropoff=dropoff, dwell=dwell)


def _line(length: float, waypoints: int = 0) -> LaneGraph:
    """Nodes a (0, 0) and b (length, 0), with ``waypoints`` evenly spaced between."""
    xs = [length * k / (waypoints + 1) for k in range(waypoints + 2)]
    names = ["a", *(f"w{k}" for k in range(1, waypoints + 1)), "b"]
    return LaneGraph(
        {n: (x, 0.0) for n, x in zip(names, xs, strict=True)},
        list(zip(names, names[1:], strict=False)),
    )


def test_a_run_is_trapezoidal_when_long_and_triangular_when_short():
    assert segment_s(20.0, 0, 0, LIMITS) == pytest.approx(20.0 / 1.5 + 1.5)  # 14.8333 s
    assert segment_s(1.0, 0, 0, LIMITS) == pytest.approx(2.0)  # 2 sqrt(1 / 1)
    assert segment_s(2.25, 0, 0, LIMITS) == pytest.approx(3.0)  # v^2 / a: profiles meet
    assert segment_s(0.0, 0, 0, LIMITS) == 0.0


def test_a_straight_lane_trip_out_and_back_is_two_runs_a_turn_back_and_two_dwells():
    graph = _line(20.0, waypoints=3)  # straight-through waypoints do not stop the unit
    task = _task(pickup=(20.0, 0.2), dropoff=(0.1, 0.0), dwell=3.0)
    expected = (20 / 1.5 + 1.5) + math.pi / 1.5 + (20 / 1.5 + 1.5) + 2 * 3.0  # 37.7611 s
    assert ideal_trip_s(graph, (0.0, 0.0), "a", task, LIMITS) == pytest.approx(expected)


def test_a_short_trip_is_driven_on_triangular_profiles():
    graph = _line(1.0)
    task = _task(pickup=(1.0, 0.0), dropoff=(0.0, 0.0), dwell=0.5)
    expected = 2.0 + math.pi / 1.5 + 2.0 + 2 * 0.5  # 2 sqrt(L / a) per run
    assert ideal_trip_s(graph, (0.0, 0.0), "a", task, LIMITS) == pytest.approx(expected)


def _l_graph() -> LaneGraph:
    """a (0, 0) - b (10, 0) - c (10, 5) - d (10, 8), and a detour a - e (0, 8) - c."""
    positions = {"a": (0, 0), "b": (10, 0), "c": (10, 5), "d": (10, 8), "e": (0, 8)}
    return LaneGraph(positions, [("a", "b"), ("b", "c"), ("c", "d"), ("a", "e"), ("e", "c")])


# A quarter turn is cut into two 45-degree bends, passed at the drive's corner speed:
# at full turn rate 1.5 rad/s the swing outside stays within CORNER_ERROR_M (0.05 m).
CORNER = 1.5 * 0.05 / (1 - math.cos(math.pi / 4))  # [m/s] = 0.2561


def _stretch(length: float, v0: float, v1: float) -> float:
    """[s] over ``length`` [m] from v0 up to 1.5 m/s, cruising, braking to v1 at 1 m/s^2."""
    ramps = (2 * 1.5**2 - v0**2 - v1**2) / 2  # [m] covered speeding up and braking
    return (1.5 - v0) + (1.5 - v1) + (length - ramps) / 1.5


def test_an_l_shaped_trip_slows_for_its_corner_without_stopping():
    graph = _l_graph()
    for u, v in (("a", "b"), ("b", "a")):  # blocked and costly: the ideal ignores both
        graph.graph.edges[u, v].update(blocked=True, weight=1e6, penalty=1e6 - 10)
    task = _task(pickup=(10.0, 5.0), dropoff=(10.0, 8.0), dwell=2.0)
    expected = (
        _stretch(10, 0, CORNER)  # a -> b, down to the corner speed at b
        + _stretch(5, CORNER, 0)  # b -> c, stop at the pickup; c -> d goes straight on
        + (3 / 1.5 + 1.5)  # c -> d
        + 2 * 2.0
    )
    assert expected < (10 / 1.5 + 1.5) + (math.pi / 2) / 1.5 + (5 / 1.5 + 1.5) + 3.5 + 4
    assert ideal_trip_s(graph, (0.0, 0.0), "a", task, LIMITS) == pytest.approx(expected)


def test_a_unit_off_its_node_drives_to_it_first_and_one_on_it_does_not():
    graph = _l_graph()
    task = _task(pickup=(10.0, 0.0), dropoff=(10.0, 0.0), dwell=0.0)
    on_node = 10 / 1.5 + 1.5
    assert ideal_trip_s(graph, (0.07, -0.07), "a", task, LIMITS) == pytest.approx(on_node)
    peak = math.sqrt(0.5 + CORNER**2 / 2)  # 0.5 m up to a: never reaches 1.5 m/s
    off = peak + (peak - CORNER) + _stretch(10, CORNER, 0)
    assert ideal_trip_s(graph, (0.0, -0.5), "a", task, LIMITS) == pytest.approx(off)


def test_a_trip_with_no_route_has_no_ideal_time():
    graph = LaneGraph({"a": (0, 0), "b": (5, 0)}, [("a", "b")], one_way=[("a", "b")])
    task = _task(pickup=(0.0, 0.0), dropoff=(0.0, 0.0), dwell=1.0)
    assert ideal_trip_s(graph, (5.0, 0.0), "b", task, LIMITS) is None


# ------------------------------------------------------------------------------ the tracker
def _state(has_task: bool, blocked: str | None = None, done=None) -> AgentState:
    kind = "stop" if has_task else "idle"
    return AgentState(Command(kind), has_task, blocked, (), None, task_done=done)


def test_metrics_add_up_a_hand_built_sequence_of_unit_ticks():
    graph = _line(1.0)
    task = _task(pickup=(1.0, 0.0), dropoff=(0.0, 0.0), dwell=0.0)
    ideal = 2.0 + math.pi / 1.5 + 2.0  # 6.0944 s
    tracker = ThroughputTracker(graph, dt=0.5)
    tracker.assigned((0.0, 0.0), "a", task, 0.0, LIMITS)
    idle = SimpleNamespace(broken_until=-math.inf, dwell_until=None)
    dwelling = SimpleNamespace(broken_until=-math.inf, dwell_until=9.0)
    broken = SimpleNamespace(broken_until=9.0, dwell_until=9.0)  # a breakdown beats a dwell
    done = SimpleNamespace(broken_until=-math.inf, dwell_until=1.0)  # a dwell that is over
    ticks = [  # (now, agent, state, speed [m/s], turn rate [rad/s])
        (0.5, idle, _state(True), 1.0, 0.0),  # driving
        (1.0, idle, _state(True), 2.0, 0.3),  # driving (and steering)
        (1.5, idle, _state(True), 0.0, 1.5),  # turn
        (2.0, idle, _state(True, "no path to (1.00, 0.00)"), 0.0, 0.0),  # freeze
        (2.5, dwelling, _state(True), 0.0, 0.0),  # dwell
        (3.0, broken, _state(True), 0.0, 0.0),  # breakdown
        (3.5, done, _state(True), 0.0, 0.0),  # traffic
        (4.0, idle, _state(True), 0.0, 0.0),  # traffic
        (4.5, idle, _state(False, done=task), 1.5, 0.0),  # trip done; moving without a task
        (5.0, idle, _state(False), 0.0, 0.0),  # parked: not counted
    ]
    for now, agent, state, speed, turn_rate in ticks:
        tracker.observe("u1", now, agent, state, SimpleNamespace(speed=speed, turn_rate=turn_rate))
    assert tracker.trips == [TripRecord("t1", "u1", 0.0, 4.5, pytest.approx(ideal))]
    assert tracker.trips[0].actual_s == 4.5
    assert tracker.metrics(units=2, sim_seconds=5.0) == {
        "trips_per_unit_hour": 360.0,  # 1 trip / (2 units x 5 s / 3600)
        "ideal_trip_s": round(ideal, 3),
        "trip_time_ratio": round(4.5 / ideal, 4),
        "fleet_efficiency": round(ideal / 10.0, 4),
        "moving_share": 0.25,  # 2 of 8 unit-ticks with a task
        "mean_speed_moving": 1.5,  # (1.0 + 2.0 + 1.5) / 3
        "wait_s": {"traffic": 1.0, "freeze": 0.5, "dwell": 0.5, "breakdown": 0.5, "turn": 0.5},
        "trips_returned": 0,
        "trips_retried": 0,
        "returned_s": 0.0,
    }


def test_metrics_of_a_run_with_nothing_to_average_are_null():
    tracker = ThroughputTracker(_line(1.0), dt=0.1)
    zeros = dict.fromkeys(("traffic", "freeze", "dwell", "breakdown", "turn"), 0.0)
    assert tracker.metrics(units=3, sim_seconds=60.0) == {
        "trips_per_unit_hour": 0.0,
        "ideal_trip_s": None,
        "trip_time_ratio": None,
        "fleet_efficiency": 0.0,
        "moving_share": None,
        "mean_speed_moving": None,
        "wait_s": zeros,
        "trips_returned": 0,
        "trips_retried": 0,
        "returned_s": 0.0,
    }
    assert tracker.metrics(units=3, sim_seconds=0.0)["trips_per_unit_hour"] is None


def test_a_returned_attempt_is_time_lost_and_the_completing_attempt_alone_is_scored():
    graph = _line(4.0)
    task = _task(pickup=(4.0, 0.0), dropoff=(0.0, 0.0), dwell=0.0)
    other = _task(pickup=(4.0, 0.0), dropoff=(0.0, 0.0), dwell=0.0, task_id="t2")
    tracker = ThroughputTracker(graph, dt=1.0)
    tracker.assigned((0.0, 0.0), "a", task, 0.0, LIMITS, "u1")
    tracker.returned(task, 30.0, "no_route")  # u1 gives it back after 30 s
    tracker.assigned((0.0, 0.0), "a", other, 30.0, LIMITS, "u1")
    tracker.assigned((4.0, 0.0), "b", task, 40.0, LIMITS, "u2")  # retried from b
    third = _task(pickup=(4.0, 0.0), dropoff=(0.0, 0.0), dwell=0.0, task_id="t3")
    tracker.assigned((4.0, 0.0), "b", third, 41.0, LIMITS, "u3")
    tracker.returned(third, 50.0, "goal_blocked")  # and never done
    idle = SimpleNamespace(broken_until=-math.inf, dwell_until=None)
    drive = SimpleNamespace(speed=1.0, turn_rate=0.0)
    tracker.observe("u2", 52.0, idle, _state(False, done=task), drive)
    ideal = ideal_trip_s(graph, (4.0, 0.0), "b", task, LIMITS)  # from where u2 started
    assert tracker.trips == [
        TripRecord("t1", "u2", 40.0, 52.0, pytest.approx(ideal),
                   (Attempt("u1", 0.0, 30.0, "returned", "no_route"),)),
    ]  # fmt: skip
    assert [a.outcome for a in tracker.trips[0].attempts] == ["returned", "completed"]
    assert tracker.unfinished() == [
        UnfinishedTrip("t3", (Attempt("u3", 41.0, 50.0, "returned", "goal_blocked"),)),
    ]
    metrics = tracker.metrics(units=2, sim_seconds=60.0)
    assert metrics["ideal_trip_s"] == round(ideal, 3)
    assert metrics["trip_time_ratio"] == round(12.0 / ideal, 4)  # 52 - 40, not 52 - 0
    assert metrics["fleet_efficiency"] == round(ideal / 120.0, 4)
    assert (metrics["trips_returned"], metrics["trips_retried"]) == (2, 1)
    assert metrics["returned_s"] == 30.0 + 9.0


def test_trips_json_lists_each_completed_trip_then_the_returned_unfinished_ones(tmp_path):
    record = RunRecord("tiny", "decay", 0, GridGeometry(10, 10, 0.5))
    record.trips += [
        TripRecord("t2", "u1", 0.0, 30.25, 21.83349),
        TripRecord("t1", "u2", 1.5, 40.0, None, (Attempt("u1", 0.1, 1.4, "returned", "no_route"),)),
    ]
    record.unfinished_trips.append(
        UnfinishedTrip(
            "t3",
            (
                Attempt("u2", 2.0, 32.0, "returned", "goal_blocked"),
                Attempt("u1", 45.0, None, "open"),
            ),
        )
    )
    path = write_trips(record, tmp_path / "trips.json")
    assert json.loads(path.read_text()) == [
        {"task": "t2", "unit": "u1", "assigned": 0.0, "done": 30.25, "ideal_s": 21.833,
         "actual_s": 30.25, "attempts": [
             {"unit": "u1", "start": 0.0, "end": 30.25, "outcome": "completed", "cause": None}]},
        {"task": "t1", "unit": "u2", "assigned": 1.5, "done": 40.0, "ideal_s": None,
         "actual_s": 38.5, "attempts": [
             {"unit": "u1", "start": 0.1, "end": 1.4, "outcome": "returned", "cause": "no_route"},
             {"unit": "u2", "start": 1.5, "end": 40.0, "outcome": "completed", "cause": None}]},
        {"task": "t3", "unit": None, "assigned": None, "done": None, "ideal_s": None,
         "actual_s": None, "attempts": [
             {"unit": "u2", "start": 2.0, "end": 32.0, "outcome": "returned",
              "cause": "goal_blocked"},
             {"unit": "u1", "start": 45.0, "end": None, "outcome": "open", "cause": None}]},
    ]  # fmt: skip
