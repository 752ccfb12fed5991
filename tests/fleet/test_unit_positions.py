"""Unit poses, paths and freezes published for the viewer: ``POST /v1/units`` and
``GET /v1/units`` (validation, roles, all-or-nothing) and MapClient's typed calls."""

import json
import math

import pytest
from fastapi.testclient import TestClient
from server_helpers import JSON, small_settings

from mapserver.api.app import create_app
from mapserver.api.unit_board import UnitBoard, UnitBoardError
from mapserver.client import ACTIVITIES, Forbidden, InvalidRequest, MapClient, UnitPose, UnitState
from mapserver.core.scan import Pose2D

UNIT, READER, ADMIN = "unit-secret", "reader-secret", "admin-secret"
TOKENS = [
    {"token": UNIT, "role": "unit", "units": ["u*"]},
    {"token": READER, "role": "reader"},
    {"token": ADMIN, "role": "admin"},
]


def auth(token):
    return {"Authorization": f"Bearer {token}"}


def unit(unit_id="u1", stamp=1.0, **fields):
    body = {
        "unit_id": unit_id,
        "stamp": stamp,
        "pose": {"x": 2.0, "y": 3.0, "yaw": 0.5},
        "path": [[2.0, 3.0], [4.0, 3.0], [4.0, 6.5]],
        "frozen": False,
        "reason": None,
        "activity": "moving",
    }
    body.update(fields)
    return body


@pytest.fixture
def client(tmp_path):
    app = create_app(small_settings(tmp_path / "data", tokens=TOKENS))
    with TestClient(app) as test_client:
        yield test_client


def board(client):
    return client.get("/v1/units", headers=auth(READER)).json()["units"]


def test_the_latest_state_of_each_unit_is_kept_and_read_back_in_unit_order(client):
    first = client.post("/v1/units", json={"units": [unit("u2"), unit("u1")]}, headers=auth(UNIT))
    assert first.status_code == 200 and first.json() == {"accepted": 2, "tracked": 2}
    frozen = unit(
        "u2", stamp=2.0, path=[], frozen=True, reason="no path: aisle 3 blocked", activity="frozen"
    )
    assert client.post("/v1/units", json={"units": [frozen]}, headers=auth(ADMIN)).json() == {
        "accepted": 1,
        "tracked": 2,
    }
    assert board(client) == [unit("u1"), frozen]


BAD_POSTS = [
    ("no units", {"units": []}, 422, "units"),
    ("not an object", [unit()], 422, "body"),
    ("missing pose", {"units": [{"unit_id": "u1", "stamp": 1.0}]}, 422, "units.0.pose"),
    ("nan x", {"units": [unit(pose={"x": math.nan, "y": 0.0, "yaw": 0.0})]}, 422, "units.0.pose.x"),
    ("text stamp", {"units": [unit(stamp="1.0")]}, 422, "units.0.stamp"),
    ("empty id", {"units": [unit(unit_id="")]}, 422, "units.0.unit_id"),
    ("short point", {"units": [unit(path=[[1.0, 2.0], [3.0]])]}, 422, "units.0.path.1"),
    ("infinite point", {"units": [unit(path=[[1.0, math.inf]])]}, 422, "units.0.path.0.1"),
    ("number frozen", {"units": [unit(frozen=1)]}, 422, "units.0.frozen"),
    ("unknown field", {"units": [unit(speed=1.0)]}, 422, "units.0.speed"),
    ("twice in a post", {"units": [unit(), unit("u2"), unit()]}, 422, "units[2].unit_id"),
    ("older stamp", {"units": [unit("u3"), unit(stamp=0.5)]}, 409, "units[1].stamp"),
    ("long reason", {"units": [unit(reason="x" * 201)]}, 422, "units.0.reason"),
    ("unknown activity", {"units": [unit(activity="flying")]}, 422, "units.0.activity"),
    ("number activity", {"units": [unit(activity=1)]}, 422, "units.0.activity"),
    ("frozen but moving", {"units": [unit(frozen=True)]}, 422, "units.0.activity"),
    (
        "frozen activity, frozen false",
        {"units": [unit(activity="frozen")]},
        422,
        "units.0.activity",
    ),
]


@pytest.mark.parametrize("name, body, status, field", BAD_POSTS, ids=[b[0] for b in BAD_POSTS])
def test_a_bad_post_names_the_field_and_changes_nothing(client, name, body, status, field):
    assert client.post("/v1/units", json={"units": [unit()]}, headers=auth(UNIT)).status_code == 200
    before = board(client)
    reply = client.post("/v1/units", content=json.dumps(body), headers=auth(UNIT) | JSON)
    assert reply.status_code == status, reply.text
    assert reply.json()["detail"].startswith(field), reply.json()
    assert board(client) == before


def test_a_bad_activity_is_refused_naming_the_field_the_value_and_the_choices(client):
    reply = client.post("/v1/units", json={"units": [unit(activity="flying")]}, headers=auth(UNIT))
    assert reply.status_code == 422
    assert reply.json()["detail"] == (
        "units.0.activity: Input should be 'moving', 'waiting', 'frozen', 'broken_down', "
        "'dwelling' or 'idle', got 'flying'"
    )
    clash = client.post("/v1/units", json={"units": [unit(frozen=True)]}, headers=auth(UNIT))
    assert clash.json()["detail"] == (
        "units.0.activity: must be 'frozen' exactly when frozen is true (frozen is true), "
        "got 'moving'"
    )


