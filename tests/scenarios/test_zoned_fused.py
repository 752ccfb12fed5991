"""``read_zoned_fused``: the zones' journals merged as one server of the site fused them."""

from __future__ import annotations

import warnings
from contextlib import ExitStack

import numpy as np
import pytest
from fastapi.testclient import TestClient
from server_helpers import TEST_SERVER

from mapserver.api.app import create_app
from mapserver.client import MapClient
from mapserver.client.zoned import ZonedMapClient
from mapserver.client.zones import ZoneLayout
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Pose2D, Scan
from mapserver.service.replay import ReplayError
from mapserver.service.settings import load_settings
from scenarios.replay.fused import read_zoned_fused

SITE = GridGeometry(300, 100, 0.1)  # 30 m x 10 m
LAYOUT = ZoneLayout.strips(SITE, 3, 5.0, 0.55)
UNITS = ("a", "b", "c")


def scan(unit: str, stamp: float, x: float) -> Scan:
    ranges = np.full(30, 2.0)
    return Scan(unit, stamp, Pose2D(x, 5.0, 0.0), -np.pi, 2 * np.pi / 30, 0.1, 5.0, ranges)


def zone_dirs(tmp_path, post, policies=("decay",) * 3):
    """Run the three zones' servers in process, ``post(zoned_client)``, stop them; their
    data dirs."""
    dirs = [tmp_path / f"zone-{k}" for k in range(LAYOUT.zones)]
    with ExitStack() as stack, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        clients = []
        for k, (data_dir, policy) in enumerate(zip(dirs, policies, strict=True)):
            g = LAYOUT.geometry(k)
            grid = {"width": g.width, "height": g.height, "resolution": g.resolution,
                    "origin_x": g.origin_x, "origin_y": g.origin_y}  # fmt: skip
            settings = load_settings(
                None, {"data_dir": data_dir, "grid": grid, "policy": policy, "server": TEST_SERVER}
            )
            clients.append(MapClient(stack.enter_context(TestClient(create_app(settings)))))
        with ZonedMapClient(LAYOUT, clients) as zones:
            zones.declare_clock(100.0)
            post(zones)
    return dirs


def test_the_zones_journals_merge_in_posting_order_each_scan_once(tmp_path):
    posted = [
        [scan("a", 1.0, 2.0), scan("b", 1.0, 10.5), scan("c", 1.0, 28.0)],
        [scan("a", 1.5, 15.0), scan("c", 1.5, 20.0)],  # a in every zone, c in two
        [scan("b", 2.0, 12.0)],
    ]
    dirs = zone_dirs(tmp_path, lambda zones: [zones.post_scans(tick) for tick in posted])
    fused = read_zoned_fused(dirs, SITE, UNITS)
    got = list(fused.scans())
    want = [s for tick in posted for s in tick]
    assert [seq for seq, _ in got] == list(range(1, len(want) + 1))
    assert [s.digest() for _, s in got] == [s.digest() for s in want]
    assert fused.settings["grid"] == {
        "width": 300, "height": 100, "resolution": 0.1, "origin_x": 0.0, "origin_y": 0.0
    }  # fmt: skip
    assert fused.settings["policy"] == "decay"


def test_a_journal_out_of_the_fleets_order_is_refused_naming_it(tmp_path):
    # b before a at one stamp: the fleet posts a tick's scans in its units' order
    dirs = zone_dirs(
        tmp_path, lambda zones: zones.post_scans([scan("b", 1.0, 2.0), scan("a", 1.0, 3.0)])
    )
    with pytest.raises(ReplayError, match=r"zone-0.*seq 2 \(unit 'a', stamp 1.0\).*posting order"):
        list(read_zoned_fused(dirs, SITE, UNITS).scans())


def test_a_unit_the_fleet_does_not_have_is_refused(tmp_path):
    dirs = zone_dirs(tmp_path, lambda zones: zones.post_scans([scan("z", 1.0, 2.0)]))
    with pytest.raises(ReplayError, match="seq 1 is unit 'z', not the fleet's"):
        list(read_zoned_fused(dirs, SITE, UNITS).scans())


def test_zones_fused_under_other_settings_are_refused(tmp_path):
    dirs = zone_dirs(tmp_path, lambda zones: None, policies=("decay", "sticky", "decay"))
    with pytest.raises(ReplayError, match="zone-1: its map settings differ from .*zone-0"):
        read_zoned_fused(dirs, SITE, UNITS)
