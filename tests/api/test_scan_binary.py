"""The binary scan encoding (docs/scan-binary.md): the codec's round trip and its refusals,
and the server taking it: the same maps as JSON, bad bodies refused with a 4xx naming the
problem and nothing changed."""

import json
import math
import struct

import numpy as np
import pytest
from conftest import make_scan
from fastapi.testclient import TestClient
from hypothesis import given, settings
from hypothesis import strategies as st
from server_helpers import JSON, limited_client, small_settings  # noqa: F401

from mapserver.api.app import create_app
from mapserver.core.scan import PoseStd, Scan
from mapserver.core.scan_binary import (
    CONTENT_TYPE,
    HEADER,
    ScanEncodingError,
    decode_scans,
    encode_batch,
    encode_scan,
)

BINARY = {"content-type": CONTENT_TYPE}


def scan_at(stamp: float, unit: str = "u1", x: float = 5.0, ranges=None) -> Scan:
    """A 200-beam scan whose ranges are exact in float32 (so both encodings carry the same
    numbers): returns, no-returns and invalid beams."""
    if ranges is None:
        ranges = np.full(200, 3.25)
        ranges[20:30] = math.inf  # no return
        ranges[40:45] = math.nan  # invalid
        ranges[60:80] = 1.5
    return make_scan(ranges, x=x, y=5.0, yaw=0.25, stamp=stamp, angle_min=-1.0, unit_id=unit)


@pytest.fixture
def pair(tmp_path):
    """Two servers: one fed JSON, one fed the binary encoding."""
    with (
        TestClient(create_app(small_settings(tmp_path / "json"))) as json_client,
        TestClient(create_app(small_settings(tmp_path / "binary"))) as binary_client,
    ):
        yield json_client, binary_client


@pytest.fixture
def client(limited_client):  # noqa: F811 (the fixture imported from server_helpers)
    return limited_client


def state(client):
    service = client.app.state.service
    return service.version, service.journal.last_seq(), service.belief.raw_log_odds().copy()


def unchanged(before, after) -> bool:
    return before[:2] == after[:2] and np.array_equal(before[2], after[2])


# ---------------------------------------------------------------------------- the codec


@settings(max_examples=60, deadline=None)
@given(
    ranges=st.lists(
        st.one_of(st.floats(0.0, 30.0, width=32), st.just(math.inf), st.just(math.nan)),
        min_size=1,
        max_size=300,
    ),
    stamp=st.floats(0.0, 1e6),
    unit=st.text(st.characters(categories=("L", "N", "P")), min_size=1, max_size=20),
    with_std=st.booleans(),
)
def test_a_record_decodes_to_the_scan_it_encodes(ranges, stamp, unit, with_std):
    std = PoseStd(0.05, 0.01) if with_std else None
    scan = Scan(unit, stamp, make_scan([1.0]).pose, -1.0, 0.01, 0.05, 20.0,
                np.asarray(ranges), pose_std=std)  # fmt: skip
    (decoded,) = decode_scans(encode_scan(scan), batch=False)
    again = Scan.from_dict(decoded)
    assert again.to_dict(with_ranges=False) == scan.to_dict(with_ranges=False)
    assert np.array_equal(again.ranges, scan.ranges, equal_nan=True)
    assert again.digest() == scan.digest()


def test_a_batch_holds_its_count_then_the_records():
    scans = [scan_at(1.0), scan_at(2.0, unit="u2")]
    body = encode_batch(scans)
    assert body[:4] == struct.pack("<I", 2)
    assert body[4:] == encode_scan(scans[0]) + encode_scan(scans[1])
    assert [s["unit_id"] for s in decode_scans(body, batch=True)] == ["u1", "u2"]


def test_a_record_is_the_header_the_unit_id_and_float32_ranges():
    body = encode_scan(scan_at(1.0))
    assert HEADER.size == 92 and len(body) == 92 + len("u1") + 4 * 200
    assert body[:6] == b"FMSC\x01\x00"  # magic, version 1, no pose_std


@settings(max_examples=100, deadline=None)
@given(cut=st.integers(0, 92 + 2 + 4 * 200 - 1))
def test_every_truncation_of_a_record_is_an_encoding_error(cut):
    body = encode_scan(scan_at(1.0))
    with pytest.raises(ScanEncodingError, match="truncated"):
        decode_scans(body[:cut], batch=False)


