"""MapClient against a contract-shaped fake server on ``httpx.MockTransport``.

The fake records every request so each test checks what went over the wire (method,
path, query, headers, body) and what the client made of the reply.
"""

from __future__ import annotations

import json
import math

import httpx
import numpy as np
import pytest
from conftest import make_scan

from mapserver.client import (
    CellOut,
    Conflict,
    Forbidden,
    Grid,
    InvalidRequest,
    MapClient,
    MapClientError,
    MapProtocolError,
    MapRequestError,
    MapServerError,
    MapServerUnavailable,
    PlanOut,
    ScanAck,
    SegmentOut,
    Unauthorized,
    UnitState,
)
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Pose2D
from mapserver.core.scan_binary import CONTENT_TYPE as BINARY_SCAN_TYPE
from mapserver.core.scan_binary import decode_scans, encode_batch, encode_scan

BASE = "http://map.test:8700"
GEOMETRY = GridGeometry(width=4, height=3, resolution=0.5, origin_x=-1.0, origin_y=2.0)


class FakeMapServer:
    """Answers docs/http-api.md requests from a costmap history held in memory.

    ``costs[v]`` is the costmap at version v; updates since v are one bounding-box patch
    per later version holding the *current* costs in that box (as the real server does).
    """

    def __init__(self, token: str | None = None, keep_versions: int = 100) -> None:
        self.token = token
        self.keep_versions = keep_versions
        self.requests: list[httpx.Request] = []
        self.costs = {1: np.arange(12, dtype=np.uint8).reshape(3, 4)}
        self.version = 1
        self.stamp = 12.5

    def change(self, row: int, col: int, value: int) -> None:
        new = self.costs[self.version].copy()
        new[row, col] = value
        self.version += 1
        self.costs[self.version] = new

    def client(
        self,
        token: str | None = None,
        timeout: float | httpx.Timeout = 5.0,
        scan_encoding: str = "binary",
    ) -> MapClient:
        # the injected client's own default timeout (60 s) must never apply
        http = httpx.Client(transport=httpx.MockTransport(self.handle), base_url=BASE, timeout=60.0)
        return MapClient(http, token=token, timeout=timeout, scan_encoding=scan_encoding)

    @property
    def last(self) -> httpx.Request:
        return self.requests[-1]

    def handle(self, request: httpx.Request) -> httpx.Response:
        self.requests.append(request)
        if self.token is not None and request.headers.get("authorization") != (
            f"Bearer {self.token}"
        ):
            return httpx.Response(401, json={"detail": "missing or wrong bearer token"})
        route = (request.method, request.url.path)
        body = decoded(request)
        if route == ("POST", "/v1/scans"):
            return httpx.Response(200, json={"seq": 7, "map_version": 42})
        if route == ("POST", "/v1/scans/batch"):
            acks = [{"seq": 10 + i, "map_version": 50 + i} for i in range(len(body["scans"]))]
            return httpx.Response(200, json={"acks": acks})
        if route == ("GET", "/v1/map/meta"):
            return httpx.Response(200, json=self.meta())
        if route == ("GET", "/v1/map"):
            occupancy = np.array([[-1, 0, 100, 50]] + [[1, 2, 3, 4]] * 2, dtype=np.int8)
            return self.raw(occupancy)
        if route == ("GET", "/v1/costmap"):
            return self.raw(self.costs[self.version])
        if route == ("GET", "/v1/costmap/updates"):
            return httpx.Response(200, json=self.updates(int(request.url.params["since"])))
        if route == ("POST", "/v1/query/cells"):
            return httpx.Response(200, json={"cells": [self.cell(*p) for p in body["points"]]})
        if route == ("POST", "/v1/query/segments"):
            return httpx.Response(
                200, json={"segments": [self.segment(*s) for s in body["segments"]]}
            )
        if route == ("POST", "/v1/plan"):
            return httpx.Response(200, json=self.plan(body))
        if route == ("GET", "/healthz"):
            return httpx.Response(200, json={"status": "ok"})
        if route == ("GET", "/metrics"):
            return httpx.Response(200, text="# TYPE fleetmap_scans_fused_total counter\n")
        return httpx.Response(404, json={"detail": f"no route {request.url.path}"})

    def meta(self) -> dict:
        return {
            "resolution": GEOMETRY.resolution,
            "width": GEOMETRY.width,
            "height": GEOMETRY.height,
            "origin": {"x": GEOMETRY.origin_x, "y": GEOMETRY.origin_y, "yaw": 0},
            "frame": "map",
            "stamp": self.stamp,
            "version": self.version,
            "policy": "decay",
            "sensor_model": {"p_hit": 0.7, "p_miss": 0.4},
            "decay": {"policy": "decay", "half_life_occupied": 30.0},
            "inflation": {"inflation_radius": 0.55},
            "thresholds": {"occupied": 0.65, "free": 0.25},
        }

    def raw(self, grid: np.ndarray) -> httpx.Response:
        headers = {
            "X-Map-Width": str(GEOMETRY.width),
            "X-Map-Height": str(GEOMETRY.height),
            "X-Map-Resolution": str(GEOMETRY.resolution),
            "X-Map-Origin-X": str(GEOMETRY.origin_x),
            "X-Map-Origin-Y": str(GEOMETRY.origin_y),
            "X-Map-Version": str(self.version),
            "X-Map-Stamp": str(self.stamp),
            "Content-Type": "application/octet-stream",
        }
        return httpx.Response(200, content=grid.tobytes(), headers=headers)

    def updates(self, since: int) -> dict:
        if since not in self.costs or since < self.version - self.keep_versions:
            return {"full": True, "version": self.version}
        current = self.costs[self.version]
        patches = []
        for v in range(since + 1, self.version + 1):
            rows, cols = np.nonzero(self.costs[v - 1] != self.costs[v])
            r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
            patches.append(
                {
                    "x0": int(c0),
                    "y0": int(r0),
                    "width": int(c1 - c0),
                    "height": int(r1 - r0),
                    "data": current[r0:r1, c0:c1].ravel().tolist(),
                }
            )
        return {"version": self.version, "patches": patches}

    def cell(self, x: float, y: float) -> dict:
        if not GEOMETRY.contains_point(x, y):
            return {
                "x": x,
                "y": y,
                "state": "outside",
                "p_occ": None,
                "cost": None,
                "last_observed": None,
                "age": None,
            }
        col, row = GEOMETRY.world_to_cell(x, y)
        return {
            "x": x,
            "y": y,
            "state": "occupied",
            "p_occ": 0.9,
            "cost": int(self.costs[self.version][row, col]),
            "last_observed": 10.0,
            "age": self.stamp - 10.0,
        }

    def segment(self, x0: float, y0: float, x1: float, y1: float) -> dict:
        blocked = x1 > 0
        return {
            "max_cost": 254 if blocked else 3,
            "blocked": blocked,
            "unknown_fraction": 0.25,
            "first_blocked": [x1, y1] if blocked else None,
        }

    def plan(self, body: dict) -> dict:
        return {
            "found": True,
            "path": [body["start"], [0.0, 3.0], body["goal"]],
            "length": 2.5,
            "cost": 17.0,
            "min_clearance": 0.3,
            "expanded": 31,
            "planning_ms": 0.8,
            "map_version": self.version,
        }


