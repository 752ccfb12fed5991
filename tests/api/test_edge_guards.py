"""The server's edge in-process: content types (415), loopback Host and Origin for an open
server (403), body bounds on every route (413), bounded metrics labels, strict numbers,
and JSON that nests too deep or holds huge integers (4xx, never 500)."""

import json

import pytest
from fastapi import HTTPException
from fastapi.testclient import TestClient
from hypothesis import given
from hypothesis import strategies as st
from server_helpers import JSON, limited_client, scan_body, small_settings  # noqa: F401

from mapserver.api.app import create_app
from mapserver.api.body import MAX_DEPTH, parse_json
from mapserver.api.guards import LocalOnlyMiddleware
from mapserver.service.settings import load_settings

PLAN = {"start": [1.0, 1.0], "goal": [2.0, 2.0]}
HUGE = "1" + "0" * 400  # 10^400: a JSON integer beyond the float range


@pytest.fixture
def client(limited_client):  # noqa: F811 (the fixture imported from server_helpers)
    return limited_client


def journal(client):
    service = client.app.state.service
    return service.version, service.journal.last_seq()


@pytest.mark.parametrize("path", ["/v1/scans", "/v1/scans/batch", "/v1/units", "/v1/plan"])
def test_a_post_not_declared_json_is_a_415_and_changes_nothing(client, path):
    before = journal(client)
    for content_type in ("text/plain", None, "application/x-www-form-urlencoded"):
        headers = {"content-type": content_type} if content_type else {}
        reply = client.post(path, content=json.dumps(scan_body()), headers=headers)
        assert reply.status_code == 415
        also = " (or application/vnd.fleetmap.scan)" if path.startswith("/v1/scans") else ""
        assert reply.json() == {
            "detail": f"content-type: must be application/json{also}, got {content_type!r}"
        }
    binary = {"content-type": "application/vnd.fleetmap.scan"}
    if not path.startswith("/v1/scans"):  # the binary encoding is for scans only
        assert client.post(path, content=b"FMSC", headers=binary).status_code == 415
    assert journal(client) == before
    charset = {"content-type": "Application/JSON; charset=utf-8"}
    if path == "/v1/scans":
        assert client.post(path, content=json.dumps(scan_body()), headers=charset).is_success


@pytest.mark.parametrize(
    "headers, field",
    [
        ({"origin": "http://evil.example"}, "origin"),
        ({"origin": "http://127.0.0.1.evil.example:8700"}, "origin"),
        ({"origin": "null"}, "origin"),
        ({"host": "evil.example"}, "host"),  # DNS rebinding: a foreign name on 127.0.0.1
        ({"host": "evil.example:8700"}, "host"),
        ({"host": "127.0.0.1:port"}, "host"),
    ],
)
def test_an_open_server_refuses_a_foreign_origin_or_host(client, headers, field):
    before = journal(client)
    reply = client.post("/v1/scans", json=scan_body(), headers=headers)
    assert reply.status_code == 403 and reply.json()["detail"].startswith(f"{field}: ")
    assert repr(next(iter(headers.values()))) in reply.json()["detail"]
    assert client.get("/v1/map/meta", headers=headers).status_code == 403
    assert journal(client) == before


@pytest.mark.parametrize(
    "origin",
    ["http://127.0.0.1:8700", "http://localhost:9", "http://[::1]:8700", "http://testserver"],
)
def test_an_open_server_answers_loopback_origins(client, origin):
    assert client.post("/v1/scans", json=scan_body(), headers={"origin": origin}).status_code == 200


def test_a_server_with_tokens_takes_any_host_and_origin(tmp_path):
    tokens = [{"token": "a", "role": "admin"}]
    settings = small_settings(tmp_path / "d", tokens=tokens, server={})
    headers = {"authorization": "Bearer a", "origin": "http://evil.example"}
    with TestClient(create_app(settings), base_url="http://fleetmap.example") as client:
        assert client.get("/v1/map/meta", headers=headers).status_code == 200


@given(
    name=st.sampled_from(["127.0.0.1", "127.3.2.1", "localhost", "LOCALHOST", "[::1]"]),
    port=st.one_of(st.none(), st.integers(0, 65535)),
)
def test_loopback_hosts_with_any_port_are_local(name, port):
    guard = LocalOnlyMiddleware(None, load_settings(None, {}))
    host = name if port is None else f"{name}:{port}"
    assert guard.problem(host, f"http://{host}") is None


@given(st.text(min_size=1, max_size=40))
def test_a_host_is_local_only_if_it_is_a_loopback_name(host):
    guard = LocalOnlyMiddleware(None, load_settings(None, {}))
    name = host.rsplit(":", 1)[0] if host.rsplit(":", 1)[-1].isdigit() else host
    loopback = name.strip().lower().strip("[]") in ("localhost", "::1") or name.strip().startswith(
        "127."
    )
    if not loopback:
        assert guard.problem(host, None).startswith("host: ")


@pytest.mark.parametrize("path", ["/v1/plan", "/v1/query/cells", "/v1/query/segments"])
def test_the_body_limit_holds_on_every_route_declared_or_streamed(client, path):
    body = json.dumps({**PLAN, "points": [[1.0, 1.0]] * 2000}).encode()
    reply = client.post(path, content=body, headers=JSON)
    assert reply.status_code == 413
    assert reply.json()["detail"] == (
        f"body: at most 10000 bytes (limits.max_body_bytes), got {len(body)}"
    )
    chunks = (body[i : i + 1000] for i in range(0, len(body), 1000))  # no Content-Length
    streamed = client.post(path, content=chunks, headers=JSON)
    assert streamed.status_code == 413
    assert (
        streamed.json()["detail"] == "body: at most 10000 bytes (limits.max_body_bytes), got more"
    )


