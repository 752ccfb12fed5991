"""``GET /``: the live map viewer, plain HTML + JS + CSS shipped in ``viewer/``.

The page itself holds no map data and needs no token; everything it shows comes from the
API with the reader token the user gives it (``#token=...`` in the URL, or a prompt).
``/viewer/palette.json`` gives the page the colours ``render`` uses for PNGs, so the
viewer and the PNG replies draw every cost value alike.
"""

from __future__ import annotations

from functools import cache
from importlib import resources

from fastapi import APIRouter, HTTPException
from fastapi.responses import HTMLResponse, JSONResponse, Response

from mapserver.api.render import cost_palette, occupancy_palette

router = APIRouter(include_in_schema=False)

ASSETS = {
    "viewer.js": "text/javascript; charset=utf-8",
    "viewer.css": "text/css; charset=utf-8",
}
HEADERS = {
    "Cache-Control": "no-cache",
    "X-Content-Type-Options": "nosniff",
    # Only the page's own script, styles and API: unit ids and reasons are shown as text.
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'self'; "
    "connect-src 'self'; img-src 'self' data:; base-uri 'none'; form-action 'none'; "
    "frame-ancestors 'none'",
}


@cache
def _asset(name: str) -> str:
    """The text of ``viewer/<name>`` (package data)."""
    return (resources.files("mapserver.api") / "viewer" / name).read_text(encoding="utf-8")


@router.get("/")
def viewer_page() -> HTMLResponse:
    return HTMLResponse(_asset("index.html"), headers=HEADERS)


@router.get("/viewer/palette.json")
def viewer_palette() -> JSONResponse:
    """RGB per uint8 value: ``cost`` for Nav2 costs, ``occupancy`` for OccupancyGrid
    values seen as uint8 (-1 is 255)."""
    palettes = {"cost": cost_palette().tolist(), "occupancy": occupancy_palette().tolist()}
    return JSONResponse(palettes, headers=HEADERS)


@router.get("/viewer/{name}")
def viewer_asset(name: str) -> Response:
    if name not in ASSETS:
        raise HTTPException(404, f"name: no viewer file of that name, got {name!r}")
    return Response(_asset(name), media_type=ASSETS[name], headers=HEADERS)
