"""Lane freezes name what blocked them: the blocked lanes on the unit's way and their first
blocked cells, through to freezes.json."""

import json
from types import SimpleNamespace

import numpy as np
from lane_helpers import Drive, FakeMap

from mapserver.client import CellOut
from mapserver.core.geometry import GridGeometry
from planner.coordinator import LaneCoordinator
from planner.freeze import FreezeDetector, LaneBlock, Segment, UnitObservation
from planner.lane_graph import LaneGraph
from scenarios.run.record import RunRecord
from scenarios.score.evidence import freeze_records
from scenarios.score.freezes_json import write_freezes
from scenarios.score.lane_evidence import blocking_cut, lane_block, lane_blocking_points

#   p           a8 ---- a9        u1 at a, goal c. Blocked: b-c (two obstacles), a9-c,
#   |           |       |         and a-p, the lane into a dead-end pocket. Every way to
#   a --------- b ----- c         c crosses b-c or a9-c; a-p leads nowhere but back.
POSITIONS = {
    "a": (0.0, 0.0),
    "b": (3.0, 0.0),
    "c": (6.0, 0.0),
    "a8": (3.0, 3.0),
    "a9": (6.0, 3.0),
    "p": (0.0, 3.0),
}
LANES = [("a", "b"), ("b", "c"), ("b", "a8"), ("a8", "a9"), ("a9", "c"), ("a", "p")]
OBSTACLES = [(4.0, 0.0), (5.0, 0.0), (6.0, 1.5), (0.0, 1.5)]


def occupied(point, last_observed, age):
    """A map server's answer for an occupied cell at ``point`` [m]."""
    x, y = point
    return CellOut(
        x=x, y=y, state="occupied", p_occ=0.9, cost=254, last_observed=last_observed, age=age
    )


def no_route_unit():
    graph = LaneGraph(POSITIONS, LANES)
    fake = FakeMap()
    fake.obstacles = list(OBSTACLES)
    coord = LaneCoordinator(graph, fake)
    coord.refresh(0.0)
    coord.request("u1", "a", "c", 0.0, 0.0)
    assert coord.status("u1").state == "no_route"
    return graph, coord


def test_the_lane_graph_keeps_the_first_blocked_cell_seen_from_each_end():
    graph, _ = no_route_unit()
    edges = graph.graph.edges
    assert edges["b", "c"]["block_cells"] == ((4.0, 0.0), (5.0, 0.0))  # from b, then from c
    assert edges["c", "b"]["block_cells"] == ((5.0, 0.0), (4.0, 0.0))
    assert edges["a9", "c"]["block_cells"] == ((6.0, 1.5),)  # one cell seen from both ends
    assert edges["a", "b"]["block_cells"] is None


def test_a_unit_with_no_route_is_held_by_the_blocked_lanes_cutting_it_off_its_goal():
    graph, coord = no_route_unit()
    block = lane_block(coord, graph, "u1")
    # b-c first: on the way it would drive on a clear floor (a-b-c); then a9-c. Not a-p.
    assert block == LaneBlock(
        origin=("a",),
        goal="c",
        lanes=(("b", "c"), ("a9", "c")),
        points=((4.0, 0.0), (5.0, 0.0), (6.0, 1.5)),
    )
    assert lane_blocking_points(coord, graph, "u1") == block.points
    assert blocking_cut(graph, "a", "c") == [("b", "c"), ("a9", "c")]
    assert blocking_cut(graph, "a", "a9") == []  # a9 is reachable: nothing cuts it off


def test_a_one_way_lane_is_in_the_cut_only_in_the_direction_it_may_be_driven():
    graph = LaneGraph(
        {"a": (0.0, 0.0), "b": (3.0, 0.0), "c": (6.0, 0.0)},
        [("a", "b"), ("b", "c")],
        one_way=[("c", "b")],
    )
    fake = FakeMap()
    fake.obstacles = [(1.0, 0.0)]
    graph.refresh(fake)
    assert blocking_cut(graph, "b", "a") == [("b", "a")]
    assert blocking_cut(graph, "a", "c") == []  # b -> c is not a lane: no route to cut
    assert blocking_cut(graph, "c", "a") == [("b", "a")]


def test_a_unit_stranded_on_a_blocked_lane_names_that_lane():
    #   c          u1 drives b -> c; u2 parks at b behind it; the lane is blocked ahead of
    #   |          u1, which must wait on it for b (as in test_coordinator).
    #   b - a
    graph = LaneGraph(
        {"a": (6.0, 0.0), "b": (3.0, 0.0), "c": (3.0, 12.0)}, [("a", "b"), ("b", "c")]
    )
    fake = FakeMap()
    coord = LaneCoordinator(graph, fake)
    drive = Drive(coord)
    drive.add("u1", "b", "c")
    for _ in range(3):
        drive.step()
    drive.add("u2", "a", "b")
    for _ in range(7):
        drive.step()
    assert lane_block(coord, graph, "u1") is None  # driving: not held
    fake.obstacles = [(3.0, 8.0)]
    coord.refresh(drive.now)
    assert coord.status("u1").state == "stranded"
    assert lane_block(coord, graph, "u1") == LaneBlock(
        origin=("b", "c"), goal="c", lanes=(("b", "c"),), points=((3.0, 8.0),)
    )
    assert lane_block(coord, graph, "u2") is None  # parked at its goal


