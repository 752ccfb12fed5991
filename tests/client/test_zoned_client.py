"""``ZonedMapClient`` against one server of the whole site, both fed the same scans.

The zones' servers and the one server are real apps (``create_app``) in process; the
scans are random, with their sensors near the cuts, where the borders matter.
"""

from __future__ import annotations

import warnings
from contextlib import ExitStack

import numpy as np
import pytest
from fastapi.testclient import TestClient

from mapserver.api.app import create_app
from mapserver.client import MapClient
from mapserver.client.zoned import ZonedMapClient
from mapserver.client.zones import ZoneLayout
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams
from mapserver.core.scan import Pose2D, Scan
from mapserver.service.settings import load_settings
from tests.server_helpers import TEST_SERVER

SITE = GridGeometry(300, 100, 0.1)  # 30 m x 10 m
RANGE_M = 5.0
INFLATION_M = InflationParams().inflation_radius


@pytest.fixture
def servers(tmp_path):
    """``make(geometry, policy)``: a ``MapClient`` of a new in-process server."""
    with ExitStack() as stack:
        made = []

        def make(geometry: GridGeometry, policy: str) -> MapClient:
            grid = {
                "width": geometry.width,
                "height": geometry.height,
                "resolution": geometry.resolution,
                "origin_x": geometry.origin_x,
                "origin_y": geometry.origin_y,
            }
            settings = load_settings(
                None,
                {
                    "data_dir": tmp_path / f"server-{len(made)}",
                    "policy": policy,
                    "grid": grid,
                    "server": TEST_SERVER,
                },
            )
            http = stack.enter_context(TestClient(create_app(settings)))
            made.append(http)
            return MapClient(http)

        yield make


def zoned(make, layout: ZoneLayout, policy: str) -> ZonedMapClient:
    clients = [make(layout.geometry(k), policy) for k in range(layout.zones)]
    return ZonedMapClient(layout, clients)


def border_scans(rng: np.random.Generator, layout: ZoneLayout, tick: int, units: int = 4):
    """``units`` scans at stamp ``1 + tick / 2``, each sensor within the LiDAR's reach
    plus a metre of a cut, 90 beams over a full turn, some no-return and invalid."""
    cuts_m = [c * SITE.resolution for c in layout.cuts[1:-1]]
    scans = []
    for u in range(units):
        x = float(np.clip(rng.choice(cuts_m) + rng.uniform(-RANGE_M - 1, RANGE_M + 1), 0, 29.99))
        ranges = rng.uniform(0.3, RANGE_M * 1.1, 90).astype(np.float32).astype(np.float64)
        ranges[rng.random(90) < 0.1] = np.nan
        pose = Pose2D(x, float(rng.uniform(0.5, 9.5)), float(rng.uniform(-np.pi, np.pi)))
        scans.append(
            Scan(f"u{u}", 1.0 + tick / 2, pose, -np.pi, 2 * np.pi / 90, 0.1, RANGE_M, ranges)
        )
    return scans


def differing_cells(one: MapClient, zones: ZonedMapClient, seed: int, ticks: int) -> list[int]:
    """Post the same scans to both, tick by tick; after each tick the number of cells in
    which the costmaps and the occupancy grids differ (summed), and check each read's
    site geometry and stamp."""
    rng = np.random.default_rng(seed)
    one.declare_clock(100.0)
    zones.declare_clock(100.0)
    out = []
    for tick in range(ticks):
        scans = border_scans(rng, zones.layout, tick)
        assert len(zones.post_scans(scans)) == len(one.post_scans(scans)) == len(scans)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reads = [(one.costmap(), zones.costmap()), (one.occupancy(), zones.occupancy())]
        for mine, stitched in reads:
            assert stitched.geometry == SITE and stitched.stamp == mine.stamp
        out.append(sum(int(np.count_nonzero(a.data != b.data)) for a, b in reads))
    return out


