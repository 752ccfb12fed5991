"""Unit tokens are bound to unit ids: a unit token posts scans and unit states only as the
units it lists (exact ids or ``prefix*``), admin as anyone; settings refuse a unit token
that lists none."""

import pytest
from fastapi.testclient import TestClient
from server_helpers import scan_body, small_settings

from mapserver.api.app import create_app
from mapserver.service.settings import SettingsError, load_settings

U1, DOCK, ADMIN = "u1-secret", "dock-secret", "admin-secret"
TOKENS = [
    {"token": U1, "role": "unit", "name": "robot one", "units": ["u1"]},
    {"token": DOCK, "role": "unit", "units": ["dock-*"]},
    {"token": ADMIN, "role": "admin"},
]


def auth(token):
    return {"Authorization": f"Bearer {token}"}


def unit_state(unit_id, stamp=1.0):
    return {"unit_id": unit_id, "stamp": stamp, "pose": {"x": 1.0, "y": 1.0, "yaw": 0.0}}


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(small_settings(tmp_path / "data", tokens=TOKENS))) as test_client:
        yield test_client


def journal(client):
    service = client.app.state.service
    return service.version, service.journal.last_seq()


def test_a_unit_token_posts_as_its_own_unit_and_not_as_another(client):
    assert client.post("/v1/scans", json=scan_body(unit="u1"), headers=auth(U1)).status_code == 200
    before = journal(client)
    # the probe: a stamp of 1e308 as u7 would lock the real u7 out
    reply = client.post("/v1/scans", json=scan_body(stamp=1e308, unit="u7"), headers=auth(U1))
    assert reply.status_code == 403
    assert reply.json()["detail"] == (
        "unit_id: token 'robot one' may not post as unit 'u7' (it may post as u1)"
    )
    assert journal(client) == before
    assert (
        client.post("/v1/scans", json=scan_body(unit="u7"), headers=auth(ADMIN)).status_code == 200
    )


def test_a_prefix_covers_every_id_that_starts_with_it_and_only_those(client):
    for unit_id, status in (("dock-1", 200), ("dock-", 200), ("dock", 403), ("u1", 403)):
        reply = client.post("/v1/scans", json=scan_body(unit=unit_id), headers=auth(DOCK))
        assert reply.status_code == status, (unit_id, reply.text)
    refused = client.post("/v1/scans", json=scan_body(unit="u1"), headers=auth(DOCK)).json()
    assert refused["detail"].startswith("unit_id: token 'tokens[1]' may not post as unit 'u1'")


def test_a_batch_with_one_foreign_scan_is_refused_whole(client):
    before = journal(client)
    scans = [scan_body(stamp=1.0), scan_body(stamp=2.0), scan_body(stamp=3.0, unit="u2")]
    reply = client.post("/v1/scans/batch", json={"scans": scans}, headers=auth(U1))
    assert reply.status_code == 403
    assert reply.json()["detail"].startswith("scans[2].unit_id: token 'robot one'")
    assert journal(client) == before
    good = client.post("/v1/scans/batch", json={"scans": scans[:2]}, headers=auth(U1))
    assert [a["seq"] for a in good.json()["acks"]] == [1, 2]


def test_unit_states_are_bound_to_the_token_units_too(client):
    posted = {"units": [unit_state("u1"), unit_state("u9")]}
    reply = client.post("/v1/units", json=posted, headers=auth(U1))
    assert reply.status_code == 403 and reply.json()["detail"].startswith("units[1].unit_id:")
    assert client.get("/v1/units", headers=auth(ADMIN)).json()["units"] == []
    own = client.post("/v1/units", json={"units": [unit_state("u1")]}, headers=auth(U1))
    assert own.json() == {"accepted": 1, "tracked": 1}
    assert client.post("/v1/units", json=posted, headers=auth(ADMIN)).status_code == 200


@pytest.mark.parametrize(
    "token, problem",
    [
        ({"token": "t", "role": "unit"}, "tokens[0].units: a unit token must list the unit ids"),
        ({"token": "t", "role": "unit", "units": []}, "tokens[0].units: a unit token must list"),
        ({"token": "t", "role": "unit", "units": ["u*1"]}, "tokens[0].units: each entry must be"),
        ({"token": "t", "role": "unit", "units": [""]}, "tokens[0].units: each entry must be"),
        ({"token": "t", "role": "reader", "units": ["u1"]}, "tokens[0].units: only unit tokens"),
        ({"token": "t", "role": "admin", "units": ["*"]}, "tokens[0].units: only unit tokens"),
    ],
)
def test_settings_refuse_unit_lists_that_are_missing_or_malformed(token, problem):
    with pytest.raises(SettingsError) as caught:
        load_settings(None, {"tokens": [token]})
    assert caught.value.problems[0].startswith(problem), caught.value.problems


def test_a_star_lets_one_token_post_for_a_whole_fleet():
    settings = load_settings(None, {"tokens": [{"token": "t", "role": "unit", "units": ["*"]}]})
    token = settings.token_table()["t"]
    assert token.name == "tokens[0]"
    assert all(token.may_post_as(unit_id) for unit_id in ("u1", "x", "*"))