@pytest.mark.parametrize("activity", ACTIVITIES)
def test_each_activity_is_kept_and_frozen_follows_from_it_when_left_out(client, activity):
    body = unit(activity=activity)
    del body["frozen"]
    assert client.post("/v1/units", json={"units": [body]}, headers=auth(UNIT)).status_code == 200
    assert board(client) == [{**body, "frozen": activity == "frozen"}]


def test_an_older_fleet_that_sends_no_activity_still_publishes(client):
    old = unit(frozen=True, reason="no lane to (1.00, 2.00)")
    del old["activity"]
    assert client.post("/v1/units", json={"units": [old]}, headers=auth(UNIT)).status_code == 200
    assert board(client) == [{**old, "activity": None}]
    schema = client.get("/openapi.json").json()["components"]["schemas"]["UnitState"]
    assert "activity" not in schema["required"]
    choices = schema["properties"]["activity"]["anyOf"]
    assert choices == [{"enum": list(ACTIVITIES), "type": "string"}, {"type": "null"}]


def test_malformed_json_is_a_400_and_an_oversized_body_a_413(tmp_path):
    settings = small_settings(tmp_path / "d", limits={"max_body_bytes": 10_000})
    with TestClient(create_app(settings)) as client:
        assert client.post("/v1/units", content=b"{units", headers=JSON).status_code == 400
        huge = {"units": [unit(path=[[1.0, 2.0]] * 2000)]}
        reply = client.post("/v1/units", json=huge)
        assert reply.status_code == 413 and reply.json()["detail"].startswith("body")
        assert client.get("/v1/units").json() == {"units": []}


@pytest.mark.parametrize(
    "token, post_status, read_status",
    [
        (None, 401, 401),
        ("wrong", 401, 401),
        (UNIT, 200, 403),
        (READER, 403, 200),
        (ADMIN, 200, 200),
    ],
)
def test_units_post_with_a_unit_token_and_read_with_a_reader_token(
    client, token, post_status, read_status
):
    headers = auth(token) if token else {}
    reply = client.post("/v1/units", json={"units": [unit()]}, headers=headers)
    assert reply.status_code == post_status
    if post_status != 200:
        assert reply.json()["detail"].startswith("authorization")
        assert board(client) == []
    assert client.get("/v1/units", headers=headers).status_code == read_status


def test_the_board_refuses_new_units_beyond_its_capacity_but_updates_known_ones():
    from mapserver.api.schemas import UnitState as Body

    states = Body.model_validate
    small = UnitBoard(capacity=2)
    assert small.publish([states(unit("a")), states(unit("b"))]) == 2
    with pytest.raises(UnitBoardError) as refused:
        small.publish([states(unit("a", stamp=2.0)), states(unit("c"))])
    assert refused.value.status == 409 and refused.value.detail.startswith("units[1].unit_id")
    assert [s.stamp for s in small.latest()] == [1.0, 1.0]  # "a" was not updated either
    assert small.publish([states(unit("b", stamp=3.0))]) == 2


def test_map_client_publishes_and_reads_typed_unit_states(client):
    states = [
        UnitState.of("u1", 1.0, Pose2D(2.0, 3.0, 0.5), ((2.0, 3.0), (4.0, 3.0))),
        UnitState.of("u2", 1.5, Pose2D(8.0, 1.0, -1.0), frozen=True, reason="lane a3 blocked"),
        UnitState.of("u3", 1.5, Pose2D(5.0, 1.0, 0.0), activity="frozen", reason="no path"),
        UnitState.of("u4", 1.5, Pose2D(6.0, 1.0, 0.0), activity="dwelling"),
    ]
    assert [(s.frozen, s.activity) for s in states] == [
        (False, None),
        (True, None),
        (True, "frozen"),
        (False, "dwelling"),
    ]
    assert MapClient(client, token=UNIT).publish_units(states) == 4
    assert MapClient(client, token=READER).units() == states
    assert MapClient(client, token=UNIT).publish_units([]) == 0


def test_map_client_raises_the_servers_refusals_and_checks_fields_locally(client):
    reader = MapClient(client, token=READER)
    with pytest.raises(Forbidden):
        reader.publish_units([UnitState.of("u1", 1.0, Pose2D(0.0, 0.0, 0.0))])
    # the wire model checks a state where it is made ...
    with pytest.raises(ValueError, match=r"stamp\n  Input should be a finite number"):
        UnitState.of("u1", math.nan, Pose2D(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"activity\n  must be 'frozen' exactly when frozen"):
        UnitState.of("u1", 1.0, Pose2D(0.0, 0.0, 0.0), frozen=True, activity="waiting")
    with pytest.raises(ValueError, match=r"path\.1\n  List should have at least 2 items"):
        UnitState.of("u1", 1.0, Pose2D(0.0, 0.0, 0.0), ((1, 2), (3,)))
    # ... and the server checks it again: one left unchecked is refused, naming the field
    unchecked = UnitState.model_construct(
        unit_id="u1", stamp=math.nan, pose=UnitPose(x=0.0, y=0.0, yaw=0.0), path=[]
    )
    writer = MapClient(client, token=UNIT)
    with pytest.raises(InvalidRequest) as refused:
        writer.publish_units([unchecked])
    assert refused.value.status == 422 and "units.0.stamp" in refused.value.detail
    with pytest.raises(TypeError, match=r"units\[0\] must be a UnitState"):
        writer.publish_units([unit()])
