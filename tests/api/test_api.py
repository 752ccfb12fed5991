"""The HTTP API in-process (FastAPI TestClient): replies, bad input, roles, formats."""

import json
import math

import numpy as np
import pytest
from fastapi.testclient import TestClient
from server_helpers import JSON, scan_body, small_settings

from mapserver.api.app import create_app
from mapserver.client import MapClient
from mapserver.core.costvalues import LETHAL, UNKNOWN

UNIT, READER, ADMIN = "unit-secret", "reader-secret", "admin-secret"
TOKENS = [
    {"token": UNIT, "role": "unit", "units": ["u*"]},
    {"token": READER, "role": "reader"},
    {"token": ADMIN, "role": "admin"},
]


@pytest.fixture
def open_client(tmp_path):
    app = create_app(small_settings(tmp_path / "data", limits={"max_body_bytes": 200_000}))
    with TestClient(app) as client:
        yield client


@pytest.fixture
def secure_client(tmp_path):
    app = create_app(small_settings(tmp_path / "data", tokens=TOKENS))
    with TestClient(app) as client:
        yield client


def auth(token):
    return {"Authorization": f"Bearer {token}"}


def state(client, headers=None):
    """(map version, journal rows, costmap) — what a rejected request must leave as it was.
    The costmap is read as a client reads it (``costmap_read``: caught up to every scan
    fused), not the follower's costmap as it stands: its own thread may refresh that
    between two calls (``costmap_follower``), which is no change of the map."""
    service = client.app.state.service
    return service.version, service.journal.last_seq(), service.costmap_read().data.tobytes()


def test_a_scan_is_acknowledged_and_fused(open_client):
    reply = open_client.post("/v1/scans", json=scan_body())
    assert reply.status_code == 200
    assert reply.json() == {"seq": 1, "map_version": 1}
    meta = open_client.get("/v1/map/meta").json()
    assert meta["version"] == 1 and meta["stamp"] == 1.0
    assert meta["width"] == 200 and meta["origin"] == {"x": 0.0, "y": 0.0, "yaw": 0.0}
    cell = open_client.post("/v1/query/cells", json={"points": [[8.05, 5.05]]}).json()["cells"][0]
    assert cell["state"] == "occupied" and cell["cost"] == LETHAL and cell["age"] == 0.0


def test_a_no_return_reading_is_weak_free_evidence_out_to_the_no_return_range(open_client):
    for unit in ("u1", "u2", "u3", "u4", "u5", "u6"):  # one stamp: nothing fades
        body = scan_body(unit=unit, angle_min=0.0, angle_increment=0.001, ranges=[21.0, 21.0])
        assert open_client.post("/v1/scans", json=body).status_code == 200  # 21 > range_max
    meta = open_client.get("/v1/map/meta").json()["sensor_model"]
    assert (meta["p_miss_no_return"], meta["no_return_range"]) == (0.45, 1.0)
    points = [[5.55, 5.05], [5.95, 5.05], [6.25, 5.05]]  # 0.55, 0.95 and 1.25 m along +x
    near, edge, far = open_client.post("/v1/query/cells", json={"points": points}).json()["cells"]
    six = 1 / (1 + (0.55 / 0.45) ** 6)  # six no-return passes: p 0.2310, free (< 0.25)
    for cell in (near, edge):  # both within the 1 m reach
        assert cell["state"] == "free" and cell["p_occ"] == pytest.approx(six, abs=1e-6)
    assert far["state"] == "unknown" and far["last_observed"] is None  # beyond 1 m


def test_a_batch_is_acknowledged_scan_by_scan(open_client):
    scans = [scan_body(stamp=1.0), scan_body(stamp=1.0, unit="u2"), scan_body(stamp=2.0)]
    reply = open_client.post("/v1/scans/batch", json={"scans": scans})
    assert reply.status_code == 200
    acks = reply.json()["acks"]
    assert [a["seq"] for a in acks] == [1, 2, 3]
    assert all(a["map_version"] == 3 for a in acks)


BAD_SCANS = [
    ("nan pose", lambda b: b["pose"].update(x=math.nan), 422, "pose.x"),
    ("inf pose", lambda b: b["pose"].update(yaw=math.inf), 422, "pose.yaw"),
    ("empty ranges", lambda b: b.update(ranges=[]), 422, "ranges"),
    ("text in ranges", lambda b: b.update(ranges=[1.0, "x"]), 422, "ranges[1]"),
    ("negative increment", lambda b: b.update(angle_increment=-0.01), 422, "angle_increment"),
    ("range_min above range_max", lambda b: b.update(range_min=30.0), 422, "range_max"),
    ("wrong frame", lambda b: b.update(frame="odom"), 422, "frame"),
    ("sensor off the map", lambda b: b["pose"].update(x=25.0), 422, "pose"),
    ("backwards stamp", lambda b: b.update(stamp=0.5), 409, "stamp"),
    ("too many beams", lambda b: b.update(ranges=[1.0] * 20000), 422, "ranges"),
    ("ranges past one turn", lambda b: b.update(ranges=[1.0] * 700), 422, "ranges"),
    ("poison pose_std", lambda b: b.update(pose_std={"xy": 1e200}), 422, "pose_std.xy"),
]


