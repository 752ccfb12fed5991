"""The lane graph: built from a warehouse layout, routed on, weighted from the costmap."""

import math

import networkx as nx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import given, settings
from hypothesis import strategies as st
from lane_helpers import FakeMap, grid_graph
from server_helpers import scan_body, small_settings

from fleet.boxworld import BoxWorld, Warehouse, warehouse_layout
from mapserver.api.app import create_app
from mapserver.client import MapClient
from planner.lane_graph import LaneGraph, lane_key


@pytest.fixture(scope="module")
def warehouse():
    return warehouse_layout()


def test_a_warehouse_gives_one_junction_per_lane_crossing(warehouse):
    g = LaneGraph.from_warehouse(warehouse)
    nx_, ny_ = len(warehouse.lane_x), len(warehouse.lane_y)
    assert len(g.nodes) == nx_ * ny_
    for ix, x in enumerate(warehouse.lane_x):
        for iy, y in enumerate(warehouse.lane_y):
            assert g.position(f"j{ix}_{iy}") == (x, y)
            assert g.graph.nodes[f"j{ix}_{iy}"]["kind"] == "junction"
    # Each junction joins its grid neighbours, both ways, and nothing else.
    assert len(g.lanes) == (nx_ - 1) * ny_ + nx_ * (ny_ - 1)
    assert g.graph.number_of_edges() == 2 * len(g.lanes)
    assert set(g.graph.successors("j1_1")) == {"j0_1", "j2_1", "j1_0", "j1_2"}
    assert set(g.graph.successors("j0_0")) == {"j1_0", "j0_1"}
    assert nx.is_strongly_connected(g.graph)
    d = g.graph.edges["j0_0", "j1_0"]
    assert d["length"] == pytest.approx(warehouse.lane_x[1] - warehouse.lane_x[0])
    assert (d["weight"], d["blocked"], d["penalty"]) == (d["length"], False, 0.0)


def test_every_lane_runs_clear_of_the_racks(warehouse):
    g = LaneGraph.from_warehouse(warehouse, segment_m=5.0)
    for a, b in g.lanes:
        (ax, ay), (bx, by) = g.position(a), g.position(b)
        t = np.linspace(0.0, 1.0, 50)
        assert warehouse.world.is_free(ax + (bx - ax) * t, ay + (by - ay) * t, 1.0).all()


def test_one_way_lanes_are_driven_one_way_only(warehouse):
    g = LaneGraph.from_warehouse(warehouse, one_way=[("j0_0", "j1_0")])
    assert g.graph.has_edge("j0_0", "j1_0") and not g.graph.has_edge("j1_0", "j0_0")
    assert g.shortest_route("j0_0", "j1_0") == ["j0_0", "j1_0"]
    back = g.shortest_route("j1_0", "j0_0")
    assert back[0] == "j1_0" and back[-1] == "j0_0" and len(back) > 2
    assert nx.is_strongly_connected(g.graph)


def test_stations_and_waypoints_split_lanes_and_inherit_one_way(warehouse):
    x0, x1, y0 = warehouse.lane_x[0], warehouse.lane_x[1], warehouse.lane_y[0]
    station = (x0 + 7.0, y0 + 0.4)  # beside the staging aisle, 0.4 m off its centre line
    g = LaneGraph.from_warehouse(
        warehouse, stations={"S1": station}, one_way=[("j1_0", "j0_0")], segment_m=5.0
    )
    assert g.position("S1") == pytest.approx((x0 + 7.0, y0))
    assert g.graph.nodes["S1"]["kind"] == "station"
    assert not g.graph.has_edge("j1_0", "j0_0")  # the stretch is split ...
    route = g.shortest_route("j1_0", "j0_0")
    assert "S1" in route and all(n.startswith("w0_0h") for n in route[1:-1] if n != "S1")
    assert g.route_length(route) == pytest.approx(x1 - x0)  # ... without changing its length
    assert all(
        g.graph.edges[e]["length"] <= 5.0 + 1e-9 for e in zip(route, route[1:], strict=False)
    )
    for u, v in zip(
        route, route[1:], strict=False
    ):  # ... and every piece keeps the one-way direction
        assert not g.graph.has_edge(v, u)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"one_way": [("j0_0", "j2_0")]}, "one_way pair \\('j0_0', 'j2_0'\\)"),
        ({"one_way": [("j0_0", "j1_0"), ("j1_0", "j0_0")]}, "both directions"),
        ({"stations": {"S": (50.0, 7.3)}}, "stations\\['S'\\]"),
        ({"stations": {"j0_0": (5.0, 4.83)}}, "station id 'j0_0'"),
        ({"segment_m": -1.0}, "segment_m must be a positive number of metres, got -1.0"),
        ({"cost_factor": -1.0}, "cost_factor"),
    ],
)
def test_bad_layout_options_are_refused_by_name(warehouse, kwargs, message):
    with pytest.raises(ValueError, match=message):
        LaneGraph.from_warehouse(warehouse, **kwargs)