@pytest.mark.parametrize("policy", ["decay", "binary", "sticky", "dual"])
def test_stitched_zones_equal_one_server_of_the_site_cell_for_cell(servers, policy):
    layout = ZoneLayout.strips(SITE, 3, RANGE_M, INFLATION_M)
    with zoned(servers, layout, policy) as zones:
        assert differing_cells(servers(SITE, policy), zones, seed=7, ticks=12) == [0] * 12


def test_a_border_short_of_the_lidar_reach_loses_evidence_the_test_would_see(servers):
    """The check above can fail: zones that take only scans from sensors within 2 m of
    their band (the LiDAR reaches 5 m) miss what the others saw."""
    full = ZoneLayout.strips(SITE, 3, RANGE_M, INFLATION_M)
    short = ZoneLayout(SITE, full.cuts, 2.0, full.margin_cells, full.border_cells)
    with zoned(servers, short, "decay") as zones:
        assert sum(differing_cells(servers(SITE, "decay"), zones, seed=7, ticks=12)) > 0


@pytest.mark.parametrize("margin", [True, False])
def test_the_margin_carries_the_inflation_of_a_wall_beside_the_cut(servers, margin):
    """A wall 0.4 m before the cut at 10 m, seen from 5 m away (x = 4.6 m), and the floor
    past the cut seen free from (10.05, 8) m looking down: zone 1 needs the wall
    to inflate its first columns, and takes its scans only with the inflation margin
    (its band then starts at 9.4 m, reached from 4.3 m)."""
    full = ZoneLayout.strips(SITE, 3, RANGE_M, INFLATION_M)
    layout = full if margin else ZoneLayout(SITE, full.cuts, full.reach_m, 0, full.border_cells)
    one = servers(SITE, "decay")
    with zoned(servers, layout, "decay") as zones:
        for client in (one, zones):
            client.declare_clock(100.0)
            for stamp in (1.0, 2.0, 3.0):
                wall = Scan(
                    "u", stamp, Pose2D(4.6, 5.0, 0.0), -0.1, 0.01, 0.1, 6.0, np.full(21, 5.0)
                )
                down = Pose2D(10.05, 8.0, -np.pi / 2)
                floor = Scan("v", stamp, down, -0.1, 0.01, 0.1, 6.5, np.full(21, 6.0))
                client.post_scans([wall, floor])
        mine, stitched = one.costmap(), zones.costmap()
        assert mine.data[50, 96] == 254  # the wall, lethal
        assert 0 < mine.data[50, 100] < 254  # the first column past the cut, inflated
        same = np.array_equal(mine.data, stitched.data)
        assert same == margin
        if not margin:
            assert stitched.data[50, 100] == 0  # zone 1 never saw the wall: free


def test_a_lagging_zone_is_read_at_the_newest_stamp(servers):
    """A zone no scan reached since stamp 1 is evaluated at the site's newest stamp,
    as one server's cells are: both reads say stamp 60 and agree."""
    layout = ZoneLayout.strips(SITE, 3, RANGE_M, INFLATION_M)
    one = servers(SITE, "decay")
    with zoned(servers, layout, "decay") as zones:
        for client in (one, zones):
            client.declare_clock(100.0)
        ranges = np.full(90, 2.0)
        early = Scan("a", 1.0, Pose2D(2.0, 5.0, 0.0), -np.pi, 2 * np.pi / 90, 0.1, 5.0, ranges)
        late = Scan("b", 60.0, Pose2D(28.0, 5.0, 0.0), -np.pi, 2 * np.pi / 90, 0.1, 5.0, ranges)
        for scans in ([early], [late]):
            one.post_scans(scans)
            zones.post_scans(scans)
        assert [m.stamp for m in map(MapClient.map_meta, zones.clients)] == [1.0, None, 60.0]
        mine, stitched = one.occupancy(), zones.occupancy()
        assert stitched.stamp == mine.stamp == 60.0
        np.testing.assert_array_equal(stitched.data, mine.data)
        lagging = zones.clients[0]  # its own now would show the early scan's cells fresher
        assert np.any(lagging.occupancy().data != lagging.occupancy(60.0).data)