@pytest.mark.parametrize("name, corrupt, status, field", BAD_SCANS, ids=[b[0] for b in BAD_SCANS])
def test_bad_scans_get_their_4xx_and_change_nothing(open_client, name, corrupt, status, field):
    assert open_client.post("/v1/scans", json=scan_body(stamp=1.0)).status_code == 200
    before = state(open_client)
    body = scan_body(stamp=2.0)
    corrupt(body)
    reply = open_client.post("/v1/scans", content=json.dumps(body), headers=JSON)
    assert reply.status_code == status, reply.text
    assert reply.json()["detail"].startswith(field)
    assert state(open_client) == before


def test_a_batch_with_one_bad_scan_changes_nothing(open_client):
    before = state(open_client)
    scans = [scan_body(stamp=1.0), scan_body(stamp=2.0, frame="odom")]
    reply = open_client.post("/v1/scans/batch", json={"scans": scans})
    assert reply.status_code == 422 and reply.json()["detail"].startswith("scans[1].frame")
    assert state(open_client) == before


def test_a_huge_body_is_refused_before_it_is_read(open_client):
    before = state(open_client)
    body = scan_body(ranges=[1.0] * 15000)  # ~ 60 kB ... beyond the 200 kB limit below
    body["padding"] = "x" * 300_000
    reply = open_client.post("/v1/scans", content=json.dumps(body), headers=JSON)
    assert reply.status_code == 413 and reply.json()["detail"].startswith("body")
    assert state(open_client) == before


def test_malformed_json_is_a_400(open_client):
    reply = open_client.post("/v1/scans", content=b"{not json", headers=JSON)
    assert reply.status_code == 400 and reply.json()["detail"].startswith("body")


@pytest.mark.parametrize(
    "headers, status",
    [({}, 401), (auth("wrong"), 401), (auth(READER), 403), (auth(UNIT), 200), (auth(ADMIN), 200)],
)
def test_posting_scans_needs_a_unit_or_admin_token(secure_client, headers, status):
    before = state(secure_client)
    reply = secure_client.post("/v1/scans", json=scan_body(), headers=headers)
    assert reply.status_code == status
    if status != 200:
        assert reply.json()["detail"].startswith("authorization")
        assert state(secure_client) == before


@pytest.mark.parametrize(
    "headers, status", [({}, 401), (auth(UNIT), 403), (auth(READER), 200), (auth(ADMIN), 200)]
)
def test_reading_needs_a_reader_or_admin_token(secure_client, headers, status):
    assert secure_client.get("/v1/costmap?format=raw", headers=headers).status_code == status
    assert secure_client.get("/v1/map/meta", headers=headers).status_code == status


def test_raw_costmap_has_the_contract_headers_and_bytes(open_client):
    open_client.post("/v1/scans", json=scan_body())
    reply = open_client.get("/v1/costmap", params={"format": "raw"})
    h = reply.headers
    assert (h["X-Map-Width"], h["X-Map-Height"], h["X-Map-Resolution"]) == ("200", "100", "0.1")
    assert (h["X-Map-Origin-X"], h["X-Map-Origin-Y"]) == ("0.0", "0.0")
    assert (h["X-Map-Version"], h["X-Map-Stamp"]) == ("1", "1.0")
    costs = np.frombuffer(reply.content, np.uint8).reshape(100, 200)
    assert costs[50, 80] == LETHAL and costs[0, 0] == UNKNOWN
    as_json = open_client.get("/v1/costmap").json()
    assert as_json["data"] == costs.ravel().tolist() and as_json["info"]["version"] == 1
    png = open_client.get("/v1/costmap", params={"format": "png"})
    assert png.headers["content-type"] == "image/png" and png.content[:4] == b"\x89PNG"


def test_occupancy_map_is_int8_with_unknown_minus_one(open_client):
    open_client.post("/v1/scans", json=scan_body())
    grid = np.frombuffer(open_client.get("/v1/map?format=raw").content, np.int8).reshape(100, 200)
    assert grid[50, 80] == 70  # one hit: p = 0.7
    assert grid[50, 60] == 40  # one pass: p = 0.4
    assert grid[0, 0] == -1


def test_costmap_at_a_later_stamp_shows_decay(open_client):
    for i in range(3):
        open_client.post("/v1/scans", json=scan_body(stamp=float(i)))
    now = np.frombuffer(open_client.get("/v1/costmap?format=raw").content, np.uint8)
    later = open_client.get("/v1/costmap", params={"format": "raw", "at": 500.0})
    assert later.headers["X-Map-Stamp"] == "500.0"
    assert np.count_nonzero(now == LETHAL) > 0
    assert np.count_nonzero(np.frombuffer(later.content, np.uint8) == LETHAL) == 0


