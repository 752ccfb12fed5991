"""``POST /v1/plan`` with a static map: landmark tables on the static lower bound, built
once and kept while scans change the costmap, and plans as cheap as without them."""

import numpy as np
import pytest
from fastapi.testclient import TestClient
from server_helpers import scan_body, small_settings

from mapserver.api.app import create_app
from mapserver.core.geometry import GridGeometry
from mapserver.store.mapfiles import write_ros_map
from planner.grid_search import GridPlanner, cell_weights

GEOMETRY = GridGeometry(200, 100, 0.1, 0.0, 0.0)  # server_helpers.GRID, 20 m x 10 m


def static_occupancy() -> np.ndarray:
    """Two rack rows (occupied), an unmapped corner (unknown), free floor elsewhere."""
    occupancy = np.zeros(GEOMETRY.shape, dtype=np.int8)
    occupancy[30:34, 20:90] = 100
    occupancy[66:70, 110:180] = 100
    occupancy[80:, 150:] = -1
    return occupancy


@pytest.fixture
def mapped_client(tmp_path):
    map_yaml = write_ros_map(tmp_path / "site", static_occupancy(), GEOMETRY)
    app = create_app(small_settings(tmp_path / "data", map_yaml=str(map_yaml)))
    with TestClient(app) as client:
        yield client


def costmap(client) -> np.ndarray:
    reply = client.get("/v1/costmap", params={"format": "raw"})
    return np.frombuffer(reply.content, np.uint8).reshape(GEOMETRY.shape)


def plan(client, start, goal) -> dict:
    reply = client.post("/v1/plan", json={"start": start, "goal": goal})
    assert reply.status_code == 200, reply.text
    return reply.json()


def test_the_static_lower_bound_stays_below_the_costmap_as_scans_change_it(mapped_client):
    bound = mapped_client.app.state.service.planning_bounds
    for allow_unknown in (True, False):
        weights = cell_weights(allow_unknown)
        assert np.all(weights[bound] <= weights[costmap(mapped_client)])
    for i in range(3):  # a wall of returns at x = 8 m, seen from (5, 5), and free floor
        mapped_client.post("/v1/scans", json=scan_body(stamp=float(i)))
    live = costmap(mapped_client)
    assert (live != bound).any()  # the scans changed the costmap above the bound
    for allow_unknown in (True, False):
        weights = cell_weights(allow_unknown)
        assert np.all(weights[bound] <= weights[live])


def test_plans_use_tables_built_once_and_cost_what_plans_without_them_cost(mapped_client):
    start, goal = [1.0, 1.0], [19.0, 9.0]
    bare = GridPlanner(GEOMETRY)
    first = plan(mapped_client, start, goal)
    assert first["cost"] == pytest.approx(bare.plan(costmap(mapped_client), start, goal).cost)
    for i in range(3):  # scans put a wall across the way at x = 8 m
        mapped_client.post("/v1/scans", json=scan_body(stamp=float(i)))
    second = plan(mapped_client, start, goal)
    expected = bare.plan(costmap(mapped_client), start, goal)
    assert second["found"] and second["map_version"] == 3
    assert second["cost"] == pytest.approx(expected.cost, rel=1e-9)
    assert second["expanded"] <= expected.expanded
    planner = mapped_client.app.state.planner._planner
    assert planner.landmarks.count == 6  # reads.plan_landmarks' default
    assert (planner.landmarks.builds, planner.bounded_plans) == (1, 2)


def test_without_a_static_map_plans_use_no_landmarks(tmp_path):
    with TestClient(create_app(small_settings(tmp_path / "data"))) as client:
        assert client.app.state.service.planning_bounds is None
        assert plan(client, [1.0, 1.0], [19.0, 9.0])["found"]
        assert client.app.state.planner._planner.landmarks.count == 0


def test_plan_landmarks_zero_turns_them_off(tmp_path):
    map_yaml = write_ros_map(tmp_path / "site", static_occupancy(), GEOMETRY)
    settings = small_settings(
        tmp_path / "data", map_yaml=str(map_yaml), reads={"plan_landmarks": 0}
    )
    with TestClient(create_app(settings)) as client:
        assert plan(client, [1.0, 1.0], [19.0, 9.0])["found"]
        assert client.app.state.planner._planner.landmarks.builds == 0