def replying(reply: dict) -> MapClient:
    """A client whose server answers every request with 200 and ``reply``."""
    transport = httpx.MockTransport(lambda request: httpx.Response(200, json=reply))
    return MapClient(httpx.Client(transport=transport, base_url=BASE))


def body_of(request: httpx.Request) -> dict:
    assert request.headers["content-type"] == "application/json"
    return json.loads(request.content)


def decoded(request: httpx.Request) -> dict | None:
    """A request's body: JSON, or a binary scan body as the same mappings."""
    if not request.content:
        return None
    if request.headers["content-type"] == BINARY_SCAN_TYPE:
        batch = request.url.path.endswith("/batch")
        scans = decode_scans(request.content, batch)
        return {"scans": scans} if batch else scans[0]
    return body_of(request)


# ---------------------------------------------------------------------------- auth, set-up


def test_bearer_token_is_sent_on_every_request_when_given():
    server = FakeMapServer(token="s3cret")
    client = server.client(token="s3cret")
    client.map_meta()
    client.costmap()
    client.post_scan(make_scan([1.0]))
    assert [r.headers["authorization"] for r in server.requests] == ["Bearer s3cret"] * 3


def test_no_authorization_header_without_a_token():
    server = FakeMapServer()
    server.client().map_meta()
    assert "authorization" not in server.last.headers