@pytest.mark.parametrize(
    "path, params, field",
    [
        ("/v1/costmap", {"format": "xml"}, "query.format"),
        ("/v1/map", {"at": "nan"}, "query.at"),
        ("/v1/costmap/updates", {"since": "-1"}, "query.since"),
        ("/v1/costmap/updates", {}, "query.since"),
    ],
)
def test_bad_query_parameters_name_the_field(open_client, path, params, field):
    reply = open_client.get(path, params=params)
    assert reply.status_code == 422 and reply.json()["detail"].startswith(field)


def test_segment_queries_report_blocking_and_unknown(open_client):
    open_client.post("/v1/scans", json=scan_body())
    reply = open_client.post(
        "/v1/query/segments", json={"segments": [[5.0, 5.05, 7.0, 5.05], [5.0, 5.05, 9.5, 5.05]]}
    )
    clear, blocked = reply.json()["segments"]
    assert clear["blocked"] is False and clear["first_blocked"] is None
    assert blocked["blocked"] is True and blocked["first_blocked"][0] < 8.0
    bad = open_client.post("/v1/query/segments", json={"segments": [[1.0, 2.0, 3.0]]})
    assert bad.status_code == 422 and bad.json()["detail"].startswith("segments.0")


def test_updates_since_the_current_version_are_empty_and_old_ones_full(tmp_path):
    # the costmap refreshed after every scan: four versions, of which two are held
    settings = small_settings(
        tmp_path / "d", journal={"history": 2}, reads={"costmap_refresh_s": 0}
    )
    with TestClient(create_app(settings)) as client:
        for i in range(4):
            client.post("/v1/scans", json=scan_body(stamp=float(i), x=3.0 + i))
        assert client.get("/v1/costmap/updates", params={"since": 4}).json() == {
            "version": 4, "stamp": 3.0, "full": False, "patches": []
        }  # fmt: skip
        assert client.get("/v1/costmap/updates", params={"since": 0}).json()["full"] is True


def test_health_and_metrics(open_client):
    open_client.post("/v1/scans", json=scan_body())
    assert open_client.get("/healthz").json() == {"status": "ok", "version": 1}
    text = open_client.get("/metrics").text
    assert "fleetmap_scans_fused_total 1.0" in text
    assert "fleetmap_journal_bytes" in text and "fleetmap_request_seconds_bucket" in text
    for stage in ("queued", "journal", "fuse_wait", "fuse", "answered"):
        assert f'fleetmap_ingest_stage_seconds_count{{stage="{stage}"}} 1.0' in text
        assert f'fleetmap_ingest_stage_seconds_bucket{{le="+Inf",stage="{stage}"}} 1.0' in text
    assert "fleetmap_ingest_group_scans_sum 1.0" in text
    assert open_client.get("/openapi.json").json()["paths"]["/v1/scans"]["post"]


def test_patches_followed_by_a_client_reproduce_the_costmap(open_client):
    client = MapClient(open_client)
    local = client.costmap()
    for i in range(6):
        open_client.post("/v1/scans", json=scan_body(stamp=float(i), x=3.0 + 2 * i, y=4.0 + i / 2))
        local = client.follow_costmap(local)
        full = client.costmap()
        assert local.version == full.version == i + 1
        assert np.array_equal(local.data, full.data)


def test_plan_finds_a_path_around_an_obstacle_on_the_current_costmap(open_client):
    for i in range(3):  # a wall of returns at x = 8 m seen from (5, 5)
        open_client.post("/v1/scans", json=scan_body(stamp=float(i)))
    reply = open_client.post(
        "/v1/plan", json={"start": [5.0, 5.0], "goal": [6.5, 5.0], "algorithm": "dijkstra"}
    )
    plan = reply.json()
    assert reply.status_code == 200 and plan["found"] is True
    assert plan["path"][0] == pytest.approx([5.05, 5.05]) and plan["map_version"] == 3
    assert plan["length"] == pytest.approx(1.5, abs=0.01) and plan["min_clearance"] > 0.5
    through_wall = open_client.post(
        "/v1/plan", json={"start": [5.0, 5.0], "goal": [12.0, 5.0], "allow_unknown": False}
    ).json()
    assert through_wall["found"] is False


def test_plan_refuses_points_off_the_map_naming_the_field(open_client):
    reply = open_client.post("/v1/plan", json={"start": [5.0, 5.0], "goal": [50.0, 5.0]})
    assert reply.status_code == 422 and reply.json()["detail"].startswith(
        "goal: must be on the map"
    )
    reply = open_client.post("/v1/plan", json={"start": [5.0], "goal": [6.0, 5.0]})
    assert reply.status_code == 422 and reply.json()["detail"].startswith("start")
