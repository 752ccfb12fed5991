"""Reserving ahead: units granted their next lanes before they reach the end of the one
they drive keep moving through nodes, follow one another, and still never conflict."""

import numpy as np
from lane_helpers import Drive

from fleet.boxworld import BoxWorld, Warehouse
from planner.coordinator import LaneCoordinator
from planner.decisions import Action
from planner.lane_graph import LaneGraph

SPEED, DT = 1.5, 0.1  # [m/s], [s]


def corridor(length: float = 30.0, segment_m: float = 3.0) -> LaneGraph:
    """j0_0 - w0_0h1 - ... - j1_0: one ``length`` [m] stretch split every ``segment_m``."""
    floor = Warehouse(BoxWorld(np.zeros((0, 4))), length + 6.0, 6.0, (3.0, 3.0 + length), (3.0,))
    return LaneGraph.from_warehouse(floor, segment_m=segment_m)


def stops(moved: list[float]) -> list[int]:
    """Ticks between a unit's first and last move on which it moved less than a full
    step (its last step may be short: it lands on its goal)."""
    driving = [k for k, m in enumerate(moved) if m > 0]
    return [k for k in range(driving[0], driving[-1]) if moved[k] < SPEED * DT - 1e-9]


def test_a_unit_drives_through_every_node_of_its_route_without_stopping():
    coord = LaneCoordinator(corridor(), reserve_ahead_m=2.5)
    drive = Drive(coord, dt=DT, speed=SPEED)
    drive.add("u1", "j0_0", "j1_0")
    assert drive.run(400) is not None
    assert stops(drive.moved["u1"]) == []
    assert sum(m > 0 for m in drive.moved["u1"]) == 200  # 30 m at 1.5 m/s in 0.1 s steps


def test_a_column_follows_one_another_through_a_corridor_without_stopping_at_nodes():
    # Four units three lanes apart drive east in a column: each is granted the node
    # ahead as soon as the unit before it is clear of it, so none ever waits.
    graph = corridor(length=60.0)
    coord = LaneCoordinator(graph, reserve_ahead_m=2.5, clear_m=0.8)
    drive = Drive(coord, dt=DT, speed=SPEED)
    names = sorted(graph.nodes, key=lambda n: graph.position(n)[0])  # west to east
    for k in range(4):  # u1 leads from the tenth node, u4 starts at the west end
        drive.add(f"u{k + 1}", names[9 - 3 * k], names[-1 - 3 * k])
    assert drive.run(600) is not None
    for k in range(4):
        uid = f"u{k + 1}"
        assert stops(drive.moved[uid]) == [], uid
        assert coord.status(uid).node == names[-1 - 3 * k]
    assert not [d for d in coord.log if d.action is Action.WAIT]


def test_two_units_meeting_head_on_in_an_aisle_both_get_through():
    # Two parallel 30 m aisles joined at both ends; u1 and u2 start at the two ends of the
    # south aisle, each bound for the other end. The aisle is driven one way at a time:
    # one drives it, the other waits at its end or takes the north aisle; both arrive.
    floor = Warehouse(BoxWorld(np.zeros((0, 4))), 36.0, 12.0, (3.0, 33.0), (3.0, 9.0))
    graph = LaneGraph.from_warehouse(floor, segment_m=3.0)
    west, east = graph.nearest_node(3.0, 3.0), graph.nearest_node(33.0, 3.0)
    coord = LaneCoordinator(graph, reserve_ahead_m=2.5)
    drive = Drive(coord, dt=DT, speed=SPEED)
    drive.add("u1", west, east)
    drive.add("u2", east, west)
    ticks = drive.run(1000)
    assert ticks is not None
    assert coord.status("u1").node == east and coord.status("u2").node == west
    assert ticks * DT < 2 * 30.0 / SPEED + 10.0  # no long stand-off: well under two trips
