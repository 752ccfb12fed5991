"""``GET /docs`` from packaged files (no CDN) and the bearer scheme in the OpenAPI schema.

The schema's security is checked against what the server does: with tokens configured,
every operation that lists the scheme answers 401 without a token and every other one
does not, and a reader token is refused (403) exactly where the description names a
``unit`` token.
"""

import re
from html.parser import HTMLParser

import pytest
from fastapi.testclient import TestClient
from server_helpers import GRID, JSON

from mapserver.api.app import create_app
from mapserver.api.auth import BEARER_SCHEME
from mapserver.api.routes_docs import swagger_ui_dir
from mapserver.service.settings import load_settings

TOKENS = [{"token": "unit-t", "role": "unit", "units": ["*"]},
          {"token": "reader-t", "role": "reader"}]  # fmt: skip
OPEN_OPERATIONS = {("get", "/healthz"), ("get", "/metrics")}


class Links(HTMLParser):
    """Every ``src`` and ``href`` of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.urls += [value for name, value in attrs if name in ("src", "href") and value]


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    data = tmp_path_factory.mktemp("docs") / "data"
    settings = load_settings(None, {"data_dir": data, "grid": GRID, "tokens": TOKENS})
    with TestClient(create_app(settings)) as test_client:
        yield test_client


@pytest.fixture(scope="module")
def schema(client):
    return client.get("/openapi.json").json()


def operations(schema):
    return [(method, path, op) for path, ops in schema["paths"].items()
            for method, op in ops.items()]  # fmt: skip


def test_the_docs_page_loads_its_script_styles_and_icon_from_this_server(client):
    page = client.get("/docs")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    links = Links()
    links.feed(page.text)
    assert sorted(links.urls) == [
        "/docs/assets/favicon-32x32.png",
        "/docs/assets/swagger-ui-bundle.js",
        "/docs/assets/swagger-ui.css",
    ]
    assert not re.search(r"(https?:)?//[a-z]", page.text)  # no other host named anywhere
    assert "url: '/openapi.json'" in page.text
    types = {"js": "text/javascript", "css": "text/css", "png": "image/png"}
    for url in links.urls:
        asset = client.get(url)
        assert asset.status_code == 200, url
        assert asset.headers["content-type"].split(";")[0] == types[url.rsplit(".", 1)[1]]
        assert asset.content == (swagger_ui_dir() / url.rsplit("/", 1)[1]).read_bytes()


def test_the_docs_page_and_schema_need_no_token_but_other_files_are_not_served(client):
    assert client.get("/openapi.json").status_code == 200
    reply = client.get("/docs/assets/swagger-ui.js.map")
    assert reply.status_code == 404
    assert reply.json() == {"detail": "name: no docs file of that name, got 'swagger-ui.js.map'"}
    assert client.get("/docs/assets/..%2Fsettings.py").status_code == 404
    assert client.get("/redoc").status_code == 404  # ReDoc needs a CDN: not offered


def test_the_schema_declares_the_bearer_scheme(schema):
    scheme = schema["components"]["securitySchemes"][BEARER_SCHEME]
    assert (scheme["type"], scheme["scheme"]) == ("http", "bearer")
    assert "security" not in schema  # no global requirement: /healthz and /metrics are open


def test_every_operation_but_the_open_ones_needs_a_bearer_token(client, schema):
    for method, path, op in operations(schema):
        listed = op.get("security")
        reply = client.request(method, path, json={}, headers=JSON)
        if (method, path) in OPEN_OPERATIONS:
            assert listed is None, (method, path)
            assert reply.status_code == 200, (method, path)
        else:
            assert listed == [{BEARER_SCHEME: []}], (method, path)
            assert reply.status_code == 401, (method, path, reply.text)
            assert "401" in op["responses"], (method, path)


def test_each_secured_operations_description_names_the_roles_the_server_admits(client, schema):
    secured = [(m, p, op) for m, p, op in operations(schema) if op.get("security")]
    assert len(secured) == 14
    for method, path, op in secured:
        if "only an `admin` token" in op["description"]:
            continue  # declaring the clock: below
        reader = client.request(
            method, path, json={}, headers={**JSON, "Authorization": "Bearer reader-t"}
        )
        if "a `unit` token" in op["description"]:
            assert reply_is(reader, 403), (method, path)
        else:
            assert "a `reader` or an `admin` token" in op["description"], (method, path)
            assert reader.status_code not in (401, 403), (method, path, reader.text)
    writes = {(m, p) for m, p, op in secured if "a `unit` token" in op["description"]}
    assert writes == {("post", "/v1/scans"), ("post", "/v1/scans/batch"), ("post", "/v1/units")}
    admin = {(m, p) for m, p, op in secured if "only an `admin` token" in op["description"]}
    assert admin == {("put", "/v1/clock")}
    for token in ("reader-t", "unit-t"):
        reply = client.put(
            "/v1/clock", json={"now": 1.0}, headers={**JSON, "Authorization": f"Bearer {token}"}
        )
        assert reply.status_code == 403 and "may not declare the clock" in reply.json()["detail"]


def reply_is(reply, status: int) -> bool:
    return reply.status_code == status and "may not write" in reply.json()["detail"]