def test_the_client_requires_a_base_url_and_a_usable_token_and_timeout():
    with pytest.raises(ValueError, match="base_url"):
        MapClient(httpx.Client())
    http = httpx.Client(base_url=BASE)
    with pytest.raises(ValueError, match="token.*''"):
        MapClient(http, token="")
    with pytest.raises(ValueError, match="timeout.*-1"):
        MapClient(http, timeout=-1)


def test_a_base_url_path_prefix_is_kept():
    seen = []
    transport = httpx.MockTransport(lambda r: seen.append(r.url.path) or httpx.Response(200))
    client = MapClient(httpx.Client(transport=transport, base_url="http://proxy.test/fleet/"))
    assert client.healthz()
    assert seen == ["/fleet/healthz"]


# ---------------------------------------------------------------------------- scans


def test_post_scan_sends_a_binary_record_by_default_and_parses_the_ack():
    server = FakeMapServer()
    scan = make_scan([1.25, math.inf, math.nan, 21.0], stamp=12.3, unit_id="u1")
    ack = server.client().post_scan(scan)
    assert ack == ScanAck(seq=7, map_version=42)
    assert server.last.headers["content-type"] == "application/vnd.fleetmap.scan"
    assert server.last.content == encode_scan(scan)
    (sent,) = decode_scans(server.last.content, batch=False)
    assert (sent["unit_id"], sent["stamp"], sent["pose"]) == (
        "u1",
        12.3,
        {"x": 0.5, "y": 0.5, "yaw": 0.0},
    )
    assert np.array_equal(sent["ranges"], [1.25, math.inf, math.nan, 21.0], equal_nan=True)


def test_post_scan_sends_the_contract_object_as_json_when_asked():
    server = FakeMapServer()
    scan = make_scan([1.2, math.inf, math.nan, 21.0], stamp=12.3, unit_id="u1")
    ack = server.client(scan_encoding="json").post_scan(scan)
    assert ack == ScanAck(seq=7, map_version=42)
    assert (server.last.method, server.last.url.path) == ("POST", "/v1/scans")
    sent = body_of(server.last)
    assert sent["unit_id"] == "u1" and sent["stamp"] == 12.3 and sent["frame"] == "map"
    # no return goes as 2 * range_max + 1 (strict JSON), an invalid (NaN) beam as null
    assert sent["ranges"] == [1.2, 2 * scan.range_max + 1, None, 21.0]
    assert b"Infinity" not in server.last.content


def test_post_scan_sends_a_dict_as_is():
    server = FakeMapServer()
    scan = {"unit_id": "u2", "stamp": 1.0, "frame": "odom"}  # the server judges it
    server.client().post_scan(scan)
    assert body_of(server.last) == scan


def test_post_scans_sends_one_batch_and_returns_one_ack_per_scan_in_order():
    server = FakeMapServer()
    scans = [make_scan([1.0], stamp=float(t)) for t in range(3)]
    acks = server.client().post_scans(scans)
    assert acks == [
        ScanAck(seq=10, map_version=50),
        ScanAck(seq=11, map_version=51),
        ScanAck(seq=12, map_version=52),
    ]
    assert (server.last.method, server.last.url.path) == ("POST", "/v1/scans/batch")
    assert server.last.content == encode_batch(scans)
    assert [s["stamp"] for s in decoded(server.last)["scans"]] == [0.0, 1.0, 2.0]
    server.client(scan_encoding="json").post_scans(scans)
    assert [s["stamp"] for s in body_of(server.last)["scans"]] == [0.0, 1.0, 2.0]


def test_a_batch_holding_a_mapping_goes_as_json():
    server = FakeMapServer()
    server.client().post_scans([make_scan([1.0]), {"unit_id": "u2", "stamp": 1.0}])
    assert [s["unit_id"] for s in body_of(server.last)["scans"]] == ["u1", "u2"]


def test_an_unknown_scan_encoding_is_refused():
    with pytest.raises(ValueError, match="scan_encoding must be 'binary' or 'json', got 'xml'"):
        MapClient(httpx.Client(base_url=BASE), scan_encoding="xml")


