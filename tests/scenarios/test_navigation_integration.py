"""A simulated unit drives to its goal on the shared map, detouring a tote it discovers:
PyBullet world -> scans -> a real map server on loopback -> costmap over HTTP ->
UnitNavigator plans -> the drive unit follows."""

import math

import httpx
from server_helpers import ServerProcess

from fleet.boxworld import warehouse_layout
from fleet.layout import Kind, Layout, Obstacle
from fleet.lidar import LidarConfig
from fleet.poster import ScanPoster
from fleet.shapes import Box
from fleet.sim import FleetSim, UnitSpec
from fleet.world import World
from mapserver.client import MapClient
from mapserver.core.scan import Pose2D
from planner.grid_search import GridPlanner
from planner.navigator import UnitNavigator

DT = 0.1  # [s]
REPLAN_S = 0.5  # [s]


def test_a_unit_detours_around_a_tote_in_its_aisle_and_reaches_its_goal(tmp_path):
    warehouse = warehouse_layout(30.0, 20.0, seed=3, cross_aisle_every_m=10.0)
    y = warehouse.lane_y[0]
    start, goal = (warehouse.lane_x[0], y), (warehouse.lane_x[0] + 12.0, y)
    tote = Obstacle(
        "tote-1", Kind.TOTE, Box.from_bounds(start[0] + 5.7, y - 0.3, start[0] + 6.3, y + 0.3)
    )
    layout = Layout.from_warehouse(warehouse)
    server = ServerProcess(tmp_path / "data")
    try:
        with (
            httpx.Client(base_url=server.url, timeout=30) as http,
            World(layout) as world,
        ):
            world.add(tote)
            client = MapClient(http)
            spec = UnitSpec("u1", Pose2D(*start, 0.0), lidar=LidarConfig(beams=360))
            sim = FleetSim(world, [spec], seed=1, poster=ScanPoster(client))
            meta = client.map_meta()
            nav = UnitNavigator("u1", meta.geometry, GridPlanner(meta.geometry))
            nav.set_route([goal], stamp=0.0)
            costs, last_plan, closest = None, -math.inf, math.inf
            for _ in range(400):
                result = sim.step(DT)
                assert result.collisions == ()
                pose = sim.unit("u1").pose
                closest = min(closest, math.dist((pose.x, pose.y), (start[0] + 6.0, y)))
                costs = client.follow_costmap(costs)
                if sim.time - last_plan >= REPLAN_S:
                    command = nav.step(sim.time, (pose.x, pose.y), costs.data)
                    last_plan = sim.time
                    if command.kind == "idle":
                        break
                    if command.kind == "follow":
                        sim.unit("u1").follow(command.path[1:] or command.path)
            assert math.dist((pose.x, pose.y), goal) <= nav.config.arrive_m
            assert closest > 0.3 + 0.3  # stayed off the tote: its half width + the unit radius
            assert all(action.action != "wait" for action in nav.actions)
    finally:
        server.stop()
