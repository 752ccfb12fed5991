"""Posting scans through MapClient: batches in order, acks back, errors surfaced."""

import threading

import httpx
import numpy as np
import pytest

from fleet.poster import ScanPoster
from mapserver.client import MapClient, MapRequestError
from mapserver.core.scan import Pose2D, Scan
from mapserver.core.scan_binary import decode_scans


def scans(n: int, stamp: float) -> list[Scan]:
    return [
        Scan(f"u{k}", stamp, Pose2D(1.0, 1.0, 0.0), -1.0, 0.5, 0.05, 20.0, np.array([2.0, np.inf]))
        for k in range(n)
    ]


class FakeServer:
    """A MockTransport handler acking scans in arrival order; can refuse a stamp."""

    def __init__(self, refuse_stamp: float | None = None) -> None:
        self.batches: list[list[tuple[str, float]]] = []
        self.refuse_stamp = refuse_stamp
        self.gate = threading.Event()
        self.gate.set()

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.gate.wait(10)
        assert request.url.path == "/v1/scans/batch"
        assert request.headers["content-type"] == "application/vnd.fleetmap.scan"
        body = decode_scans(request.content, batch=True)
        if any(s["stamp"] == self.refuse_stamp for s in body):
            return httpx.Response(
                409, json={"detail": f"stamp: went backwards, got {self.refuse_stamp}"}
            )
        start = sum(len(b) for b in self.batches)
        self.batches.append([(s["unit_id"], s["stamp"]) for s in body])
        acks = [{"seq": start + i + 1, "map_version": start + i + 1} for i in range(len(body))]
        return httpx.Response(200, json={"acks": acks})


def client(server: FakeServer) -> MapClient:
    return MapClient(httpx.Client(base_url="http://map", transport=httpx.MockTransport(server)))


def test_a_tick_is_sent_in_batches_of_at_most_max_batch_and_acked_in_order():
    server = FakeServer()
    poster = ScanPoster(client(server), max_batch=4)
    acks = poster.post(scans(10, 1.0))
    assert [len(b) for b in server.batches] == [4, 4, 2]
    assert [a.seq for a in acks] == list(range(1, 11)) and poster.posted == 10
    assert poster.post([]) == [] and len(server.batches) == 3


def test_a_pipelined_poster_sends_every_tick_in_order_and_returns_the_acks_later():
    server = FakeServer()
    server.gate.clear()  # hold the server: the simulation must not wait for it
    with ScanPoster(client(server), in_flight=3) as poster:
        assert poster.post(scans(2, 1.0)) == []  # queued, or on its way
        poster.post(scans(2, 2.0))
        server.gate.set()
        late = poster.post(scans(2, 3.0))
        acks = late + poster.flush()
    assert [a.seq for a in acks] == list(range(1, 7)) and poster.posted == 6
    assert [stamp for batch in server.batches for _, stamp in batch] == [1, 1, 2, 2, 3, 3]


def test_a_failed_request_stops_the_pipeline_and_is_raised():
    server = FakeServer(refuse_stamp=2.0)
    poster = ScanPoster(client(server), in_flight=2)
    poster.post(scans(1, 1.0))
    poster.post(scans(1, 2.0))
    with pytest.raises(MapRequestError, match="409"):
        poster.flush()
    with pytest.raises(MapRequestError):
        poster.post(scans(1, 3.0))
    with pytest.raises(MapRequestError):
        poster.close()
    assert [stamp for batch in server.batches for _, stamp in batch] == [1.0]


@pytest.mark.parametrize(("field", "value"), [("max_batch", 0), ("in_flight", -1)])
def test_settings_errors_name_the_field_and_value(field, value):
    with pytest.raises(ValueError, match=f"{field} must be an integer >= ., got {value}"):
        ScanPoster(client(FakeServer()), **{field: value})