def test_post_scans_of_nothing_sends_nothing():
    server = FakeMapServer()
    assert server.client().post_scans([]) == []
    assert server.requests == []


def test_a_batch_reply_with_the_wrong_number_of_acks_is_a_protocol_error():
    reply = {"acks": [{"seq": 1, "map_version": 1}]}
    client = replying(reply)
    with pytest.raises(MapProtocolError, match=r"one answer per item asked \(2\) in 'acks', got 1"):
        client.post_scans([make_scan([1.0]), make_scan([1.0], stamp=1.0)])


# ---------------------------------------------------------------------------- map


def test_map_meta_parses_every_contract_field():
    server = FakeMapServer()
    meta = server.client().map_meta()
    assert (server.last.method, server.last.url.path) == ("GET", "/v1/map/meta")
    assert meta.geometry == GEOMETRY
    assert (meta.origin.yaw, meta.frame, meta.stamp, meta.version) == (0.0, "map", 12.5, 1)
    assert meta.sensor_model == {"p_hit": 0.7, "p_miss": 0.4}
    assert meta.decay["policy"] == "decay"
    assert meta.inflation == {"inflation_radius": 0.55}
    assert meta.thresholds == {"occupied": 0.65, "free": 0.25}


def test_occupancy_is_int8_with_row_zero_from_the_first_bytes():
    server = FakeMapServer()
    grid = server.client().occupancy(at=20.0)
    assert (server.last.method, server.last.url.path) == ("GET", "/v1/map")
    assert dict(server.last.url.params) == {"format": "raw", "at": "20.0"}
    assert grid.data.dtype == np.int8 and grid.data.shape == (3, 4)
    assert grid.data[0].tolist() == [-1, 0, 100, 50]  # the bottom row: first 4 bytes
    assert grid.geometry == GEOMETRY
    assert (grid.version, grid.stamp) == (1, 12.5)


def test_costmap_is_uint8_row_major_from_the_origin_and_read_only():
    server = FakeMapServer()
    grid = server.client().costmap()
    assert dict(server.last.url.params) == {"format": "raw"}
    assert server.last.url.path == "/v1/costmap"
    assert grid.data.dtype == np.uint8
    # index = row * width + col: byte 6 is cell (col 2, row 1)
    assert grid.data[1, 2] == 6
    assert np.array_equal(grid.data.ravel(), np.arange(12))
    with pytest.raises(ValueError):
        grid.data[0, 0] = 1


def raw_client(content: bytes, **headers: str) -> MapClient:
    base = {
        "X-Map-Width": "4",
        "X-Map-Height": "3",
        "X-Map-Resolution": "0.5",
        "X-Map-Origin-X": "0",
        "X-Map-Origin-Y": "0",
        "X-Map-Version": "3",
        "X-Map-Stamp": "1.5",
    }
    base.update(headers)
    base = {k: v for k, v in base.items() if v != "DROP"}

    def handler(request: httpx.Request) -> httpx.Response:
        return httpx.Response(200, content=content, headers=base)

    return MapClient(httpx.Client(transport=httpx.MockTransport(handler), base_url=BASE))


def test_a_truncated_raw_body_is_a_protocol_error_naming_both_sizes():
    with pytest.raises(MapProtocolError, match="= 12 bytes, got 11$") as err:
        raw_client(bytes(11)).costmap()
    assert err.value.value == 11


@pytest.mark.parametrize(
    ("headers", "message"),
    [
        ({"X-Map-Width": "DROP"}, "header X-Map-Width is missing"),
        ({"X-Map-Version": "v3"}, "header X-Map-Version must be an integer.*v3"),
        ({"X-Map-Resolution": "0"}, "no valid grid.*resolution"),
    ],
)
def test_bad_raw_headers_are_protocol_errors_naming_the_header(headers, message):
    with pytest.raises(MapProtocolError, match=message):
        raw_client(bytes(12), **headers).occupancy()


@pytest.mark.parametrize("stamp", ["nan", "null"])
def test_a_nan_or_null_stamp_header_means_no_stamp_yet(stamp):
    assert raw_client(bytes(12), **{"X-Map-Stamp": stamp}).costmap().stamp is None


# ---------------------------------------------------------------------------- updates


