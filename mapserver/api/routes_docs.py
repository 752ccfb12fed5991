"""``GET /docs``: the OpenAPI page (Swagger UI), served with no network beyond this server.

FastAPI's own page loads Swagger UI from a CDN, so it is blank on an air-gapped warehouse
network. Here the page's script, styles and icon come from ``/docs/assets/``, read from
the ``swagger-ui-bundle-v2`` package (Swagger UI's own distribution files, Apache-2.0),
and the page reads the schema from ``/openapi.json``. Neither needs a token: the schema
describes the API, holds no map data. The app is created with ``docs_url=None`` and
``redoc_url=None`` (ReDoc would need a CDN too).
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

from fastapi import APIRouter, HTTPException, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, Response

router = APIRouter(include_in_schema=False)

DOCS_PATH = "/docs"
ASSETS_PATH = "/docs/assets"
ASSETS = {
    "swagger-ui-bundle.js": "text/javascript; charset=utf-8",
    "swagger-ui.css": "text/css; charset=utf-8",
    "favicon-32x32.png": "image/png",
}
HEADERS = {"Cache-Control": "public, max-age=86400", "X-Content-Type-Options": "nosniff"}


def swagger_ui_dir() -> Path:
    """The folder of Swagger UI's distribution files that ``swagger_ui_bundle`` ships."""
    from swagger_ui_bundle import swagger_ui_path

    return Path(swagger_ui_path)


@cache
def _asset(name: str) -> bytes:
    return (swagger_ui_dir() / name).read_bytes()


@router.get(DOCS_PATH)
def docs_page(request: Request) -> HTMLResponse:
    """Swagger UI for this server's ``/openapi.json``, every file from this server."""
    return get_swagger_ui_html(
        openapi_url=request.app.openapi_url,
        title=f"{request.app.title} - API",
        swagger_js_url=f"{ASSETS_PATH}/swagger-ui-bundle.js",
        swagger_css_url=f"{ASSETS_PATH}/swagger-ui.css",
        swagger_favicon_url=f"{ASSETS_PATH}/favicon-32x32.png",
        swagger_ui_parameters={"persistAuthorization": False},
    )


@router.get(ASSETS_PATH + "/{name}")
def docs_asset(name: str) -> Response:
    """One of Swagger UI's files (``ASSETS``); 404 naming any other."""
    if name not in ASSETS:
        raise HTTPException(404, f"name: no docs file of that name, got {name!r}")
    return Response(_asset(name), media_type=ASSETS[name], headers=HEADERS)
