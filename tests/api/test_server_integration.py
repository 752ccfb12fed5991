"""A real ``fleetmap serve`` (uvicorn) on 127.0.0.1, started and stopped by each test."""

import json
import threading

import httpx
import numpy as np
import pytest
from server_helpers import JSON, ServerProcess

from fleet.boxworld import sample_scans, warehouse_layout


@pytest.fixture(scope="module")
def scans():
    """Warehouse scans inside the 30 m x 20 m test grid, as JSON bodies."""
    warehouse = warehouse_layout(30.0, 20.0, seed=3, cross_aisle_every_m=10.0)
    return [s.to_dict() for s in sample_scans(warehouse, 300, beams=360, seed=3, units=3)]


def raw(url: str, path: str, at: float) -> bytes:
    reply = httpx.get(url + path, params={"format": "raw", "at": at}, timeout=30)
    reply.raise_for_status()
    return reply.content


def test_a_real_server_fuses_posted_scans_and_serves_them(tmp_path, scans):
    server = ServerProcess(tmp_path / "data")
    try:
        with httpx.Client(base_url=server.url, timeout=10, headers=JSON) as http:
            acks = [http.post("/v1/scans", content=json.dumps(body)).json() for body in scans[:20]]
            assert [a["seq"] for a in acks] == list(range(1, 21))
            meta = http.get("/v1/map/meta").json()
            assert meta["version"] == 20 and meta["width"] == 300
            costs = np.frombuffer(http.get("/v1/costmap?format=raw").content, np.uint8)
            assert costs.size == 300 * 200 and np.any(costs == 254) and np.any(costs == 0)
    finally:
        server.stop()


def test_a_restart_on_the_same_data_dir_restores_the_map(tmp_path, scans):
    data = tmp_path / "data"
    server = ServerProcess(data)
    try:
        for body in scans[:30]:
            httpx.post(
                server.url + "/v1/scans", content=json.dumps(body), timeout=10, headers=JSON
            ).raise_for_status()
        before = raw(server.url, "/v1/costmap", 100.0)
    finally:
        server.stop()
    server = ServerProcess(data)
    try:
        assert raw(server.url, "/v1/costmap", 100.0) == before
        assert httpx.get(server.url + "/v1/map/meta").json()["version"] == 30
        # the restarted server still refuses a unit's stamp going backwards
        old = dict(scans[0])
        assert (
            httpx.post(server.url + "/v1/scans", content=json.dumps(old), headers=JSON).status_code
            == 409
        )
    finally:
        server.stop()


def test_sigkill_loses_no_acknowledged_scan_and_restarts_to_the_same_map(tmp_path, scans):
    data = tmp_path / "data"
    server = ServerProcess(data)
    acked: list[int] = []
    stop = threading.Event()

    def post_until_killed():
        with httpx.Client(base_url=server.url, timeout=10, headers=JSON) as http:
            for body in scans:
                if stop.is_set():
                    return
                try:
                    reply = http.post("/v1/scans", content=json.dumps(body))
                except httpx.HTTPError:
                    return  # the server died mid-request: this scan was never acknowledged
                if reply.status_code == 200:
                    acked.append(reply.json()["seq"])

    poster = threading.Thread(target=post_until_killed)
    poster.start()
    while len(acked) < 60 and poster.is_alive():
        threading.Event().wait(0.01)
    server.kill()
    stop.set()
    poster.join()
    assert len(acked) >= 60

    restarted = ServerProcess(data)
    fresh = ServerProcess(tmp_path / "fresh")
    try:
        version = httpx.get(restarted.url + "/v1/map/meta").json()["version"]
        assert version >= max(acked)  # every acknowledged scan is in the map
        # Feed a fresh server exactly the scans the restarted one holds, in journal order.
        with httpx.Client(base_url=fresh.url, timeout=10, headers=JSON) as http:
            for body in scans[:version]:
                assert http.post("/v1/scans", content=json.dumps(body)).status_code == 200
        at = max(body["stamp"] for body in scans[:version]) + 1.0
        for path in ("/v1/costmap", "/v1/map"):
            assert raw(restarted.url, path, at) == raw(fresh.url, path, at)
    finally:
        restarted.stop()
        fresh.stop()
