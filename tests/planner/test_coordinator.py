"""The lane coordinator: no conflicting grants, deadlocks broken, blocked lanes left."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from lane_helpers import Drive, FakeMap, grid_graph, pocket_graph, warehouse_graph

from fleet.boxworld import BoxWorld, Warehouse
from planner.coordinator import ACTIONS, CoordinatorSettings, LaneCoordinator
from planner.decisions import Action, Cause
from planner.lane_graph import LaneGraph
from planner.reservations import unit_order


def actions(coord, unit, action=None, cause=None):
    return [
        d
        for d in coord.log
        if d.unit == unit
        and (action is None or d.action == action)
        and (cause is None or d.cause == cause)
    ]


# ---------------------------------------------------------------- deadlocks


def test_two_units_swapping_the_ends_of_a_lane_both_arrive():
    coord = LaneCoordinator(grid_graph(3, 3))
    drive = Drive(coord)
    drive.add("u1", "n0_0", "n1_0")
    drive.add("u2", "n1_0", "n0_0")
    assert drive.run(100) is not None
    assert coord.status("u1").node == "n1_0" and coord.status("u2").node == "n0_0"
    assert coord.deadlocks == 1
    # Equal priority: the larger id gives way, and the record says why.
    (gave_way,) = actions(coord, "u2", Action.REROUTE, Cause.DEADLOCK)
    assert gave_way.waiting_for == ("u1", "u2") and "u2 -> u1" in gave_way.detail
    assert not actions(coord, "u1", Action.REROUTE) and not actions(coord, "u1", Action.BACK_OFF)


def test_the_lower_priority_unit_gives_way():
    coord = LaneCoordinator(grid_graph(3, 3))
    drive = Drive(coord)
    drive.add("u1", "n0_0", "n1_0", priority=0)
    drive.add("u2", "n1_0", "n0_0", priority=5)
    assert drive.run(100) is not None
    assert actions(coord, "u1", Action.REROUTE, Cause.DEADLOCK)
    assert not actions(coord, "u2", Action.REROUTE)


def test_a_swap_in_a_corridor_with_a_pocket_backs_off_into_it():
    # u1: a -> c, u2: c -> a. Neither may stop in the crossing b while its way out is
    # held, so they deadlock; u2 (the larger id) backs off through b into the pocket p
    # and lets u1 pass.
    coord = LaneCoordinator(pocket_graph())
    drive = Drive(coord)
    drive.add("u1", "a", "c")
    drive.add("u2", "c", "a")
    waits = drive.step()
    assert {(d.unit, d.cause) for d in waits if d.action is Action.WAIT} == {
        ("u1", Cause.EXIT_HELD),
        ("u2", Cause.EXIT_HELD),
    }
    assert drive.run(200) is not None
    assert [coord.status(u).node for u in ("u1", "u2")] == ["c", "a"]
    assert coord.deadlocks == 1
    (back_off,) = actions(coord, "u2", Action.BACK_OFF, Cause.DEADLOCK)
    assert back_off.edge == ("c", "b") and back_off.route[:3] == ("c", "b", "p")
    assert back_off.waiting_for == ("u1", "u2")


def test_four_units_around_a_square_each_wanting_the_next_ones_node_all_arrive():
    coord = LaneCoordinator(grid_graph(4, 4))
    drive = Drive(coord)
    ring = ["n1_1", "n2_1", "n2_2", "n1_2"]
    for k, node in enumerate(ring):
        drive.add(f"u{k + 1}", node, ring[(k + 1) % 4])
    assert drive.run(200) is not None
    assert [coord.status(f"u{k + 1}").node for k in range(4)] == ring[1:] + ring[:1]
    assert coord.deadlocks == 1
    broke = [d for d in coord.log if d.cause is Cause.DEADLOCK]
    assert broke[0].unit == "u4" and broke[0].waiting_for == ("u1", "u2", "u3", "u4")


def test_an_idle_unit_in_the_way_moves_aside():
    g = LaneGraph(
        {"a": (0.0, 0.0), "b": (3.0, 0.0), "c": (6.0, 0.0), "p": (3.0, -3.0)},
        [("a", "b"), ("b", "c"), ("b", "p")],
    )
    coord = LaneCoordinator(g)
    drive = Drive(coord)
    drive.add("u1", "b", "b")  # parked on the only way from a to c
    drive.add("u2", "a", "c")
    assert drive.run(100) is not None
    (aside,) = actions(coord, "u1", Action.BACK_OFF, Cause.CLEAR_WAY)
    assert aside.edge == ("b", "p") and aside.waiting_for == ("u2",)
    assert coord.status("u1").node == "p" and coord.status("u2").node == "c"


# ---------------------------------------------------------------- corridors


def long_corridor() -> LaneGraph:
    """j0_0 - w0_0h1 - ... - w0_0h7 - j1_0: one 12 m stretch in eight 1.5 m lanes."""
    floor = Warehouse(BoxWorld(np.zeros((0, 4))), 18.0, 6.0, (3.0, 15.0), (3.0,))
    return LaneGraph.from_warehouse(floor, segment_m=1.5)


def test_units_follow_one_another_through_a_corridor():
    coord = LaneCoordinator(long_corridor())
    drive = Drive(coord)
    drive.add("u1", "w0_0h1", "j1_0")
    drive.add("u2", "j0_0", "w0_0h7")
    together = 0
    for _ in range(60):
        drive.step()
        if all(coord.status(u).state == "moving" for u in ("u1", "u2")):
            together += 1
    assert together > 10  # both driving the corridor at once, one lane apart
    assert [coord.status(u).node for u in ("u1", "u2")] == ["j1_0", "w0_0h7"]
    claims = [r for r in coord.log if r.action is Action.WAIT]
    assert all(d.cause is Cause.NODE_HELD for d in claims)  # u2 only ever waited behind u1


def test_units_never_meet_head_on_in_a_corridor():
    coord = LaneCoordinator(long_corridor())
    drive = Drive(coord)
    drive.add("u1", "j0_0", "w0_0h6")
    drive.step()  # u1 enters the corridor heading east ...
    drive.add("u2", "j1_0", "w0_0h2")
    (wait,) = [d for d in drive.step() if d.unit == "u2"]
    assert (wait.action, wait.cause, wait.waiting_for) == (Action.WAIT, Cause.LANE_HELD, ("u1",))
    assert coord.status("u2").node == "j1_0"  # ... so u2 may not enter it heading west
    while coord.status("u1").state == "moving":
        assert coord.status("u2").node == "j1_0"
        drive.step()
    # u1 parked inside: it no longer claims the corridor; u2 comes in and pushes it on.
    assert drive.run(200) is not None
    assert coord.status("u2").node == "w0_0h2"
    assert actions(coord, "u1", Action.BACK_OFF, Cause.CLEAR_WAY)


# ---------------------------------------------------------------- blocked lanes


def block(coord, fake, now, *points):
    fake.obstacles = list(points)
    return coord.refresh(now)


def test_a_unit_whose_route_becomes_blocked_is_rerouted():
    fake = FakeMap()
    coord = LaneCoordinator(grid_graph(3, 3), fake)
    drive = Drive(coord)
    drive.add("u1", "n1_0", "n1_2")
    assert coord.status("u1").route == ("n1_0", "n1_1", "n1_2")
    decisions = block(coord, fake, drive.now, (3.0, 4.5))  # on n1_1 - n1_2
    (rerouted,) = [d for d in decisions if d.unit == "u1"]
    assert (rerouted.action, rerouted.cause) == (Action.REROUTE, Cause.LANE_BLOCKED)
    assert "n1_1-n1_2" in rerouted.detail and ("n1_1", "n1_2") not in zip(
        rerouted.route, rerouted.route[1:], strict=False
    )
    assert drive.run(100) is not None and coord.status("u1").node == "n1_2"


def test_a_unit_on_a_lane_blocked_ahead_of_it_turns_back():
    fake = FakeMap()
    coord = LaneCoordinator(grid_graph(3, 3), fake)
    drive = Drive(coord)
    drive.add("u1", "n1_0", "n1_2")
    for _ in range(3):
        drive.step()  # granted n1_0 -> n1_1, 1 m up the lane
    assert coord.status("u1").edge == ("n1_0", "n1_1")
    decisions = block(coord, fake, drive.now, (3.0, 2.0))  # 2 m up: ahead of it
    turn, reverse = decisions
    assert (turn.action, turn.cause) == (Action.REROUTE, Cause.LANE_BLOCKED)
    assert turn.edge == ("n1_1", "n1_0")
    assert "ahead" in turn.detail
    assert (reverse.action, reverse.edge) == (Action.GRANT, ("n1_1", "n1_0"))
    status = coord.status("u1")
    assert status.target == "n1_0" and coord.holder("n1_1") is None
    assert coord.holder("n1_0") == "u1"
    highest = 0.0
    for _ in range(100):
        drive.step()
        x, y = drive.positions["u1"]
        if x == 3.0 and y < 3.0:
            highest = max(highest, y)
        if coord.status("u1").state == "idle":
            break
    assert coord.status("u1").node == "n1_2" and highest < 2.0


def test_a_unit_already_past_the_block_carries_on():
    fake = FakeMap()
    coord = LaneCoordinator(grid_graph(3, 3), fake)
    drive = Drive(coord)
    drive.add("u1", "n1_0", "n1_2")
    for _ in range(5):
        drive.step()  # 2 m up n1_0 -> n1_1
    (decision,) = block(coord, fake, drive.now, (3.0, 1.0))  # behind it
    assert (decision.action, decision.cause) == (Action.REROUTE, Cause.LANE_BLOCKED)
    assert "carrying on" in decision.detail
    assert coord.status("u1").target == "n1_1"
    assert drive.run(100) is not None and coord.status("u1").node == "n1_2"


def test_a_unit_that_cannot_turn_back_waits_on_the_lane_for_its_start():
    #   c          u1 drives b -> c (12 m); u2 parks at b behind it; the lane is then
    #   |          blocked ahead of u1, which must wait on the lane until u2 leaves b.
    #   |
    #   b - a
    g = LaneGraph({"a": (6.0, 0.0), "b": (3.0, 0.0), "c": (3.0, 12.0)}, [("a", "b"), ("b", "c")])
    fake = FakeMap()
    coord = LaneCoordinator(g, fake)
    drive = Drive(coord)
    drive.add("u1", "b", "c")
    for _ in range(3):
        drive.step()  # u1 has left b ...
    drive.add("u2", "a", "b")
    for _ in range(7):
        drive.step()  # ... and u2 has taken it and parked there
    assert coord.status("u2").node == "b" and coord.status("u1").state == "moving"
    block(coord, fake, drive.now, (3.0, 8.0))
    status = coord.status("u1")
    assert status.state == "stranded" and status.target is None
    assert status.waiting_for == ("u2",)
    assert actions(coord, "u1", Action.WAIT, Cause.LANE_BLOCKED)
    coord.request("u2", "b", "a", 0, drive.now)  # u2 leaves: u1 can go back ...
    for _ in range(40):
        drive.step()
    assert coord.status("u2").node == "a"
    status = coord.status("u1")  # ... to b, where it has no route to c
    assert (status.node, status.state) == ("b", "no_route")
    assert actions(coord, "u1", Action.GRANT, Cause.LANE_BLOCKED)[0].edge == ("c", "b")


def test_with_no_route_a_unit_waits_until_a_lane_clears():
    fake = FakeMap()
    coord = LaneCoordinator(grid_graph(2, 1), fake)
    drive = Drive(coord)
    block(coord, fake, drive.now, (1.5, 0.0))
    drive.add("u1", "n0_0", "n1_0")
    assert actions(coord, "u1", Action.WAIT, Cause.NO_ROUTE)
    for _ in range(10):
        drive.step()
    assert coord.status("u1").state == "no_route" and drive.positions["u1"] == (0.0, 0.0)
    block(coord, fake, drive.now)
    assert actions(coord, "u1", Action.REROUTE, Cause.LANE_CLEARED)
    assert drive.run(50) is not None


# ---------------------------------------------------------------- safety, property-based


@st.composite
def scenarios(draw):
    """A small lane grid (3 m spacing; maybe split into 1.5 m waypoints, maybe with one-way
    stretches), units at distinct nodes with random goals and priorities, and events: new
    tasks, lanes blocked at random points, all blocks cleared."""
    nx_, ny_ = draw(st.integers(2, 4)), draw(st.integers(2, 3))
    segment_m = draw(st.sampled_from([None, 1.5]))
    stretches = [(f"j{i}_{j}", f"j{i + 1}_{j}") for i in range(nx_ - 1) for j in range(ny_)]
    stretches += [(f"j{i}_{j}", f"j{i}_{j + 1}") for i in range(nx_) for j in range(ny_ - 1)]
    one_way = draw(st.lists(st.sampled_from(stretches), unique=True, max_size=2))
    one_way = [(b, a) if draw(st.booleans()) else (a, b) for a, b in one_way]
    names = warehouse_graph(nx_, ny_, segment_m, one_way).nodes
    n_units = draw(st.integers(1, min(7, len(names) - 1)))
    starts = draw(st.permutations(names))[:n_units]
    units = [
        (f"u{k + 1}", start, draw(st.sampled_from(names)), draw(st.integers(0, 2)))
        for k, start in enumerate(starts)
    ]
    events = draw(
        st.lists(
            st.tuples(
                st.integers(0, 150),  # tick
                st.sampled_from(["task", "block", "clear"]),
                st.integers(0, 1000),  # which unit and goal / which lane
                st.floats(0.1, 0.9),  # where on the lane the block is
            ),
            max_size=8,
        )
    )
    return nx_, ny_, segment_m, one_way, units, sorted(events, key=lambda e: e[0])


def play(scenario, reserve_ahead_m=0.0, policy="reserve_ahead"):
    """Drive a scenario, checking the invariants after every tick, refresh and request;
    until a lane is first blocked, also that no corridor is driven both ways at once."""
    nx_, ny_, segment_m, one_way, units, events = scenario
    graph = warehouse_graph(nx_, ny_, segment_m, one_way)
    fake = FakeMap()
    coord = LaneCoordinator(graph, fake, reserve_ahead_m=reserve_ahead_m, policy=policy)
    drive = Drive(coord)
    for uid, start, goal, priority in units:
        drive.add(uid, start, goal, priority)
    drive.check()
    pending = list(events)
    blocked_ever = False
    for tick in range(160):
        while pending and pending[0][0] <= tick:
            _, kind, k, where = pending.pop(0)
            if kind == "task":
                uid = units[k % len(units)][0]
                status = coord.status(uid)
                start = status.node or (
                    status.edge[0] if status.state == "stranded" else status.target
                )
                coord.request(uid, start, graph.nodes[k % len(graph.nodes)], k % 3, drive.now)
            else:
                a, b = graph.lanes[k % len(graph.lanes)]
                (ax, ay), (bx, by) = graph.position(a), graph.position(b)
                point = (ax + (bx - ax) * where, ay + (by - ay) * where)
                if kind == "block":
                    fake.obstacles.append(point)
                    blocked_ever = True
                else:
                    fake.obstacles = []
                coord.refresh(drive.now)
            drive.check()
        drive.step()
        for uid, *_ in units:  # the shortcut says what the whole status says
            status = coord.status(uid)
            assert coord.start_node(uid) == (status.node or status.target)
        if not blocked_ever:
            check_corridors_one_way(coord)
    return coord


def check_corridors_one_way(coord):
    headings = {}
    for r in coord.reservations():
        if r.kind == "corridor":
            headings.setdefault(r.resource, set()).add(r.tail)
    assert all(len(ends) == 1 for ends in headings.values()), headings


POLICY_CASES = [(0.0, "reserve_ahead"), (2.0, "reserve_ahead"), (0.0, "pibt"), (2.0, "pibt")]


@pytest.mark.parametrize(("reserve_ahead_m", "policy"), POLICY_CASES)
@given(scenario=scenarios())
def test_the_coordinator_never_grants_conflicting_lanes(scenario, reserve_ahead_m, policy):
    coord = play(scenario, reserve_ahead_m, policy)
    assert all(d.action in ACTIONS and isinstance(d.cause, Cause) for d in coord.log)


@pytest.mark.parametrize(("reserve_ahead_m", "policy"), POLICY_CASES)
@given(scenario=scenarios())
def test_the_same_inputs_give_the_same_decisions(scenario, reserve_ahead_m, policy):
    first = play(scenario, reserve_ahead_m, policy).log
    assert first == play(scenario, reserve_ahead_m, policy).log


# ---------------------------------------------------------------- interface


def test_requests_are_checked_and_name_the_bad_value():
    coord = LaneCoordinator(grid_graph(2, 2))
    coord.request("u1", "n0_0", "n1_0", 0, 1.0)
    with pytest.raises(ValueError, match="start_node 'n0_0' is held by unit 'u1'"):
        coord.request("u2", "n0_0", "n1_1", 0, 1.0)
    with pytest.raises(ValueError, match="start_node 'n1_1' for unit 'u1'.*'n0_0'"):
        coord.request("u1", "n1_1", "n0_0", 0, 1.0)
    with pytest.raises(ValueError, match="goal_node|not a node"):
        coord.request("u3", "n0_1", "nowhere", 0, 1.0)
    with pytest.raises(ValueError, match="priority must be finite, got nan"):
        coord.request("u3", "n0_1", "n1_1", math.nan, 1.0)
    with pytest.raises(ValueError, match="now must not go backwards: got 0.5 after 1.0"):
        coord.tick(0.5, {})
    with pytest.raises(ValueError, match="unit_positions\\['u1'\\]"):
        coord.tick(2.0, {"u1": (math.inf, 0.0)})
    with pytest.raises(ValueError, match="refresh needs a map client"):
        coord.refresh(2.0)
    with pytest.raises(ValueError, match="clear_m must be a positive"):
        LaneCoordinator(grid_graph(2, 2), clear_m=0.0)
    with pytest.raises(ValueError, match="back_off_hops must be an integer >= 1, got 0"):
        LaneCoordinator(grid_graph(2, 2), back_off_hops=0)
    with pytest.raises(ValueError, match="give settings or clear_m, not both"):
        LaneCoordinator(grid_graph(2, 2), settings=CoordinatorSettings(), clear_m=2.0)


def test_reservations_carry_time_windows_and_decisions_serialise():
    coord = LaneCoordinator(grid_graph(2, 1), speed=1.5, clear_m=1.0)
    coord.request("u1", "n0_0", "n1_0", 0, 2.0)
    (grant,) = coord.tick(2.0, {"u1": (0.0, 0.0)})
    assert grant.to_dict() == {
        "time": 2.0, "unit": "u1", "action": "grant", "cause": "route",
        "detail": "n0_0 -> n1_0", "edge": ["n0_0", "n1_0"], "waiting_for": [],
        "route": ["n0_0", "n1_0"],
    }  # fmt: skip
    plain = grant.to_dict()  # the strings of docs/files.md, not the enum members
    assert type(plain["action"]) is str and type(plain["cause"]) is str
    windows = {(r.kind, r.resource): r for r in coord.reservations()}
    assert windows["lane", ("n0_0", "n1_0")].tail == "n0_0"
    assert windows["lane", ("n0_0", "n1_0")].expected_end == pytest.approx(2.0 + 3.0 / 1.5)
    assert windows["node", "n1_0"].expected_end == pytest.approx(2.0 + 4.0 / 1.5)
    assert windows["node", "n0_0"].start == 2.0
    coord.tick(3.0, {"u1": (1.2, 0.0)})  # clear of n0_0: released
    assert coord.holder("n0_0") is None and coord.holder("n1_0") == "u1"
    (arrived,) = coord.tick(4.0, {"u1": (2.95, 0.0)})
    assert (arrived.action, arrived.cause) == (Action.ARRIVED, Cause.GOAL)
    assert [r.kind for r in coord.reservations()] == ["node"]
    assert coord.reservations()[0].expected_end == math.inf


def test_unit_ids_sort_naturally():
    assert sorted(["u10", "u9", "u1"], key=unit_order) == ["u1", "u9", "u10"]