def test_costmap_updates_parse_patches_as_uint8_boxes():
    server = FakeMapServer()
    server.change(row=2, col=1, value=254)
    updates = server.client().costmap_updates(since=1)
    assert (server.last.url.path, dict(server.last.url.params)) == (
        "/v1/costmap/updates",
        {"since": "1"},
    )
    assert (updates.version, updates.full) == (2, False)
    (patch,) = (p.to_patch() for p in updates.patches)
    assert (patch.x0, patch.y0, patch.width, patch.height) == (1, 2, 1, 1)
    assert patch.data.dtype == np.uint8 and patch.data.tolist() == [[254]]


def test_costmap_updates_report_full_when_the_server_lost_the_version():
    server = FakeMapServer()
    updates = server.client().costmap_updates(since=99)
    assert (updates.full, updates.patches, updates.version) == (True, [], 1)


@pytest.mark.parametrize(
    ("patch", "message"),
    [
        (
            {"x0": 0, "y0": 0, "width": 2, "height": 1, "data": [1]},
            "patches\\[0\\]': data must hold width \\* height = 2 values, not 1, got",
        ),
        (
            {"x0": 0, "y0": 0, "width": 1, "height": 1, "data": [256]},
            "data\\[0\\]': Input should be less than or equal to 255, got 256$",
        ),
        (
            {"x0": 0, "y0": 0, "width": 1, "height": 1, "data": [1.5]},
            "data\\[0\\]': Input should be a valid integer, got 1.5$",
        ),
        (
            {"x0": -1, "y0": 0, "width": 1, "height": 1, "data": [1]},
            "x0': Input should be greater than or equal to 0, got -1$",
        ),
        ({"x0": 0, "y0": 0, "width": 1, "data": [1]}, "'patches\\[0\\].height' is missing"),
    ],
)
def test_malformed_patches_are_protocol_errors(patch, message):
    reply = {"version": 2, "patches": [patch]}
    client = replying(reply)
    with pytest.raises(MapProtocolError, match=message):
        client.costmap_updates(since=1)


def test_follow_costmap_patches_a_copy_to_reproduce_the_full_costmap():
    server = FakeMapServer()
    client = server.client()
    local = client.follow_costmap(None)  # no local copy yet: the full costmap
    assert server.last.url.path == "/v1/costmap"
    before = local.data.copy()
    server.change(0, 0, 254)
    server.change(2, 3, 253)
    server.change(0, 0, 0)  # a cell changed twice: the current value wins
    followed = client.follow_costmap(local)
    assert server.last.url.path == "/v1/costmap/updates"
    assert followed.version == 4
    assert np.array_equal(followed.data, client.costmap().data)
    assert np.array_equal(local.data, before)  # the local grid is untouched
    assert followed.geometry == local.geometry


def test_follow_costmap_returns_the_local_grid_when_nothing_changed():
    server = FakeMapServer()
    client = server.client()
    local = client.costmap()
    assert client.follow_costmap(local) is local
    assert server.last.url.path == "/v1/costmap/updates"


def test_follow_costmap_refetches_everything_when_the_server_answers_full():
    server = FakeMapServer(keep_versions=1)
    client = server.client()
    local = client.costmap()
    server.change(1, 1, 254)
    server.change(1, 2, 254)
    followed = client.follow_costmap(local)
    assert [r.url.path for r in server.requests[-2:]] == ["/v1/costmap/updates", "/v1/costmap"]
    assert followed.version == 3
    assert followed.data[1, 1] == followed.data[1, 2] == 254


def test_follow_costmap_rejects_a_patch_outside_the_local_grid():
    reply = {"version": 2, "patches": [{"x0": 3, "y0": 0, "width": 2, "height": 1, "data": [1, 2]}]}
    client = replying(reply)
    local = Grid(np.zeros((3, 4), np.uint8), GEOMETRY, 1, 0.0)
    with pytest.raises(MapProtocolError, match="exceeds the 4 x 3 local grid"):
        client.follow_costmap(local)


def test_follow_costmap_refuses_an_occupancy_grid():
    server = FakeMapServer()
    client = server.client()
    with pytest.raises(ValueError, match="uint8 costmap.*int8"):
        client.follow_costmap(client.occupancy())


# ---------------------------------------------------------------------------- queries, plan


