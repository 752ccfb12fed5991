"""One bad client must not damage what the rest of the fleet sees: clocks that lead,
retries, extra fields, numbers beyond float range (in-process app, real journal)."""

import json
import math

import numpy as np
import pytest
from fastapi.testclient import TestClient
from server_helpers import scan_body, small_settings

from mapserver.api.app import create_app
from mapserver.core.scan import Scan

# The endpoints of scan_body's beams 80..120 (3 m from (5, 5)): cells u1..u3 see occupied.
WALL_POINTS = [
    [5.0 + 3.0 * math.cos(-1.0 + 0.01 * i), 5.0 + 3.0 * math.sin(-1.0 + 0.01 * i)]
    for i in range(80, 121)
]


def fleet_scans(client, seconds=10.0):
    """u1..u3 scan the same wall at 1 Hz from stamp 0 to ``seconds``."""
    for k in range(int(seconds) + 1):
        for unit in ("u1", "u2", "u3"):
            reply = client.post("/v1/scans", json=scan_body(stamp=float(k), unit=unit))
            assert reply.status_code == 200, reply.text


def wall_cells(client):
    cells = client.post("/v1/query/cells", json={"points": WALL_POINTS}).json()["cells"]
    return [(c["state"], c["p_occ"], c["cost"], c["last_observed"]) for c in cells]


@pytest.fixture
def data_dir(tmp_path):
    return tmp_path / "data"


def app_on(data_dir, **overrides):
    return TestClient(create_app(small_settings(data_dir, **overrides)))


@pytest.mark.parametrize("lead", [300.0, 1e15])
def test_a_unit_far_ahead_is_refused_and_changes_no_cell(data_dir, lead):
    with app_on(data_dir) as client:
        fleet_scans(client)
        before, meta = wall_cells(client), client.get("/v1/map/meta").json()
        assert {state for state, *_ in before} == {"occupied"}
        reply = client.post("/v1/scans", json=scan_body(stamp=10.0 + lead, unit="u4", y=4.0))
        assert reply.status_code == 422
        detail = reply.json()["detail"]
        assert detail.startswith(f"stamp: {10.0 + lead!r} is ") and "max_lead_s = 5 s" in detail
        reference = "the server's clock" if lead > 1e9 else "simulated time (1"
        assert reference in detail and "this unit's clock runs" in detail
        assert wall_cells(client) == before
        assert client.get("/v1/map/meta").json() == meta
        ok = client.post("/v1/scans", json=scan_body(stamp=11.0, unit="u4", y=4.0))
        assert ok.status_code == 200  # the same unit, on time again, is welcome
    with app_on(data_dir) as client:  # and after a restart
        assert client.get("/v1/map/meta").json()["stamp"] == 11.0
        assert [c[0] for c in wall_cells(client)] == ["occupied"] * len(WALL_POINTS)


def test_a_declared_clock_stops_a_unit_walking_the_time_forward(data_dir):
    with app_on(data_dir) as client:
        fleet_scans(client, seconds=2.0)
        assert client.put("/v1/clock", json={"now": 2.0}).json()["reference"] == "declared"
        statuses = [
            client.post("/v1/scans", json=scan_body(stamp=2.0 + 4.0 * k, unit="u9")).status_code
            for k in range(1, 5)
        ]
        assert statuses == [200, 422, 422, 422]  # 6 s leads 2 s by 4; 10 s would lead by 8
        assert client.get("/v1/map/meta").json()["stamp"] == 6.0


def test_without_a_declared_clock_a_walk_is_bounded_by_the_lead_per_step(data_dir):
    """The residue of docs/map-time.md: with no clock declared, a unit may lead the map's
    simulated time by max_lead_s (plus max_sim_rate x the wall time since it advanced,
    nearly 0 here) with each scan, and no further."""
    with app_on(data_dir, clock={"max_sim_rate": 1e-6}) as client:
        fleet_scans(client, seconds=2.0)
        posted = {
            stamp: client.post("/v1/scans", json=scan_body(stamp=stamp, unit="u9")).status_code
            for stamp in (6.9, 11.8, 17.0, 16.7)
        }
        assert posted == {6.9: 200, 11.8: 200, 17.0: 422, 16.7: 200}


def test_a_retry_returns_the_original_ack_and_journals_nothing(data_dir):
    with app_on(data_dir) as client:
        first = client.post("/v1/scans", json=scan_body(stamp=1.0))
        client.post("/v1/scans", json=scan_body(stamp=1.0, unit="u2"))
        again = client.post("/v1/scans", json=scan_body(stamp=1.0))
        assert again.status_code == 200 and again.json() == first.json() == {
            "seq": 1,
            "map_version": 1,
        }
        assert client.app.state.service.journal.last_seq() == 2
        other = client.post("/v1/scans", json=scan_body(stamp=1.0, ranges=[4.0] * 200))
        assert other.status_code == 409
        assert "already sent another scan at stamp 1.0" in other.json()["detail"]
        batch = [scan_body(stamp=1.0), scan_body(stamp=2.0)]  # a retry and a new scan
        acks = client.post("/v1/scans/batch", json={"scans": batch}).json()["acks"]
        assert [a["seq"] for a in acks] == [1, 3]
        twice = client.post("/v1/scans/batch", json={"scans": [scan_body(stamp=5.0)] * 2})
        assert [a["seq"] for a in twice.json()["acks"]] == [4, 4]
    with app_on(data_dir) as client:  # after a restart the journal answers
        again = client.post("/v1/scans", json=scan_body(stamp=5.0))
        assert again.status_code == 200 and again.json()["seq"] == 4
        assert client.post("/v1/scans", json=scan_body(stamp=5.0, y=6.0)).status_code == 409
        assert client.app.state.service.journal.last_seq() == 4