def test_made_up_methods_share_one_metrics_series(client):
    for i in range(1000):
        client.request(f"M{i}X", "/healthz")
    client.request("BREW", "/no/such/path")
    text = client.get("/metrics").text
    series = [
        line for line in text.splitlines() if line.startswith("fleetmap_request_seconds_count")
    ]
    assert 'method="OTHER",route="/healthz",status="405"' in text
    assert 'method="OTHER",route="unmatched",status="404"' in text
    assert not any('method="M' in line for line in series)
    assert len(series) <= 4


@pytest.mark.parametrize(
    "path, body, field",
    [
        ("/v1/plan", {**PLAN, "start": [True, 1.0]}, "start.0"),
        ("/v1/plan", {**PLAN, "allow_unknown": 1}, "allow_unknown"),
        ("/v1/plan", {**PLAN, "goal": ["2", 2.0]}, "goal.0"),
        ("/v1/query/cells", {"points": [[1.0, False]]}, "points.0.1"),
        ("/v1/query/cells", {"points": [[1.0, 1.0]], "at": True}, "at"),
        ("/v1/query/segments", {"segments": [[1, 1, 2, True]]}, "segments.0.3"),
    ],
)
def test_a_bool_is_not_a_number(client, path, body, field):
    reply = client.post(path, json=body)
    assert reply.status_code == 422 and reply.json()["detail"].startswith(f"{field}: "), reply.text


def test_integers_still_count_as_numbers(client):
    reply = client.post("/v1/plan", json={"start": [1, 1], "goal": [2, 2], "allow_unknown": True})
    assert reply.status_code == 200 and reply.json()["path"][0] == [1.05, 1.05]


def nest(levels):
    return "[" * levels + "]" * levels


SCAN = json.dumps(scan_body())
DEEP = nest(1000)


@pytest.mark.parametrize(
    "path, template, value",
    [
        ("/v1/plan", '{"start": [@, 1], "goal": [2, 2]}', HUGE),
        ("/v1/query/cells", '{"points": [[1, 1]], "at": @}', HUGE),
        ("/v1/query/segments", '{"segments": [[@, 1, 2, 2]]}', HUGE),
        ("/v1/scans", SCAN.replace('"stamp": 1.0', '"stamp": @'), HUGE),
        ("/v1/units", '{"units": [{"unit_id": "u1", "stamp": @}]}', HUGE),
        ("/v1/plan", '{"start": @, "goal": [2, 2]}', DEEP),
        ("/v1/plan", '{"start": @, "goal": [2, 2]}', nest(900)),
        ("/v1/query/cells", '{"points": @}', nest(900)),
        ("/v1/scans", SCAN.replace('"frame": "map"', '"frame": @'), DEEP),
        ("/v1/scans/batch", '{"scans": @}', DEEP),
        ("/v1/units", '{"units": [{"unit_id": @}]}', nest(900)),
    ],
)
def test_huge_integers_and_deep_nesting_are_4xx(client, path, template, value):
    before = journal(client)
    reply = client.post(path, content=template.replace("@", value), headers=JSON)
    assert reply.status_code in (400, 422), reply.text
    assert len(reply.json()["detail"]) < 300
    assert journal(client) == before


def test_read_json_names_the_problem():
    with pytest.raises(HTTPException, match="beyond the float range") as caught:
        parse_json(f'{{"stamp": {HUGE}}}'.encode())
    assert caught.value.status_code == 400
    with pytest.raises(HTTPException, match=f"nested deeper than {MAX_DEPTH} levels"):
        parse_json(DEEP.encode())
    with pytest.raises(HTTPException, match=f"nested deeper than {MAX_DEPTH} levels"):
        parse_json(nest(MAX_DEPTH + 1).encode())
    nested = nest(MAX_DEPTH)
    assert parse_json(nested.encode()) == json.loads(nested)
    assert parse_json(b'{"r": [1.0, Infinity, -Infinity]}') == {
        "r": [1.0, float("inf"), -float("inf")]
    }


# Integers of 64 bits are read exactly; wider ones as the nearest float (below).
INT64 = st.integers(min_value=-(2**63), max_value=2**64 - 1)
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | INT64 | st.floats(allow_nan=False) | st.text(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(), inner, max_size=4),
    max_leaves=30,
)


@given(JSON_VALUES)
def test_read_json_reads_back_any_json_value(value):
    assert parse_json(json.dumps(value).encode()) == value


@given(
    st.integers(min_value=2**64, max_value=10**300)
    | st.integers(max_value=-(2**63) - 1, min_value=-(10**300))
)
def test_read_json_reads_an_integer_wider_than_64_bits_as_the_nearest_float(value):
    # No field of the API holds an integer: every number is a float (stamps, ranges, poses).
    for body in (json.dumps(value), json.dumps([value, float("inf")])):  # both parsers
        parsed = parse_json(body.encode())
        parsed = parsed if isinstance(parsed, float) else parsed[0]
        assert isinstance(parsed, float) and parsed == float(value)


@given(st.binary(max_size=200))
def test_read_json_answers_any_bytes_with_a_value_or_a_400(raw):
    try:
        parse_json(raw)
    except HTTPException as exc:
        assert exc.status_code == 400 and exc.detail.startswith("body: ")