def test_query_cells_sends_points_and_at_and_parses_each_cell():
    server = FakeMapServer()
    cells = server.client().query_cells(np.array([[-0.75, 2.25], [50.0, 50.0]]), at=13.0)
    assert (server.last.method, server.last.url.path) == ("POST", "/v1/query/cells")
    assert body_of(server.last) == {"points": [[-0.75, 2.25], [50.0, 50.0]], "at": 13.0}
    assert cells == [
        CellOut(x=-0.75, y=2.25, state="occupied", p_occ=0.9, cost=0, last_observed=10.0, age=2.5),
        CellOut(
            x=50.0, y=50.0, state="outside", p_occ=None, cost=None, last_observed=None, age=None
        ),
    ]


def test_query_cells_without_at_leaves_it_to_the_server():
    server = FakeMapServer()
    server.client().query_cells([(0.0, 2.5)])
    assert body_of(server.last) == {"points": [[0.0, 2.5]]}


def test_query_arguments_of_the_wrong_shape_name_the_bad_item():
    client = FakeMapServer().client()
    with pytest.raises(ValueError, match=r"points\[1\] must be 2 numbers.*1, 2, 3"):
        client.query_cells([(0.0, 0.0), (1, 2, 3)])
    with pytest.raises(ValueError, match=r"segments\[0\] must be 4 numbers"):
        client.query_segments([(0.0, 0.0, "a", 1.0)])


def test_query_segments_sends_segments_and_parses_each_answer():
    server = FakeMapServer()
    found = server.client().query_segments([(0, 2, 1, 2.5), (-1.0, 2.0, -0.5, 2.0)])
    assert (server.last.method, server.last.url.path) == ("POST", "/v1/query/segments")
    assert body_of(server.last) == {"segments": [[0.0, 2.0, 1.0, 2.5], [-1.0, 2.0, -0.5, 2.0]]}
    assert found == [
        SegmentOut(max_cost=254, blocked=True, unknown_fraction=0.25, first_blocked=[1.0, 2.5]),
        SegmentOut(max_cost=3, blocked=False, unknown_fraction=0.25, first_blocked=None),
    ]


def test_a_reply_with_fewer_answers_than_questions_is_a_protocol_error():
    reply = {"cells": []}
    client = replying(reply)
    with pytest.raises(
        MapProtocolError, match=r"one answer per item asked \(1\) in 'cells', got 0"
    ):
        client.query_cells([(0.0, 0.0)])


def test_plan_sends_the_contract_request_and_parses_the_result():
    server = FakeMapServer()
    result = server.client().plan((-0.5, 2.5), [0.5, 3.0], algorithm="dijkstra", unit_id="u3")
    assert (server.last.method, server.last.url.path) == ("POST", "/v1/plan")
    assert body_of(server.last) == {
        "start": [-0.5, 2.5],
        "goal": [0.5, 3.0],
        "algorithm": "dijkstra",
        "allow_unknown": True,
        "unit_id": "u3",
    }
    assert result == PlanOut(
        found=True,
        path=[[-0.5, 2.5], [0.0, 3.0], [0.5, 3.0]],
        length=2.5,
        cost=17.0,
        min_clearance=0.3,
        expanded=31,
        planning_ms=0.8,
        map_version=1,
    )


def test_plan_without_unit_id_omits_it():
    server = FakeMapServer()
    server.client().plan((0, 2.5), (0.5, 3), allow_unknown=False)
    sent = body_of(server.last)
    assert "unit_id" not in sent
    assert (sent["algorithm"], sent["allow_unknown"]) == ("astar", False)


def test_a_mistyped_reply_field_is_a_protocol_error_carrying_the_value():
    reply = {
        "found": "yes",
        "path": [],
        "length": 0,
        "cost": 0,
        "min_clearance": 0,
        "expanded": 0,
        "planning_ms": 0,
        "map_version": 1,
    }
    client = replying(reply)
    with pytest.raises(
        MapProtocolError, match="field 'found': Input should be a valid boolean, got 'yes'$"
    ) as err:
        client.plan((0, 0), (1, 1))
    assert err.value.value == "yes"


