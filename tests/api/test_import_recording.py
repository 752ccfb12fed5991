"""``fleetmap import``: a bag streamed into a real ``fleetmap serve`` on loopback builds
the room's map on the server; stamps restamped to now are accepted at full speed, and
the same scans again as recorded are refused as conflicts, counted, not fatal."""

import httpx
import numpy as np
import pytest
from recording_helpers import BagSpec, Motion, assert_room_map, room_grid, write_bag

from mapserver.cli.import_cmd import Importer
from mapserver.client.map_client import MapClient
from mapserver.core.belief import CellState
from mapserver.core.scan_binary import decode_scans
from mapserver.service.settings import load_settings
from mapserver.store.recordings import open_recording
from scenarios.cli.main import main
from scenarios.run.embedded_server import EmbeddedServer


@pytest.fixture
def server(tmp_path):
    g = room_grid(0.1)
    grid = {"width": g.width, "height": g.height, "resolution": g.resolution,
            "origin_x": g.origin_x, "origin_y": g.origin_y}  # fmt: skip
    process = EmbeddedServer(tmp_path / "data", {"grid": grid})
    yield process
    process.stop()


def server_states(url: str) -> np.ndarray:
    """The server's map as CellStates, by its own thresholds."""
    thresholds = load_settings(None, {}).sensor_model
    with httpx.Client(base_url=url) as http:
        reply = http.get("/v1/map", params={"format": "raw"})
        reply.raise_for_status()
        shape = int(reply.headers["X-Map-Height"]), int(reply.headers["X-Map-Width"])
    values = np.frombuffer(reply.content, dtype=np.int8).reshape(shape)
    states = np.full(shape, CellState.UNKNOWN, dtype=np.uint8)
    states[(values >= 0) & (values > 100 * thresholds.occupied_threshold)] = CellState.OCCUPIED
    states[(values >= 0) & (values < 100 * thresholds.free_threshold)] = CellState.FREE
    return states


def test_an_imported_bag_builds_the_room_on_the_server(server, tmp_path, capsys):
    path = write_bag(tmp_path / "bag", BagSpec(storage="mcap"))
    code = main(["import", str(path), "--server", server.url, "--rate", "max", "--batch", "7"])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "sent 20 scans, accepted 20, refused 0" in out.out
    assert "sent 20/20 scans (100 %)" in out.err
    assert_room_map(server_states(server.url), room_grid(0.1))

    again = main(["import", str(path), "--server", server.url, "--rate", "max", "--no-restamp"])
    out = capsys.readouterr()
    assert again == 1
    assert "sent 20 scans, accepted 0, refused 20 (20 409 stamp)" in out.out


def test_a_recording_off_the_servers_grid_stops_with_the_servers_message(server, tmp_path, capsys):
    far = Motion(map_odom=(50.0, 50.0, 0.0))
    path = write_bag(tmp_path / "far.bag", BagSpec(storage="ros1", scans=3, motion=far))
    code = main(["import", str(path), "--server", server.url, "--rate", "max"])
    out = capsys.readouterr()
    assert code == 1
    assert "the server stopped the import: POST /v1/scans/batch: HTTP 422" in out.err
    assert "the sensor must be on the map" in out.err
    assert "sent 0 scans, accepted 0" in out.out


def test_throttling_is_waited_out_and_the_pacing_follows_the_recording(tmp_path):

    replies = iter([429, 429] + [200] * 100)
    posted: list[int] = []

    def handler(request: httpx.Request) -> httpx.Response:
        status = next(replies)
        if status == 429:
            return httpx.Response(429, headers={"Retry-After": "3"}, json={"detail": "busy"})
        count = len(decode_scans(request.content, batch=True))
        posted.append(count)
        return httpx.Response(200, json={"acks": [{"seq": 1, "map_version": 1}] * count})

    now = [1000.0]
    waits: list[float] = []

    def sleep(seconds: float) -> None:
        waits.append(seconds)
        now[0] += seconds

    path = write_bag(tmp_path / "bag", BagSpec(storage="mcap", scans=10))
    with httpx.Client(base_url="http://map", transport=httpx.MockTransport(handler)) as http:
        client = MapClient(http, retries=0, sleep=sleep)
        importer = Importer(client, rate=1.0, batch=50, clock=lambda: now[0], sleep=sleep)
        importer.run(open_recording(path), lambda done, total: None)
    summary = importer.summary
    assert (summary.sent, summary.accepted, summary.throttled) == (10, 10, 2)
    assert summary.first_stamp == 1000.0  # restamped: the first scan now
    # At rate 1 the first scan goes at once (throttled twice: 2 s on the fake clock); by
    # then the other nine, 0.1 s apart, are all due and go as one batch.
    assert posted == [1, 9] and waits == [1.0, 1.0] and now[0] == 1002.0