@settings(max_examples=200, deadline=None)
@given(body=st.binary(max_size=400), batch=st.booleans())
def test_arbitrary_bytes_decode_or_raise_an_encoding_error_only(body, batch):
    try:
        decode_scans(body, batch)
    except ScanEncodingError as exc:
        assert str(exc).startswith("body: ")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda b: b"XXXX" + b[4:],
            r"the scan does not start with b'FMSC', got b'XXXX' \(at byte 0\)",
        ),
        (lambda b: b[:4] + b"\x02" + b[5:], "format version 2; this server reads 1"),
        (lambda b: b[:5] + b"\x06" + b[6:], "sets flag bits 0x06, no field of a scan"),
        (lambda b: b + b"\x00" * 3, "3 bytes follow the last scan record, expected none"),
        (lambda b: b[:92] + b"\xff\xfe" + b[94:], "unit_id is not UTF-8"),
    ],
)
def test_a_malformed_record_names_what_is_wrong_and_where(edit, message):
    with pytest.raises(ScanEncodingError, match=message):
        decode_scans(edit(encode_scan(scan_at(1.0))), batch=False)


# ---------------------------------------------------------------------------- the server


def test_binary_and_json_encodings_of_the_same_scans_give_identical_maps(pair):
    json_client, binary_client = pair
    scans = [scan_at(float(t), x=4.0 + 0.5 * t) for t in range(1, 6)]
    for scan in scans[:3]:  # one at a time ...
        body = json.dumps(scan.to_dict())  # Infinity for no return, null for invalid
        assert json_client.post("/v1/scans", content=body, headers=JSON).status_code == 200
        reply = binary_client.post("/v1/scans", content=encode_scan(scan), headers=BINARY)
        assert reply.status_code == 200, reply.text
    batch = json.dumps({"scans": [scan.to_dict() for scan in scans[3:]]})  # ... and as a batch
    assert json_client.post("/v1/scans/batch", content=batch, headers=JSON).status_code == 200
    reply = binary_client.post("/v1/scans/batch", content=encode_batch(scans[3:]), headers=BINARY)
    assert reply.json() == {"acks": [{"seq": 4, "map_version": 5}, {"seq": 5, "map_version": 5}]}
    a, b = (c.app.state.service for c in pair)
    assert (a.version, b.version) == (5, 5)
    assert np.array_equal(a.belief.raw_log_odds(), b.belief.raw_log_odds())
    assert np.array_equal(a.belief.last_observed(), b.belief.last_observed(), equal_nan=True)
    for path in ("/v1/map?format=raw", "/v1/costmap?format=raw"):
        assert json_client.get(path).content == binary_client.get(path).content
    assert (a.belief.raw_log_odds() != 0).sum() > 1000  # the scans did map something


def test_a_retried_binary_scan_gets_its_first_ack_and_is_fused_once(client):
    body = encode_scan(scan_at(1.0))
    first = client.post("/v1/scans", content=body, headers=BINARY).json()
    before = state(client)
    assert client.post("/v1/scans", content=body, headers=BINARY).json() == first
    assert unchanged(before, state(client))


@pytest.mark.parametrize(
    ("body", "status", "detail"),
    [
        (
            encode_scan(scan_at(1.0))[:500],
            400,
            "body: truncated: the scan declares a 2-byte unit_id",
        ),
        (b"", 400, "body: truncated: the scan needs a 92-byte header, got 0 bytes (at byte 0)"),
        (encode_scan(scan_at(1.0)) + b"\x00", 400, "body: 1 bytes follow the last scan record"),
        (encode_scan(scan_at(math.nan)), 422, "stamp: must be a finite number, got nan"),
        (encode_scan(scan_at(1.0, unit="")), 422, "unit_id: must be a non-empty string, got ''"),
    ],
)
def test_a_bad_binary_scan_is_refused_naming_the_problem_and_changes_nothing(
    client, body, status, detail
):
    before = state(client)
    reply = client.post("/v1/scans", content=body, headers=BINARY)
    assert (reply.status_code, reply.json()["detail"][: len(detail)]) == (status, detail)
    assert unchanged(before, state(client))


def test_an_oversized_binary_body_is_413_and_changes_nothing(client):
    before = state(client)
    big = scan_at(1.0, ranges=np.full(3000, 2.0))  # 12 kB > limits.max_body_bytes (10 kB)
    reply = client.post("/v1/scans", content=encode_scan(big), headers=BINARY)
    assert reply.status_code == 413 and reply.json()["detail"].startswith("body: at most 10000")
    assert unchanged(before, state(client))


def test_a_binary_batch_is_all_or_nothing_and_names_the_bad_scan(client):
    before = state(client)
    bad = encode_batch([scan_at(1.0), scan_at(math.inf, unit="u2")])
    reply = client.post("/v1/scans/batch", content=bad, headers=BINARY)
    assert reply.status_code == 422
    assert reply.json()["detail"] == "scans[1].stamp: must be a finite number, got inf"
    empty = client.post("/v1/scans/batch", content=struct.pack("<I", 0), headers=BINARY)
    assert empty.status_code == 422 and empty.json()["detail"].startswith(
        "scans: must be a non-empty"
    )
    short = client.post("/v1/scans/batch", content=bad[:-4], headers=BINARY)
    assert short.status_code == 400 and "scan 1 declares" in short.json()["detail"]
    assert unchanged(before, state(client))