def test_fields_a_newer_server_adds_to_a_reply_are_ignored_at_every_depth():
    reply = {
        "units": [
            {
                "unit_id": "u1",
                "stamp": 3.5,
                "pose": {"x": 1.0, "y": 2.0, "yaw": 0.5, "z": 0.1},
                "path": [[1.0, 2.0], [3.0, 2.0]],
                "frozen": False,
                "battery": 0.8,
            }
        ],
        "site": "north",
    }
    (unit,) = replying(reply).units()
    assert unit == UnitState.of("u1", 3.5, Pose2D(1.0, 2.0, 0.5), [(1.0, 2.0), (3.0, 2.0)])
    assert not hasattr(unit, "battery") and not hasattr(unit.pose, "z")


def test_a_reply_missing_a_field_is_still_a_protocol_error():
    client = replying({"found": True, "path": [], "length": 0.0, "cost": 0.0})
    with pytest.raises(
        MapProtocolError,
        match=r"field 'min_clearance' is missing \(fields present\), "
        r"got \['cost', 'found', 'length', 'path'\]$",
    ):
        client.plan((0, 0), (1, 1))


# ---------------------------------------------------------------------------- operations


def test_healthz_and_metrics():
    server = FakeMapServer()
    client = server.client()
    assert client.healthz() is True
    assert server.last.url.path == "/healthz"
    assert client.metrics_text().startswith("# TYPE fleetmap_scans_fused_total counter")
    assert server.last.url.path == "/metrics"


def test_healthz_is_false_when_not_ready_or_unreachable():
    not_ready = httpx.MockTransport(lambda r: httpx.Response(503, json={"detail": "replaying"}))
    assert MapClient(httpx.Client(transport=not_ready, base_url=BASE)).healthz() is False
    assert (
        MapClient(httpx.Client(transport=httpx.MockTransport(refuse), base_url=BASE)).healthz()
        is False
    )


# ---------------------------------------------------------------------------- errors


def refuse(request: httpx.Request) -> httpx.Response:
    raise httpx.ConnectError("[Errno 111] Connection refused", request=request)


@pytest.mark.parametrize(
    ("status", "error"),
    [
        (400, InvalidRequest),
        (401, Unauthorized),
        (403, Forbidden),
        (404, MapRequestError),
        (409, Conflict),
        (413, InvalidRequest),
        (422, InvalidRequest),
        (429, MapRequestError),
        (500, MapServerError),
        (503, MapServerError),
    ],
)
def test_each_error_status_maps_to_its_exception_carrying_status_and_detail(status, error):
    detail = f"stamp: went backwards, got 3.0 (status {status})"
    transport = httpx.MockTransport(lambda r: httpx.Response(status, json={"detail": detail}))
    client = MapClient(httpx.Client(transport=transport, base_url=BASE), retries=0)
    with pytest.raises(error) as err:
        client.post_scan(make_scan([1.0], stamp=3.0))
    assert type(err.value) is error
    assert isinstance(err.value, MapClientError)
    assert (err.value.status, err.value.detail) == (status, detail)
    assert err.value.endpoint == "POST /v1/scans"
    assert detail in str(err.value)


def test_a_structured_422_detail_is_kept_as_sent():
    detail = [{"loc": ["body", "pose", "x"], "msg": "must be finite", "input": "nan"}]
    transport = httpx.MockTransport(lambda r: httpx.Response(422, json={"detail": detail}))
    with pytest.raises(InvalidRequest) as err:
        MapClient(httpx.Client(transport=transport, base_url=BASE)).map_meta()
    assert err.value.detail == detail


def test_an_error_without_a_json_body_carries_the_body_text():
    transport = httpx.MockTransport(lambda r: httpx.Response(502, text="Bad Gateway"))
    with pytest.raises(MapServerError) as err:
        MapClient(httpx.Client(transport=transport, base_url=BASE)).costmap()
    assert (err.value.status, err.value.detail) == (502, "Bad Gateway")


def test_a_wrong_token_is_unauthorized():
    server = FakeMapServer(token="right")
    with pytest.raises(Unauthorized, match="missing or wrong bearer token"):
        server.client(token="wrong").map_meta()


def test_a_connect_error_becomes_map_server_unavailable_wrapping_it():
    client = MapClient(httpx.Client(transport=httpx.MockTransport(refuse), base_url=BASE))
    with pytest.raises(MapServerUnavailable, match="Connection refused") as err:
        client.post_scan(make_scan([1.0]))
    assert isinstance(err.value.cause, httpx.ConnectError)
    assert err.value.__cause__ is err.value.cause


