"""``/docs`` in headless Chromium with no network but loopback: Swagger UI renders.

Chromium resolves no host name but 127.0.0.1 (``--host-resolver-rules``), as on an
air-gapped warehouse network, and every request the page makes is recorded: all go to
this server. The server has tokens, as a deployed one does.
"""

import json
import urllib.request

import pytest
from browser_helpers import Browser, chromium_or_skip
from server_helpers import ServerProcess

OFFLINE = ["--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1"]
SCAN_PATHS = "[...document.querySelectorAll('.opblock-summary-path')].map(e => e.textContent)"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    folder = tmp_path_factory.mktemp("docs-server")
    config = folder / "server.yaml"
    config.write_text(json.dumps({"tokens": [{"token": "reader-t", "role": "reader"}]}))
    process = ServerProcess(folder / "data", config=config)
    yield process
    process.stop()


@pytest.fixture(scope="module")
def operations(server) -> list[dict]:
    """Every operation of the server's own OpenAPI schema (method, path and body)."""
    with urllib.request.urlopen(f"{server.url}/openapi.json", timeout=10) as reply:
        schema = json.load(reply)
    return [op for item in schema["paths"].values() for op in item.values()]


@pytest.fixture(scope="module")
def page(server, tmp_path_factory):
    browser = Browser(chromium_or_skip(), tmp_path_factory.mktemp("profile"), flags=OFFLINE)
    try:
        browser.open(f"{server.url}/docs")
        browser.wait_for("document.querySelectorAll('.opblock').length > 0", timeout=30)
        yield browser
    finally:
        browser.close()


def test_swagger_ui_renders_every_operation_from_this_server_alone(page, server, operations):
    paths = page.evaluate(SCAN_PATHS)
    assert {"/v1/scans", "/v1/scans/batch", "/v1/costmap", "/healthz", "/v1/clock"} <= set(paths)
    assert len(paths) == len(operations)  # one block per operation of the schema
    requested = [e["request"]["url"] for e in page.named("Network.requestWillBeSent")]
    assert f"{server.url}/openapi.json" in requested
    assert f"{server.url}/docs/assets/swagger-ui-bundle.js" in requested
    elsewhere = [u for u in requested if not u.startswith(server.url + "/")]
    assert all(u.startswith("data:") for u in elsewhere), elsewhere
    assert page.named("Network.loadingFailed") == []
    assert page.console_errors() == []
    outside = "fetch('https://cdn.jsdelivr.net/').then(() => 'reached', () => 'unreachable')"
    assert page.evaluate(outside) == "unreachable"  # the page had no way out


def test_the_authorize_button_offers_the_bearer_scheme(page, operations):
    assert page.evaluate("document.querySelectorAll('button.authorize').length") == 1
    page.evaluate("document.querySelector('button.authorize').click(), true")
    dialog = page.wait_for("document.querySelector('.modal-ux-content')?.innerText")
    assert "bearerAuth" in dialog and "http, Bearer" in dialog
    locks = "document.querySelectorAll('.opblock .authorization__btn').length"
    secured = [op for op in operations if op.get("security")]
    assert 0 < len(secured) < len(operations)  # /healthz and /metrics need none
    assert page.evaluate(locks) == len(secured)  # a lock on each operation that needs a token
