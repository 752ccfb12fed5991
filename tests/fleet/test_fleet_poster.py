"""Posting scans through MapClient: batches in order, acks back, errors surfaced."""

import json
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
        self.entered = threading.Event()  # set when a request arrives

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.entered.set()
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


def sent(server: FakeServer) -> list[float]:
    """The stamps the server has taken so far, in order."""
    return [stamp for batch in server.batches for _, stamp in batch]


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
    poster.flush()  # tick 1 alone: the refusal of tick 2 does not take it along
    poster.post(scans(1, 2.0))
    with pytest.raises(MapRequestError, match="409"):
        poster.flush()
    with pytest.raises(MapRequestError):
        poster.post(scans(1, 3.0))
    with pytest.raises(MapRequestError):
        poster.close()
    assert [stamp for batch in server.batches for _, stamp in batch] == [1.0]


def test_ticks_queued_behind_a_request_go_out_together_in_order():
    server = FakeServer()
    server.gate.clear()  # the first tick's request waits at the server
    with ScanPoster(client(server), max_batch=5, in_flight=4) as poster:
        poster.post(scans(2, 1.0))
        assert server.entered.wait(10)  # the worker is on its way with tick 1
        for stamp in (2.0, 3.0, 4.0):
            poster.post(scans(2, stamp))
        server.gate.set()
        acks = poster.flush()
    assert [len(b) for b in server.batches] == [2, 5, 1]  # ticks 2-4: one batch, split at 5
    assert sent(server) == [1.0, 1.0, 2.0, 2.0, 3.0, 3.0, 4.0, 4.0]
    assert [a.seq for a in acks] == list(range(1, 9)) and poster.posted == 8


def test_a_refused_request_refuses_the_ticks_sent_with_it():
    server = FakeServer(refuse_stamp=3.0)
    server.gate.clear()
    poster = ScanPoster(client(server), in_flight=4)
    poster.post(scans(1, 1.0))
    assert server.entered.wait(10)
    poster.post(scans(1, 2.0))
    poster.post(scans(1, 3.0))
    server.gate.set()
    with pytest.raises(MapRequestError, match="409"):
        poster.flush()
    assert sent(server) == [1.0]  # ticks 2 and 3 went together, and were refused together
    with pytest.raises(MapRequestError):
        poster.close()


@pytest.mark.parametrize(("field", "value"), [("max_batch", 0), ("in_flight", -1)])
def test_settings_errors_name_the_field_and_value(field, value):
    with pytest.raises(ValueError, match=f"{field} must be an integer >= ., got {value}"):
        ScanPoster(client(FakeServer()), **{field: value})


class ClockServer(FakeServer):
    """A FakeServer that also takes ``PUT /v1/clock`` (or answers it ``clock_status``)."""

    def __init__(self, clock_status: int = 200) -> None:
        super().__init__()
        self.clock_status = clock_status
        self.requests: list[tuple[str, float]] = []  # ("clock", now) or ("scans", stamp)

    def __call__(self, request: httpx.Request) -> httpx.Response:
        if request.url.path != "/v1/clock":
            reply = super().__call__(request)
            self.requests.append(("scans", self.batches[-1][0][1]))
            return reply
        now = json.loads(request.content)["now"]
        if self.clock_status != 200:
            return httpx.Response(self.clock_status, json={"detail": "Not Found"})
        self.requests.append(("clock", now))
        body = {"reference": "declared", "now": now, "wall": 1.7e9, "map_stamp": None,
                "declared": {"now": now, "age_s": 0.0}, "max_lead_s": 5.0}  # fmt: skip
        return httpx.Response(200, json=body)


def test_the_poster_declares_the_clock_before_the_scans_every_declare_every_s():
    server = ClockServer()
    with ScanPoster(client(server), in_flight=2, declare_every_s=1.0) as poster:
        for k in range(1, 26):
            poster.post(scans(1, k * 0.1))
        poster.flush()
    clocks = [r for r in server.requests if r[0] == "clock"]
    assert [now for _, now in clocks] == pytest.approx([0.1, 1.1, 2.1])
    first_scan = server.requests.index(("scans", pytest.approx(0.1)))
    assert server.requests.index(("clock", pytest.approx(0.1))) < first_scan


@pytest.mark.parametrize("status", [403, 404, 405])
def test_a_server_that_does_not_take_the_clock_still_gets_the_scans(status):
    server = ClockServer(clock_status=status)
    poster = ScanPoster(client(server), declare_every_s=1.0)
    for k in range(1, 4):
        assert len(poster.post(scans(1, float(k)))) == 1
    assert poster.declare_every_s is None and len(server.batches) == 3