def test_each_scan_gets_its_home_zones_ack_and_reaches_every_zone_it_can_observe(servers):
    layout = ZoneLayout.strips(SITE, 3, RANGE_M, INFLATION_M)
    with zoned(servers, layout, "decay") as zones:
        zones.declare_clock(100.0)
        ranges = np.full(90, 1.0)
        scans = [
            Scan(f"u{i}", 1.0, Pose2D(x, 5.0, 0.0), -np.pi, 2 * np.pi / 90, 0.1, 5.0, ranges)
            for i, x in enumerate([1.0, 10.5, 15.0, 29.0])
        ]
        acks = zones.post_scans(scans)
        versions = [m.version for m in map(MapClient.map_meta, zones.clients)]
        # exact bands (the cores plus 0.6 m) [-0.6, 10.6], [9.4, 20.6], [19.4, 30.6] m,
        # reached from 5.1 m: zone 0 takes x <= 15.7 (u0, u1, u2), zone 1 x in
        # [4.3, 25.7] (u1, u2), zone 2 x >= 14.3 (u2, u3); homes 0, 1, 1, 2
        assert versions == [3, 2, 2]
        assert [a.seq for a in acks] == [1, 1, 2, 2]
        assert zones.map_meta().version == 7 and zones.map_meta().geometry == SITE


def test_a_sensor_off_the_site_is_refused_by_its_home_zone_naming_the_pose(servers):
    layout = ZoneLayout.strips(SITE, 3, RANGE_M, INFLATION_M)
    with zoned(servers, layout, "decay") as zones:
        zones.declare_clock(100.0)
        off = Scan("u", 1.0, Pose2D(-30.0, 5.0, 0.0), 0.0, 0.1, 0.1, 5.0, np.full(3, 1.0))
        with pytest.raises(Exception, match="pose") as caught:
            zones.post_scans([off])
        assert getattr(caught.value, "status", None) == 422
        assert [m.version for m in map(MapClient.map_meta, zones.clients)] == [0, 0, 0]


def test_a_scan_given_as_a_dict_without_a_pose_is_refused_before_anything_is_sent(servers):
    layout = ZoneLayout.strips(SITE, 3, RANGE_M, INFLATION_M)
    with zoned(servers, layout, "decay") as zones:
        with pytest.raises(ValueError, match=r"scans\[0\]\.pose\.x"):
            zones.post_scans([{"unit_id": "u", "stamp": 1.0}])
        assert [m.version for m in map(MapClient.map_meta, zones.clients)] == [0, 0, 0]


def test_segment_queries_on_the_stitched_costmap_answer_as_one_server_does(servers):
    """Lanes read through the zones (``coordination.lanes_from: server``): each segment,
    across a cut or inside a strip, gets the reading one server of the site replies."""
    layout = ZoneLayout.strips(SITE, 3, RANGE_M, INFLATION_M)
    one = servers(SITE, "decay")
    with zoned(servers, layout, "decay") as zones:
        rng = np.random.default_rng(3)
        one.declare_clock(100.0)
        zones.declare_clock(100.0)
        for tick in range(4):
            scans = border_scans(rng, layout, tick)
            one.post_scans(scans)
            zones.post_scans(scans)
        segments = [(1.0, 5.0, 29.0, 5.0), (8.0, 2.0, 12.0, 8.0), (21.0, 1.0, 21.0, 9.0),
                    (9.95, 5.0, 10.05, 5.0), (15.0, 5.0, 15.0, 5.0)]  # fmt: skip
        mine = one.query_segments(segments)
        zoned_readings = zones.query_segments(segments)
        assert any(r.blocked for r in mine) and any(not r.blocked for r in mine)
        for server, stitched in zip(mine, zoned_readings, strict=True):
            assert stitched.max_cost == server.max_cost
            assert stitched.blocked == server.blocked
            assert stitched.unknown_fraction == pytest.approx(server.unknown_fraction, abs=1e-12)
            want = None if server.first_blocked is None else tuple(server.first_blocked)
            assert stitched.first_blocked == (
                None if want is None else pytest.approx(want, abs=1e-12)
            )