class Truth:
    """Ground truth that knows one occupied point."""

    def __init__(self, occupied):
        self.occupied = occupied

    def is_occupied(self, points, at=None):
        return np.array([tuple(p) == self.occupied for p in np.asarray(points).tolist()])


def test_a_lane_freeze_in_freezes_json_names_its_lanes_and_their_cells(tmp_path):
    graph, coord = no_route_unit()
    detector = FreezeDetector()
    evidence = {}
    for k in range(6):  # the runner's loop, 0.25 s ticks: observe, then note the evidence
        stamp = 0.25 * k
        block = lane_block(coord, graph, "u1")
        detector.observe(
            UnitObservation(
                "u1",
                stamp,
                True,
                False,
                "no lane to (6.00, 0.00)",
                block.points,
                (6.0, 0.0),
                (0.0, 0.0),
                lane_block=block,
            )
        )
        for point in block.points:  # first seen: read from the map
            seen = 1.5 if point == (5.0, 0.0) else None
            evidence.setdefault(
                ("u1", point),
                (stamp, occupied(point, seen, None)),
            )
    (freeze,) = detector.finish(1.5)
    assert freeze.lanes == [("b", "c"), ("a9", "c")]
    assert freeze.lane_block.origin == ("a",)
    agents = {"u1": SimpleNamespace(navigator=SimpleNamespace(actions=[]))}
    scans = {1.5: [("u2", 4.0, 0.5, 8.0)]}
    freeze.segments = [Segment(freeze.start, freeze.end, "true_block", "no lane route")]
    (rec,) = freeze_records(detector.freezes, agents, coord, Truth((5.0, 0.0)), evidence, scans)
    assert rec.lanes == (("b", "c"), ("a9", "c"))
    record = RunRecord("x", "decay", 1, GridGeometry(80, 40, 0.1))
    record.freezes.append(rec)
    (out,) = json.loads(write_freezes(record, tmp_path / "freezes.json").read_text())
    assert out["lanes"] == [["b", "c"], ["a9", "c"]]
    cells = out["blocking_cells"]
    assert [(c["x"], c["y"]) for c in cells] == [(4.0, 0.0), (5.0, 0.0), (6.0, 1.5)]
    assert [c["truly_occupied"] for c in cells] == [False, True, False]
    assert cells[1]["marked_by"] == [{"unit": "u2", "stamp": 1.5}]
    assert cells[0]["last_observed"] is None and cells[0]["p_occ"] == 0.9


def test_each_freeze_gets_the_evidence_read_during_it_not_at_an_earlier_freeze():
    """A unit frozen twice by one cell: the first freeze's reading (the box there) must not
    stand for the second (the box gone, the map still blocked: a phantom)."""
    detector = FreezeDetector()
    point = (4.0, 0.0)
    evidence = {}
    for k in range(20):  # blocked 0 .. 1.5 s and 3 .. 4.75 s
        stamp = 0.25 * k
        blocked = stamp < 1.75 or stamp >= 3.0
        reason = "no path to (6.00, 0.00)" if blocked else None
        detector.observe(
            UnitObservation("u1", stamp, True, not blocked, reason, (point,) if blocked else (),
                            (6.0, 0.0), (0.0, 0.0))
        )  # fmt: skip
        if blocked:  # the observer's rule: read a point again once per blocked run
            since = detector.open_since("u1")
            readings = evidence.setdefault(("u1", point), [])
            if not any(s >= since for s, _ in readings):
                readings.append((stamp, occupied(point, stamp, 0.0)))
    assert detector.open_since("u1") == 3.0 and detector.open_since("u2") is None
    detector.finish(4.75)
    first, second = detector.freezes
    first.segments = [Segment(first.start, first.end, "true_block", "box there")]
    second.segments = [Segment(second.start, second.end, "phantom", "box gone")]

    class BoxGoneAt2(Truth):
        def is_occupied(self, points, at=None):
            return np.array([at < 2.0] * len(points))

    agents = {"u1": SimpleNamespace(navigator=SimpleNamespace(actions=[]))}
    coord = LaneCoordinator(LaneGraph({"a": (0.0, 0.0), "b": (1.0, 0.0)}, [("a", "b")]))
    records = freeze_records(detector.freezes, agents, coord, BoxGoneAt2(None), evidence, {})
    assert [r.blocking[0].truly_occupied for r in records] == [True, False]
    assert [r.blocking[0].last_observed for r in records] == [0.0, 3.0]
