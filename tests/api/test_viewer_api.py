"""What the viewer reads, in-process: the evidence-age grid (``GET /v1/map/age``), the
page and its files (``GET /``, ``/viewer/...``) and the palette it shares with PNGs."""

import math

import numpy as np
import pytest
from fastapi.testclient import TestClient
from server_helpers import scan_body, small_settings

from mapserver.api.app import create_app
from mapserver.api.render import cost_palette, occupancy_palette

READER, UNIT = "reader-secret", "unit-secret"
LETHAL_CELL = (50, 80)  # (row, col): the return of scan_body's beams at (8.05, 5.05)
NEVER_SEEN = (20, 150)  # (row, col): far from every scan here


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(small_settings(tmp_path / "data"))) as test_client:
        yield test_client


def ages_raw(client, **params):
    reply = client.get("/v1/map/age", params={"format": "raw", **params})
    assert reply.status_code == 200
    return reply, np.frombuffer(reply.content, dtype="<f4").reshape(100, 200)


def test_ages_are_float32_seconds_since_last_observed_with_nan_where_never_observed(client):
    for stamp in (1.0, 2.0, 3.0):
        client.post("/v1/scans", json=scan_body(stamp=stamp))
    client.post("/v1/scans", json=scan_body(stamp=8.0, unit="u2", x=15.0, y=8.0))
    reply, ages = ages_raw(client)
    h = reply.headers
    assert (h["X-Map-Width"], h["X-Map-Height"], h["X-Map-Resolution"]) == ("200", "100", "0.1")
    assert (h["X-Map-Version"], h["X-Map-Stamp"]) == ("4", "8.0")
    assert ages[LETHAL_CELL] == 5.0  # last seen at 3.0, the map's stamp is 8.0
    assert math.isnan(ages[NEVER_SEEN])
    assert ages[80, 150] == 0.0  # seen by the scan at 8.0 from (15, 8)
    cells = client.post("/v1/query/cells", json={"points": [[8.05, 5.05], [15.05, 2.05]]})
    assert [c["age"] for c in cells.json()["cells"]] == [5.0, None]


def test_ages_at_a_later_stamp_and_as_json_with_null_for_never_observed(client):
    client.post("/v1/scans", json=scan_body(stamp=3.0))
    reply, later = ages_raw(client, at=20.0)
    assert reply.headers["X-Map-Stamp"] == "20.0" and later[LETHAL_CELL] == 17.0
    as_json = client.get("/v1/map/age").json()
    data = np.array(as_json["data"], dtype=object).reshape(100, 200)
    assert data[LETHAL_CELL] == 0.0 and data[NEVER_SEEN] is None
    assert as_json["info"]["stamp"] == 3.0 and as_json["info"]["version"] == 1


def test_before_any_scan_every_age_is_nan(client):
    reply, ages = ages_raw(client)
    assert np.isnan(ages).all() and reply.headers["X-Map-Stamp"] == "nan"


@pytest.mark.parametrize(
    "params, field", [({"format": "png"}, "query.format"), ({"at": "inf"}, "query.at")]
)
def test_bad_age_parameters_name_the_field(client, params, field):
    reply = client.get("/v1/map/age", params=params)
    assert reply.status_code == 422 and reply.json()["detail"].startswith(field)


def test_ages_need_a_reader_token_but_the_page_needs_none(tmp_path):
    tokens = [{"token": READER, "role": "reader"}, {"token": UNIT, "role": "unit", "units": ["*"]}]
    with TestClient(create_app(small_settings(tmp_path / "d", tokens=tokens))) as client:
        assert client.get("/v1/map/age?format=raw").status_code == 401
        unit = {"Authorization": f"Bearer {UNIT}"}
        assert client.get("/v1/map/age?format=raw", headers=unit).status_code == 403
        reader = {"Authorization": f"Bearer {READER}"}
        assert client.get("/v1/map/age?format=raw", headers=reader).status_code == 200
        assert client.get("/").status_code == 200
        assert client.get("/viewer/viewer.js").status_code == 200


def test_the_page_and_its_files_are_served_with_their_types_and_a_strict_policy(client):
    page = client.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert 'src="viewer/viewer.js"' in page.text and 'href="viewer/viewer.css"' in page.text
    assert "script-src 'self'" in page.headers["content-security-policy"]
    script = client.get("/viewer/viewer.js")
    assert script.headers["content-type"].startswith("text/javascript")
    assert "v1/costmap/updates?since=" in script.text
    assert client.get("/viewer/viewer.css").headers["content-type"].startswith("text/css")
    assert "/" not in client.get("/openapi.json").json()["paths"]


@pytest.mark.parametrize("name", ["index.js", "palette.txt", "..%5Capp.py"])
def test_only_the_viewer_files_are_served(client, name):
    reply = client.get(f"/viewer/{name}")
    assert reply.status_code == 404 and reply.json()["detail"].startswith("name")
    assert client.get("/viewer/..%2Fapp.py").status_code == 404


def test_the_palette_is_the_one_png_replies_use(client):
    palettes = client.get("/viewer/palette.json").json()
    assert palettes["cost"] == cost_palette().tolist()
    assert palettes["occupancy"] == occupancy_palette().tolist()
    assert len({tuple(palettes["cost"][v]) for v in (0, 1, 252, 253, 254, 255)}) == 6
