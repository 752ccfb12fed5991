"""A scan body's keys (``mapserver.api.scan_fields``): a key that is no field of a scan is
refused with 422 naming it and the nearest field, in one scan, a batch and the binary
encoding's flag bits, and changes nothing; stored records still read with extra keys."""

import json
import math

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import given, settings
from hypothesis import strategies as st
from server_helpers import JSON, scan_body, small_settings

from mapserver.api.app import create_app
from mapserver.api.scan_fields import unknown_scan_field
from mapserver.api.schemas import ScanIn
from mapserver.core.scan import Scan
from mapserver.core.scan_binary import CONTENT_TYPE, encode_batch, encode_scan

BINARY = {"content-type": CONTENT_TYPE}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    app = create_app(small_settings(tmp_path_factory.mktemp("scan-fields") / "data"))
    with TestClient(app) as client:
        assert client.post("/v1/scans", json=scan_body(stamp=1.0)).status_code == 200
        yield client


def state(client):
    """What a refused request must leave as it was: map version, journal, log-odds."""
    service = client.app.state.service
    return service.version, service.journal.last_seq(), service.belief.raw_log_odds().tobytes()


def with_key(body, path, key, value):
    """``body`` with ``key: value`` added at ``path`` (``""``, ``"pose"``, ``"pose_std"``)."""
    body = json.loads(json.dumps(body))
    target = body if not path else body.setdefault(path, {"xy": 0.1, "yaw": 0.01})
    target[key] = value
    return body


UNKNOWN = [  # (where, key, the detail)
    ("", "pose_sdt", "pose_sdt: not a field of a scan; did you mean 'pose_std'?"),
    ("", "ranegs", "ranegs: not a field of a scan; did you mean 'ranges'?"),
    ("", "unitid", "unitid: not a field of a scan; did you mean 'unit_id'?"),
    ("pose", "yew", "pose.yew: not a field of a pose; did you mean 'yaw'?"),
    ("pose_std", "yaww", "pose_std.yaww: not a field of pose_std; did you mean 'yaw'?"),
    (
        "",
        "colour",
        "colour: not a field of a scan (expected one of angle_increment, angle_min, frame, "
        "pose, pose_std, range_max, range_min, ranges, stamp, unit_id)",
    ),
]


@pytest.mark.parametrize(("path", "key", "detail"), UNKNOWN, ids=[u[1] for u in UNKNOWN])
def test_an_unknown_key_is_422_naming_it_and_the_nearest_field_and_changes_nothing(
    client, path, key, detail
):
    before = state(client)
    body = with_key(scan_body(stamp=2.0), path, key, {"xy": 0.5, "yaw": 0.1})
    if key == "ranegs":
        body["ranegs"] = body.pop("ranges")  # the misspelt list, no ranges
    reply = client.post("/v1/scans", content=json.dumps(body), headers=JSON)
    assert (reply.status_code, reply.json()) == (422, {"detail": detail})
    assert state(client) == before


def test_a_batch_with_one_unknown_key_is_refused_whole_naming_the_scan(client):
    before = state(client)
    scans = [scan_body(stamp=3.0, unit="u2"), with_key(scan_body(stamp=3.0), "", "pose_sdt", 1)]
    reply = client.post("/v1/scans/batch", json={"scans": scans})
    assert reply.status_code == 422
    assert reply.json()["detail"] == (
        "scans[1].pose_sdt: not a field of a scan; did you mean 'pose_std'?"
    )
    misspelt = client.post("/v1/scans/batch", json={"sacns": scans[:1]})
    assert (misspelt.status_code, misspelt.json()["detail"]) == (
        422,
        "sacns: not a field of a batch; did you mean 'scans'?",
    )
    assert state(client) == before


def test_a_binary_flag_bit_no_field_stands_for_is_422_single_or_batched(client):
    before = state(client)
    scan = Scan.from_dict(scan_body(stamp=4.0))
    record = bytearray(encode_scan(scan))
    record[5] = 0x03  # pose_std and bit 1, which version 1 does not define
    reply = client.post("/v1/scans", content=bytes(record), headers=BINARY)
    assert reply.status_code == 422
    assert reply.json()["detail"] == (
        "body: the scan sets flag bits 0x02, no field of a scan: format version 1 defines "
        "bit 0 (pose_std) only (at byte 5)"
    )
    batch = bytearray(encode_batch([scan, Scan.from_dict(scan_body(stamp=4.0, unit="u2"))]))
    second = 4 + len(encode_scan(scan))
    batch[second + 5] = 0x80
    reply = client.post("/v1/scans/batch", content=bytes(batch), headers=BINARY)
    assert reply.status_code == 422
    assert reply.json()["detail"].startswith("body: scan 1 sets flag bits 0x80, no field")
    assert state(client) == before


def test_known_keys_only_pass_and_the_names_are_the_documented_models():
    body = scan_body(pose_std={"xy": 0.02, "yaw": 0.01})
    assert unknown_scan_field(body) is None
    assert set(body) == set(ScanIn.model_fields)
    assert unknown_scan_field(["not", "a", "mapping"]) is None  # Scan.from_dict says why
    schema = ScanIn.model_json_schema()
    assert schema["additionalProperties"] is False  # the OpenAPI page says so too


@settings(max_examples=40, deadline=None)
@given(key=st.text(min_size=1, max_size=80), value=st.none() | st.floats(allow_nan=False))
def test_any_key_that_is_no_field_is_named_first(key, value):
    if key in ScanIn.model_fields:
        return
    detail = unknown_scan_field({**scan_body(), key: value})
    assert detail is not None and ": not a field of a scan" in detail
    assert detail.startswith(key) or detail.startswith(repr(key)[:20])


def test_stored_records_with_keys_the_api_refuses_still_read():
    """Journals and recordings are read by ``Scan.from_dict``, which keeps reading them."""
    body = {**scan_body(), "note": "written by an older fleet"}
    scan = Scan.from_dict(body)
    assert scan.unit_id == "u1" and np.all(scan.ranges == 3.0) and not math.isnan(scan.stamp)
