"""The ``pibt`` lane coordination policy (``planner.policy_pibt``): units meeting at a
crossing or standing in a ring all get through, without the deadlock breaker."""

import pytest
from lane_helpers import Drive, grid_graph, pocket_graph, warehouse_graph

from planner.coordinator import POLICIES, LaneCoordinator
from planner.decisions import Action, Cause


def pibt(graph, **kw) -> LaneCoordinator:
    return LaneCoordinator(graph, policy="pibt", **kw)


def reached(coord: LaneCoordinator, uid: str, goal: str) -> bool:
    """Did ``uid`` park at ``goal`` (a parked unit may be pushed on later, and parks
    where it is pushed)?"""
    return any(
        d.unit == uid and d.action is Action.ARRIVED and d.route == (goal,) for d in coord.log
    )


def recoveries(coord: LaneCoordinator) -> list:
    return [d for d in coord.log if d.cause in (Cause.DEADLOCK, Cause.DEADLOCK_UNRESOLVED)]


@pytest.mark.parametrize("segment_m", [None, 1.5])
def test_four_units_meeting_at_a_two_way_crossing_all_get_through(segment_m):
    #        j1_2
    #         |
    #  j0_1 - j1_1 - j2_1     each unit drives through the crossing j1_1 to the far side
    #         |
    #        j1_0
    coord = pibt(warehouse_graph(3, 3, segment_m))
    drive = Drive(coord)
    trips = {"u1": ("j0_1", "j2_1"), "u2": ("j2_1", "j0_1"),
             "u3": ("j1_0", "j1_2"), "u4": ("j1_2", "j1_0")}  # fmt: skip
    for uid, (start, goal) in trips.items():
        drive.add(uid, start, goal)
    assert drive.run(400) is not None  # the invariants are checked every tick
    assert all(reached(coord, uid, goal) for uid, (_, goal) in trips.items())
    assert coord.deadlocks == 0 and not recoveries(coord)


def test_a_ring_of_units_each_wanting_the_next_ones_node_resolves_without_a_recovery():
    coord = pibt(grid_graph(4, 4))
    drive = Drive(coord)
    ring = ["n1_1", "n2_1", "n2_2", "n1_2"]
    for k, node in enumerate(ring):
        drive.add(f"u{k + 1}", node, ring[(k + 1) % 4])
    assert drive.run(200) is not None
    assert all(reached(coord, f"u{k + 1}", ring[(k + 1) % 4]) for k in range(4))
    assert coord.deadlocks == 0 and not recoveries(coord)
    # Somebody stepped out of the ring for a higher-priority unit (inheritance).
    assert any(d.action is Action.BACK_OFF and d.cause is Cause.INHERIT for d in coord.log)


def test_a_swap_on_a_lane_resolves_by_inheritance_without_a_recovery():
    coord = pibt(grid_graph(3, 3))
    drive = Drive(coord)
    drive.add("u1", "n0_0", "n1_0", priority=1)
    drive.add("u2", "n1_0", "n0_0")
    assert drive.run(100) is not None
    assert reached(coord, "u1", "n1_0") and reached(coord, "u2", "n0_0")
    assert coord.deadlocks == 0 and not recoveries(coord)


def test_a_parked_unit_in_the_way_is_pushed_aside_and_parks_there():
    # u1 is parked at b, on the only way from a to c: pushed aside into the pocket p
    # (off u2's route), where it parks.
    coord = pibt(pocket_graph())
    drive = Drive(coord)
    drive.add("u1", "b", "b")
    drive.add("u2", "a", "c")
    assert drive.run(100) is not None
    assert coord.status("u1").node == "p" and coord.status("u2").node == "c"
    (aside,) = [d for d in coord.log if d.unit == "u1" and d.action is Action.BACK_OFF]
    assert aside.cause is Cause.INHERIT
    assert aside.edge == ("b", "p") and aside.waiting_for == ("u2",)
    assert coord.deadlocks == 0


def test_the_same_inputs_give_the_same_decisions():
    def play() -> list:
        coord = pibt(warehouse_graph(3, 3, 1.5), reserve_ahead_m=2.0)
        drive = Drive(coord)
        for k, (start, goal) in enumerate(
            [
                ("j0_0", "j2_2"),
                ("j2_2", "j0_0"),
                ("j0_2", "j2_0"),
                ("j2_0", "j0_2"),
                ("j1_1", "j1_1"),
            ]  # fmt: skip
        ):
            drive.add(f"u{k + 1}", start, goal)
        drive.run(300)
        return coord.log

    assert play() == play()


def test_a_bad_policy_is_refused_naming_it():
    with pytest.raises(ValueError, match=r"policy must be one of reserve_ahead, pibt\b.*, got 'x'"):
        LaneCoordinator(grid_graph(2, 2), policy="x")
    assert POLICIES[0] == "reserve_ahead"  # the default stays today's coordinator