def test_a_timeout_becomes_map_server_unavailable():
    def slow(request: httpx.Request) -> httpx.Response:
        raise httpx.ReadTimeout("timed out", request=request)

    client = MapClient(httpx.Client(transport=httpx.MockTransport(slow), base_url=BASE))
    with pytest.raises(MapServerUnavailable) as err:
        client.costmap_updates(since=0)
    assert isinstance(err.value.cause, httpx.TimeoutException)


def test_a_non_json_reply_is_a_protocol_error():
    transport = httpx.MockTransport(lambda r: httpx.Response(200, text="<html>proxy</html>"))
    with pytest.raises(MapProtocolError, match="not JSON.*<html>") as err:
        MapClient(httpx.Client(transport=transport, base_url=BASE)).map_meta()
    assert err.value.endpoint == "GET /v1/map/meta"


# ---------------------------------------------------------------------------- timeouts


CALLS = {
    "post_scan": lambda c: c.post_scan(make_scan([1.0])),
    "post_scans": lambda c: c.post_scans([make_scan([1.0])]),
    "map_meta": lambda c: c.map_meta(),
    "occupancy": lambda c: c.occupancy(),
    "costmap": lambda c: c.costmap(),
    "costmap_updates": lambda c: c.costmap_updates(1),
    "follow_costmap": lambda c: c.follow_costmap(None),
    "query_cells": lambda c: c.query_cells([(0.0, 2.5)]),
    "query_segments": lambda c: c.query_segments([(0.0, 2.0, 1.0, 2.0)]),
    "plan": lambda c: c.plan((0.0, 2.5), (0.5, 3.0)),
    "healthz": lambda c: c.healthz(),
    "metrics_text": lambda c: c.metrics_text(),
}


@pytest.mark.parametrize("call", CALLS.values(), ids=CALLS.keys())
def test_every_request_carries_the_explicit_timeout(call):
    server = FakeMapServer()
    call(server.client(timeout=2.5))
    assert server.requests
    for request in server.requests:
        assert request.extensions["timeout"] == httpx.Timeout(2.5).as_dict()


def test_a_timeout_object_is_passed_through():
    server = FakeMapServer()
    timeout = httpx.Timeout(1.0, connect=0.25)
    server.client(timeout=timeout).map_meta()
    assert server.last.extensions["timeout"] == timeout.as_dict()


@pytest.mark.parametrize(
    ("replies", "waits", "final"),
    [
        ([(429, "3"), (200, None)], [3.0], 200),  # waits as long as the server asks
        ([(503, None), (503, "120"), (200, None)], [1.0, 5.0], 200),  # default 1 s, capped
        ([(429, "1"), (429, "1"), (429, "1")], [1.0, 1.0], 429),  # two retries, then the error
        ([(409, None)], [], 409),  # a refusal is final
    ],
)
def test_try_later_replies_are_retried_after_retry_after(replies, waits, final):
    pending, slept = list(replies), []

    def handler(request: httpx.Request) -> httpx.Response:
        status, retry_after = pending.pop(0)
        headers = {"Retry-After": retry_after} if retry_after else {}
        if status == 200:
            return httpx.Response(200, json={"seq": 7, "map_version": 7})
        return httpx.Response(status, json={"detail": "busy"}, headers=headers)

    http = httpx.Client(transport=httpx.MockTransport(handler), base_url=BASE)
    client = MapClient(http, retries=2, max_retry_wait_s=5.0, sleep=slept.append)
    if final == 200:
        assert client.post_scan(make_scan([1.0], stamp=3.0)).seq == 7
    else:
        with pytest.raises(MapRequestError) as err:
            client.post_scan(make_scan([1.0], stamp=3.0))
        assert err.value.status == final
    assert slept == waits and not pending


@pytest.mark.parametrize(
    ("name", "value"), [("retries", -1), ("retries", True), ("max_retry_wait_s", -1)]
)
def test_bad_retry_settings_are_refused_by_name(name, value):
    http = httpx.Client(base_url=BASE)
    with pytest.raises(ValueError, match=f"^{name} must be"):
        MapClient(http, **{name: value})