def test_unknown_fields_are_refused_not_journaled_and_deep_nesting_is_refused(data_dir):
    nested = '{"x":' * 20 + "{}" + "}" * 20
    deep = '{"x":' * 1000 + "{}" + "}" * 1000  # json.dumps could not even write it back
    with app_on(data_dir) as client:

        def post(extra):
            body = json.dumps(scan_body(stamp=1.0))[:-1] + ', "extra": ' + extra + "}"
            return client.post(
                "/v1/scans", content=body, headers={"Content-Type": "application/json"}
            )

        refused = post(deep)
        assert refused.status_code == 400 and refused.json()["detail"].startswith("body")
        unknown = post(nested)  # parsed, then refused by name (scan_fields)
        assert unknown.status_code == 422
        assert unknown.json()["detail"].startswith("extra: not a field of a scan (expected")
        assert client.app.state.service.journal.last_seq() == 0
        assert client.post("/v1/scans", json=scan_body(stamp=1.0)).status_code == 200
        (seq, stored), *_ = client.app.state.service.journal.scans_after(0)
    assert Scan.from_dict(stored).digest() == Scan.from_dict(scan_body(stamp=1.0)).digest()


@pytest.mark.parametrize(
    "field, value, status, detail",
    [
        ("stamp", 10**400, 400, "body: not valid JSON (integer 1000"),
        ("pose", {"x": 10**400, "y": 5.0, "yaw": 0.0}, 400, "body: not valid JSON (integer"),
        ("range_max", True, 422, "range_max: must be a finite number, got True"),
    ],
)
def test_numbers_beyond_float_range_and_booleans_are_refused(
    data_dir, field, value, status, detail
):
    with app_on(data_dir) as client:
        body = json.dumps(scan_body(**{field: value}))
        reply = client.post("/v1/scans", content=body, headers={"Content-Type": "application/json"})
        assert reply.status_code == status
        assert reply.json()["detail"].startswith(detail)
        assert client.app.state.service.journal.last_seq() == 0


@pytest.mark.parametrize("field", ["stamp", "angle_min", "range_max"])
def test_a_scan_file_number_beyond_float_range_is_refused_by_name(field):
    with pytest.raises(ValueError, match=rf"^{field}: must be a finite number"):
        Scan.from_dict(scan_body(**{field: 10**400}))


def test_a_range_beyond_float_range_is_refused_by_index():
    ranges = [3.0] * 5 + [10**400] + [3.0] * 4
    with pytest.raises(ValueError, match=r"ranges\[5\]: must be a number"):
        Scan.from_dict(scan_body(ranges=ranges))


def test_digests_tell_scans_apart_and_nans_alike():
    a = Scan.from_dict(scan_body(ranges=[None, 3.0]))
    b = Scan.from_dict(scan_body(ranges=[float("nan"), 3.0]))
    c = Scan.from_dict(scan_body(ranges=[3.0, 3.0]))
    assert a.digest() == b.digest() != c.digest()
    assert np.isnan(a.journal_record()["ranges"][0])


def test_an_old_journal_with_a_stamp_far_ahead_replays_without_it(data_dir):
    with app_on(data_dir) as client:
        fleet_scans(client)
        before = wall_cells(client)
        service = client.app.state.service
        # as a server before the clock rule would have journaled it
        service.journal.append([Scan.from_dict(scan_body(stamp=1e15, unit="u7")).journal_record()])
        bad_seq = service.journal.last_seq()
    with app_on(data_dir) as client:
        service = client.app.state.service
        assert wall_cells(client) == before
        assert client.get("/v1/map/meta").json()["stamp"] == 10.0
        assert [row[0] for row in service.journal.quarantined_rows()] == [bad_seq]
        assert "ahead of the server's clock at start-up" in service.journal.quarantined_rows()[0][3]
        assert "fleetmap_journal_quarantined 1.0" in client.get("/metrics").text
        ok = client.post("/v1/scans", json=scan_body(stamp=10.5, unit="u7"))
        assert ok.status_code == 200  # the real u7 is not locked out


@pytest.mark.parametrize(
    "poison, field",
    [
        ({"pose_std": {"xy": 1e200, "yaw": 0.0}}, "pose_std.xy"),  # overflowed the weighting
        ({"pose": {"x": 5.0, "y": 5.0, "yaw": 1.7e308}, "angle_min": 1.7e308}, "pose.yaw"),
    ],
)
def test_a_poison_scan_is_refused_and_the_server_restarts_to_the_same_map(data_dir, poison, field):
    with app_on(data_dir) as client:
        fleet_scans(client, seconds=2.0)
        reply = client.post("/v1/scans", json=scan_body(stamp=2.5, unit="u9", **poison))
        assert reply.status_code == 422 and reply.json()["detail"].startswith(field)
        fleet_scans_after = client.post("/v1/scans", json=scan_body(stamp=3.0))
        assert fleet_scans_after.status_code == 200
        before, meta = wall_cells(client), client.get("/v1/map/meta").json()
    with app_on(data_dir) as client:
        assert wall_cells(client) == before
        assert client.get("/v1/map/meta").json() == meta
        assert client.app.state.service.journal.quarantined == 0
