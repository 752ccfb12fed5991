"""Identities that cannot hurt others: a unit id (and every string the API stores or
echoes) is 1 to 64 printable characters, else 422 naming the field with the value quoted
bounded, from JSON (either reader) and binary bodies alike; the scans beside a refused
one are served."""

import json
import threading
import unicodedata

import httpx
import orjson
import pytest
from fastapi import HTTPException
from fastapi.testclient import TestClient
from hypothesis import example, given
from hypothesis import strategies as st
from server_helpers import JSON, ServerProcess, scan_body, small_settings

from mapserver.api.app import create_app
from mapserver.api.body import parse_json
from mapserver.core.scan import Pose2D, Scan, ScanError
from mapserver.core.scan_binary import CONTENT_TYPE, encode_batch, encode_scan
from mapserver.core.text import MAX_ID_CHARS, quote, text_problem
from mapserver.json_text import read_fallback

SURROGATE = "evil\ud800"
HUGE = "x" * 1_000_000
BINARY = {"content-type": CONTENT_TYPE}
ANY_CHAR = st.characters(exclude_categories=())  # surrogates, controls, everything
STRINGS = st.one_of(
    st.text(ANY_CHAR, max_size=80),
    st.builds(lambda c, n: c * n, ANY_CHAR, st.integers(60, 70)),  # around the bound
)


def clean(value: str) -> bool:
    """The rule, written from the Unicode categories rather than ``str.isprintable``:
    not blank, at most 64 characters, none "Other" (C*) or "Separator" (Z*) but the
    ASCII space."""
    printable = all(unicodedata.category(c)[0] not in "CZ" or c == " " for c in value)
    return bool(value.strip()) and len(value) <= MAX_ID_CHARS and printable


@given(STRINGS)
@example("小车-7")
@example("unité 3")
@example(" ")
@example("a\u200db")
@example("a\u00a0b")
def test_an_id_is_accepted_iff_it_keeps_the_rule(value):
    problem = text_problem(value)
    assert (problem is None) == clean(value), problem
    try:
        scan = Scan.from_dict(scan_body(unit=value))
    except ScanError as exc:
        assert problem is not None and exc.field == "unit_id" and problem in str(exc)
        assert len(str(exc)) < 300  # the value quoted bounded
    else:
        assert problem is None and scan.unit_id == value


def outcome(read, raw: bytes):
    """What a route makes of body ``raw`` read by ``read``: 400, or the scan's unit id,
    or the validator's refusal."""
    try:
        body = read(raw)
    except (HTTPException, ValueError):
        return 400
    try:
        return Scan.from_dict(body).unit_id
    except ScanError as exc:
        return str(exc)


@given(STRINGS, st.booleans(), st.booleans())
@example(SURROGATE, True, False)
@example(SURROGATE, False, False)
@example("u1", True, True)
def test_both_json_readers_read_a_body_alike(value, ascii_only, infinite):
    """A body read as the server reads it (orjson, then ``json`` for what orjson refuses)
    and the same body forced through the fallback give the same scan or the same error;
    where orjson reads a body at all, the fallback reads the same value."""
    body = scan_body(unit=value, frame=value, ranges=[3.0, float("inf") if infinite else 4.0])
    text = json.dumps(body, ensure_ascii=ascii_only)
    raw = text.encode("utf-8", "surrogatepass")  # invalid UTF-8 where a surrogate is
    assert outcome(parse_json, raw) == outcome(read_fallback, raw)
    try:
        fast = orjson.loads(raw)
    except orjson.JSONDecodeError:
        return
    assert read_fallback(raw) == fast


@pytest.mark.parametrize(
    "raw",
    [
        b"\xef\xbb\xbf" + json.dumps(scan_body()).encode(),  # a byte order mark
        json.dumps(scan_body()).encode("utf-16"),
        json.dumps(scan_body(unit=SURROGATE), ensure_ascii=False).encode("utf-8", "surrogatepass"),
    ],
    ids=["bom", "utf-16", "encoded-surrogate"],
)
def test_a_body_that_is_not_utf8_is_400_from_either_reader(raw):
    assert outcome(parse_json, raw) == outcome(read_fallback, raw) == 400


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(small_settings(tmp_path / "data"))) as test_client:
        yield test_client


def refused(reply, field: str) -> str:
    assert reply.status_code == 422, reply.text
    detail = reply.json()["detail"]
    assert detail.startswith(f"{field}: ") and len(detail) < 300, detail
    return detail