def test_bad_nodes_are_refused_by_name():
    g = grid_graph(2, 2)
    with pytest.raises(ValueError, match="b 'nowhere' is not a node"):
        g.shortest_route("n0_0", "nowhere")
    with pytest.raises(ValueError, match="lane \\('a', 'a'\\)"):
        LaneGraph({"a": (0.0, 0.0)}, [("a", "a")])
    with pytest.raises(ValueError, match="zero length"):
        LaneGraph({"a": (0.0, 0.0), "b": (0.0, 0.0)}, [("a", "b")])


def test_nearest_node_breaks_ties_by_id():
    g = grid_graph(3, 3)
    assert g.nearest_node(3.2, 5.9) == "n1_2"
    assert g.nearest_node(1.5, 0.0) == "n0_0"  # halfway between n0_0 and n1_0


def nearest_free_by_scan(g: LaneGraph, x: float, y: float, taken) -> str | None:
    """The reference: every free node's ``math.dist``, ties to the smallest id."""
    free = [n for n in g.nodes if n not in taken]
    return min(free, key=lambda n: (math.dist(g.position(n), (x, y)), n), default=None)


@given(
    st.integers(1, 6),
    st.integers(1, 6),
    st.floats(-3, 20),
    st.floats(-3, 20),
    st.sets(st.tuples(st.integers(0, 5), st.integers(0, 5))),
)
@settings(max_examples=300, deadline=None)
def test_nearest_free_node_is_the_nearest_by_math_dist_ties_to_the_smallest_id(
    nx_, ny_, x, y, taken_cells
):
    g = grid_graph(nx_, ny_)  # nodes 3 m apart: many exact ties on the grid's lines
    taken = {f"n{i}_{j}" for i, j in taken_cells} | {"not-a-node"}
    for px, py in ((x, y), (round(x / 1.5) * 1.5, round(y / 1.5) * 1.5)):
        assert g.nearest_free_node(px, py, taken) == nearest_free_by_scan(g, px, py, taken)


def test_nearest_free_node_is_none_when_every_node_is_taken():
    g = grid_graph(2, 2)
    assert g.nearest_free_node(0.0, 0.0, set(g.nodes)) is None
    assert g.nearest_free_node(0.0, 0.0, set()) == "n0_0"
    with pytest.raises(ValueError, match="finite"):
        g.nearest_free_node(math.nan, 0.0, set())


def test_refresh_reads_every_lane_both_ways_in_one_query():
    g = grid_graph(3, 2)
    fake = FakeMap()
    g.refresh(fake)
    assert len(fake.calls) == 1
    sent = fake.calls[0]
    assert len(sent) == 2 * len(g.lanes)
    for k, (a, b) in enumerate(g.lanes):
        assert sent[2 * k] == (*g.position(a), *g.position(b))
        assert sent[2 * k + 1] == (*g.position(b), *g.position(a))


def test_refresh_weights_lanes_by_the_documented_rule():
    g = grid_graph(3, 2, cost_factor=2.0, unknown_factor=0.5)
    fake = FakeMap()
    fake.set_reading((0.0, 0.0), (3.0, 0.0), 126, 0.0)  # half the graded band
    fake.set_reading((3.0, 0.0), (6.0, 0.0), None, 1.0)  # never seen
    fake.set_reading((0.0, 0.0), (0.0, 3.0), 252, 0.4)  # full graded cost, partly unknown
    changes = g.refresh(fake)
    assert changes.blocked == () and changes.cleared == () and g.version == 1
    weight = {lane: g.graph.edges[lane]["weight"] for lane in g.lanes}
    assert weight[("n0_0", "n1_0")] == pytest.approx(3.0 * (1 + 2.0 * 126 / 252))
    assert weight[("n1_0", "n2_0")] == pytest.approx(3.0 * (1 + 0.5 * 1.0))
    assert weight[("n0_0", "n0_1")] == pytest.approx(3.0 * (1 + 2.0 + 0.5 * 0.4))
    assert weight[("n1_0", "n1_1")] == 3.0
    for u, v in g.graph.edges:  # both directions, penalty = what the costmap adds
        d = g.graph.edges[u, v]
        assert d["weight"] == weight[lane_key(u, v)] and d["penalty"] == d["weight"] - 3.0
    assert g.graph.edges["n1_0", "n2_0"]["max_cost"] is None
    g.refresh(fake)
    assert g.version == 1  # nothing changed


