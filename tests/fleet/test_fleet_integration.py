"""Simulated units post their scans to a real map server on loopback, which fuses them."""

import httpx
import numpy as np
from server_helpers import ServerProcess

from fleet.boxworld import warehouse_layout
from fleet.ground_truth import GroundTruth
from fleet.layout import Layout
from fleet.lidar import LidarConfig
from fleet.localization import PoseNoise
from fleet.poster import ScanPoster
from fleet.sim import FleetSim, UnitSpec
from fleet.world import World
from mapserver.client import MapClient
from mapserver.core.inflation import InflationParams
from mapserver.core.scan import Pose2D


def test_units_post_scans_that_the_map_server_fuses(tmp_path):
    warehouse = warehouse_layout(30.0, 20.0, seed=3, cross_aisle_every_m=10.0)
    x0, x1 = warehouse.lane_x[0], warehouse.lane_x[1]
    y0, y1 = warehouse.lane_y[0], warehouse.lane_y[1]
    lidar = LidarConfig(beams=360, range_noise=0.01)
    specs = [
        UnitSpec("u1", Pose2D(x0, y0, 0.0), lidar=lidar, pose_noise=PoseNoise(std_xy=0.01)),
        UnitSpec("u2", Pose2D(x0, y1, 0.0), lidar=lidar),
    ]
    server = ServerProcess(tmp_path / "data")  # a 30 m x 20 m grid at 0.1 m
    try:
        with (
            httpx.Client(base_url=server.url, timeout=30) as http,
            World(Layout.from_warehouse(warehouse)) as world,
        ):
            client = MapClient(http)
            sim = FleetSim(world, specs, seed=4, poster=ScanPoster(client))
            sim.unit("u1").follow([(x1, y0)])
            sim.unit("u2").follow([(x1, y1)])
            results = [sim.step(0.1) for _ in range(20)]
            acks = [a for r in results for a in r.acks]
            assert len(acks) == 40 and [a.seq for a in acks] == list(range(1, 41))
            meta = client.map_meta()
            assert meta.version == acks[-1].map_version == 40
            assert meta.stamp == sim.time
            # the face of the first rack block, across the staging aisle from u1
            rack = world.obstacle("rack-1").shape.bounds()
            face = (rack[0] + 0.03, (rack[1] + rack[3]) / 2)  # 3 cm inside its left face
            open_floor = (x0, (y0 + y1) / 2 - 1.0)
            cells = client.query_cells([face, open_floor])
            assert [c.state for c in cells] == ["occupied", "free"]
            truth = GroundTruth(world, meta.geometry, InflationParams())
            assert truth.is_occupied(np.array([face, open_floor])).tolist() == [True, False]
    finally:
        server.stop()