@pytest.mark.parametrize(
    "unit, reason",
    [
        (SURROGATE, "U+D800 at index 4"),
        (HUGE, "at most 64 characters (got 1000000)"),
        ("u1\x1b[2J", "U+001B at index 2"),  # a terminal escape
        ("u1\u202e", "U+202E at index 2"),  # a bidirectional override
        ("", "non-empty"),
    ],
)
def test_a_bad_id_is_422_naming_the_field_from_every_body(client, unit, reason):
    raw = json.dumps(scan_body(unit=unit), ensure_ascii=True).encode()
    assert reason in refused(client.post("/v1/scans", content=raw, headers=JSON), "unit_id")
    batch = {"scans": [scan_body(unit="u1"), scan_body(unit=unit)]}
    reply = client.post("/v1/scans/batch", content=json.dumps(batch).encode(), headers=JSON)
    assert reason in refused(reply, "scans[1].unit_id")
    units = {"units": [{"unit_id": unit, "stamp": 1.0, "pose": {"x": 1, "y": 1, "yaw": 0}}]}
    reply = client.post("/v1/units", content=json.dumps(units).encode(), headers=JSON)
    assert reason in refused(reply, "units.0.unit_id")
    plan = {"start": [1, 1], "goal": [2, 2], "unit_id": unit}
    reply = client.post("/v1/plan", content=json.dumps(plan).encode(), headers=JSON)
    if unit == SURROGATE:  # pydantic's parser, the plan's, refuses the escape itself
        assert reply.status_code == 400 and "hex escape" in reply.json()["detail"]
    else:
        assert reason in refused(reply, "unit_id")
    assert client.app.state.service.journal.last_seq() == 0
    assert client.post("/v1/scans", json=scan_body(unit="u1")).status_code == 200


@pytest.mark.parametrize(
    "unit, reason",
    [("b" * 1000, "at most 64 characters (got 1000)"), ("u1\x00", "U+0000 at index 2")],
)
def test_a_bad_id_in_a_binary_body_is_422_naming_the_field(client, unit, reason):
    good = Scan.from_dict(scan_body())
    bad = Scan(unit, 1.0, Pose2D(5.0, 5.0, 0.0), -1.0, 0.01, 0.05, 20.0, good.ranges)
    reply = client.post("/v1/scans", content=encode_scan(bad), headers=BINARY)
    assert reason in refused(reply, "unit_id")
    reply = client.post("/v1/scans/batch", content=encode_batch([good, bad]), headers=BINARY)
    assert reason in refused(reply, "scans[1].unit_id")
    assert client.post("/v1/scans", content=encode_scan(good), headers=BINARY).status_code == 200


def test_a_unit_state_reason_keeps_the_rule(client):
    state = {"unit_id": "u1", "stamp": 1.0, "pose": {"x": 1, "y": 1, "yaw": 0}, "frozen": True}
    for reason, problem in [("a\nb", "U+000A"), ("r" * 201, "at most 200 characters")]:
        reply = client.post("/v1/units", json={"units": [{**state, "reason": reason}]})
        assert problem in refused(reply, "units.0.reason")
    reply = client.post("/v1/units", json={"units": [{**state, "reason": "lane L3 held"}]})
    assert reply.status_code == 200


def test_messages_quote_a_unit_id_bounded():
    assert len(quote(HUGE)) < 70 and quote(SURROGATE) == "'evil\\ud800'"
    with pytest.raises(ScanError) as bad:
        Scan.from_dict(scan_body(unit=HUGE))
    assert len(str(bad.value)) < 200


def test_on_a_real_server_bad_ids_posted_flat_out_leave_the_fleet_served(tmp_path):
    """Three units at about 20 Hz beside a client posting a surrogate id and a 1 MB id
    as fast as it can: every honest scan 200, every bad one 422 naming unit_id, bounded."""
    with ServerProcess(tmp_path / "data") as server:
        stop = threading.Event()
        bad_statuses: list[tuple[int, str]] = []

        def flood() -> None:
            with httpx.Client(base_url=server.url, timeout=10) as http:
                k = 0
                while not stop.is_set():
                    unit = SURROGATE if k % 2 == 0 else HUGE
                    raw = json.dumps(scan_body(stamp=1.0 + k, unit=unit)).encode()
                    reply = http.post("/v1/scans", content=raw, headers=JSON)
                    bad_statuses.append((reply.status_code, reply.json()["detail"]))
                    k += 1

        honest: list[int] = []

        def unit(name: str, row: float) -> None:
            with httpx.Client(base_url=server.url, timeout=10) as http:
                for k in range(15):
                    body = scan_body(stamp=1.0 + 0.05 * k, unit=name, y=row)
                    honest.append(http.post("/v1/scans", json=body).status_code)
                    stop.wait(0.05)

        flooder = threading.Thread(target=flood)
        units = [threading.Thread(target=unit, args=(f"u{i}", 4.0 + i)) for i in range(3)]
        flooder.start()
        for thread in units:
            thread.start()
        for thread in units:
            thread.join()
        stop.set()
        flooder.join()
        assert honest == [200] * 45
        assert len(bad_statuses) > 10
        assert {status for status, _ in bad_statuses} == {422}
        assert all(d.startswith("unit_id: ") and len(d) < 300 for _, d in bad_statuses)
        meta = httpx.get(server.url + "/v1/map/meta").json()
        assert meta["version"] == 45