def test_refresh_blocks_lanes_and_reports_changes_and_spans():
    g = grid_graph(3, 3)
    fake = FakeMap()
    fake.obstacles = [(3.0, 0.9), (3.0, 1.8)]  # on lane n1_0-n1_1, 0.9 to 1.8 m up it
    changes = g.refresh(fake)
    assert changes.blocked == (("n1_0", "n1_1"),) and changes.cleared == ()
    up, down = g.graph.edges["n1_0", "n1_1"], g.graph.edges["n1_1", "n1_0"]
    assert up["blocked"] and down["blocked"]
    assert up["block_span"] == pytest.approx((0.9, 1.8))
    assert down["block_span"] == pytest.approx((1.2, 2.1))  # seen from n1_1
    assert g.is_blocked("n1_1", "n1_0") and not g.is_blocked("n0_0", "n1_0")
    assert g.graph.edges["n0_0", "n1_0"]["block_span"] is None
    fake.obstacles = []
    changes = g.refresh(fake)
    assert changes.blocked == () and changes.cleared == (("n1_0", "n1_1"),)
    assert not up["blocked"] and up["block_span"] is None


def test_shortest_route_avoids_blocked_and_costly_lanes():
    g = grid_graph(3, 3)
    assert g.shortest_route("n1_0", "n1_2") == ["n1_0", "n1_1", "n1_2"]
    fake = FakeMap()
    fake.obstacles = [(3.0, 1.5)]
    g.refresh(fake)
    route = g.shortest_route("n1_0", "n1_2")
    assert route is not None and ("n1_0", "n1_1") not in zip(route, route[1:], strict=False)
    assert g.route_length(route) == pytest.approx(12.0)
    fake.obstacles = []
    fake.set_reading((3.0, 3.0), (3.0, 6.0), 252, 0.0)  # the direct way costs double now
    g.refresh(fake)
    assert g.shortest_route("n1_0", "n1_2") == ["n1_0", "n1_1", "n1_2"]  # 9 < 12
    fake.set_reading((3.0, 0.0), (3.0, 3.0), 252, 1.0)  # ... and now triple on its first lane
    g.refresh(fake)
    assert g.route_length(g.shortest_route("n1_0", "n1_2")) == pytest.approx(12.0)
    fake.obstacles = [(0.0, 1.5), (3.0, 1.5), (6.0, 1.5)]  # cut the grid in two
    g.refresh(fake)
    assert g.shortest_route("n1_0", "n1_2") is None
    assert g.shortest_route("n0_0", "n2_0") == ["n0_0", "n1_0", "n2_0"]


def test_avoid_edges_and_nodes_route_around_them_but_never_around_the_goal():
    g = grid_graph(3, 1)
    assert g.shortest_route("n0_0", "n2_0", avoid_nodes={"n1_0"}) is None
    assert g.shortest_route("n0_0", "n1_0", avoid_nodes={"n1_0"}) == ["n0_0", "n1_0"]
    assert g.shortest_route("n0_0", "n1_0", avoid_edges={("n0_0", "n1_0")}) is None


def test_refresh_through_the_map_server(tmp_path):
    """A real MapClient over the FastAPI app: one scan's wall blocks the lane it crosses."""
    nodes = {"a": (2.0, 2.0), "b": (8.05, 2.0), "c": (8.05, 8.0), "d": (2.0, 8.0)}
    g = LaneGraph(nodes, [("a", "b"), ("b", "c"), ("c", "d"), ("d", "a")])
    with TestClient(create_app(small_settings(tmp_path / "data"))) as http:
        http.post("/v1/scans", json=scan_body()).raise_for_status()  # hits 3 m east of (5, 5)
        changes = g.refresh(MapClient(http))
    assert changes.blocked == (("b", "c"),)
    near, far = g.graph.edges["b", "c"]["block_span"]
    assert 1.0 < near < 3.0 < far < 5.0  # the wall (and its inscribed band) crosses y = 5
    d = g.graph.edges["a", "d"]  # never observed: unknown, passable, weighted double
    assert (d["blocked"], d["unknown"], d["max_cost"]) == (False, 1.0, None)
    assert d["weight"] == pytest.approx(2 * d["length"])
    assert g.shortest_route("b", "c") == ["b", "a", "d", "c"]


def test_a_custom_warehouse_with_two_lines_each_way():
    w = Warehouse(BoxWorld(np.zeros((0, 4))), 10.0, 10.0, (1.0, 9.0), (1.0, 9.0))
    g = LaneGraph.from_warehouse(w, segment_m=3.0)
    assert len(g.lanes) == 4 * 3  # four 8 m stretches in three pieces each
    assert math.isclose(g.route_length(g.shortest_route("j0_0", "j1_1")), 16.0)


def test_corridors_chain_the_waypoints_and_stations_of_one_stretch(warehouse):
    x0, y0 = warehouse.lane_x[0], warehouse.lane_y[0]
    g = LaneGraph.from_warehouse(warehouse, stations={"S1": (x0 + 7.0, y0)}, segment_m=5.0)
    first = g.corridors[g.graph.edges["j0_0", "w0_0h1"]["corridor"]]
    assert first[0] == "j0_0" and first[-1] == "j1_0" and "S1" in first
    assert all(n.startswith(("w0_0h", "S")) for n in first[1:-1])
    for u, v in zip(first, first[1:], strict=False):  # one corridor, +1 along its order
        assert g.graph.edges[u, v]["heading"] == 1 and g.graph.edges[v, u]["heading"] == -1
    assert g.corridors[g.graph.edges["j0_0", "j0_1"]["corridor"]] == ("j0_0", "j0_1")
    assert {"j0_0", "j1_0"} <= g.corridor_ends and "S1" not in g.corridor_ends
    assert sum(len(c) - 1 for c in g.corridors) == len(g.lanes)  # every lane in one corridor


@pytest.mark.parametrize(("n_x", "n_y"), [(2, 2), (3, 2), (2, 5), (6, 9), (7, 4)])
def test_one_way_aisles_turn_every_row_one_way_alternating_and_keep_columns_two_way(n_x, n_y):
    import networkx as nx

    from planner.lane_graph import one_way_aisles

    pairs = one_way_aisles(n_x, n_y)
    assert len(pairs) == (n_x - 1) * n_y  # every row stretch once, no column stretch
    for a, b in pairs:
        (ax, ay), (bx, by) = (tuple(map(int, n[1:].split("_"))) for n in (a, b))
        assert ay == by and abs(bx - ax) == 1
        assert (bx > ax) == (ay % 2 == 0)  # the bottom row east, then alternating
    g = nx.DiGraph(pairs)
    for ix in range(n_x):  # the columns both ways
        for iy in range(n_y - 1):
            g.add_edge(f"j{ix}_{iy}", f"j{ix}_{iy + 1}")
            g.add_edge(f"j{ix}_{iy + 1}", f"j{ix}_{iy}")
    assert nx.is_strongly_connected(g)


def test_one_way_aisles_need_two_junctions_each_way():
    from planner.lane_graph import one_way_aisles

    with pytest.raises(ValueError, match="at least 2 x 2 junctions, got 1 x 3"):
        one_way_aisles(1, 3)


@pytest.mark.parametrize(("n_x", "n_y"), [(2, 2), (3, 2), (2, 5), (6, 9), (7, 4)])
def test_one_way_loops_are_strongly_connected_with_every_stretch_one_way(n_x, n_y):
    import networkx as nx

    from planner.lane_graph import one_way_loops

    pairs = one_way_loops(n_x, n_y)
    assert len(pairs) == (n_x - 1) * n_y + n_x * (n_y - 1)  # every stretch, once
    assert len({tuple(sorted(p)) for p in pairs}) == len(pairs)
    assert nx.is_strongly_connected(nx.DiGraph(pairs))
