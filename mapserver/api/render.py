"""Grid replies in the three formats of docs/http-api.md 2.3: json, raw bytes with headers, png."""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np
from fastapi import Response
from fastapi.responses import JSONResponse
from PIL import Image

from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.service.map_service import GridRead


def raw_headers(read: GridRead, geometry: GridGeometry) -> dict[str, str]:
    """The X-Map-* headers of a raw grid reply."""
    return {
        "X-Map-Width": str(geometry.width),
        "X-Map-Height": str(geometry.height),
        "X-Map-Resolution": repr(geometry.resolution),
        "X-Map-Origin-X": repr(geometry.origin_x),
        "X-Map-Origin-Y": repr(geometry.origin_y),
        "X-Map-Version": str(read.version),
        "X-Map-Stamp": repr(read.stamp) if math.isfinite(read.stamp) else "nan",
    }


def grid_response(
    fmt: str, read: GridRead, geometry: GridGeometry, meta: dict[str, Any], palette: np.ndarray
) -> Response:
    """Render ``read`` as json ({"info", "data"}), raw bytes or a PNG via ``palette``."""
    if fmt == "raw":
        return Response(
            np.ascontiguousarray(read.data).tobytes(),
            media_type="application/octet-stream",
            headers=raw_headers(read, geometry),
        )
    if fmt == "png":
        lookup = palette[read.data.astype(np.uint8)]  # int8 -1 becomes 255
        image = Image.fromarray(np.ascontiguousarray(lookup[::-1]), mode="RGB")  # top row = max y
        buffer = io.BytesIO()
        image.save(buffer, format="PNG")
        headers = raw_headers(read, geometry)
        return Response(buffer.getvalue(), media_type="image/png", headers=headers)
    return JSONResponse({"info": _info(meta, read), "data": read.data.ravel().tolist()})


def age_response(
    fmt: str, read: GridRead, geometry: GridGeometry, meta: dict[str, Any]
) -> Response:
    """Render evidence ages [s] (float32, NaN never observed) as json (null for NaN) or
    raw little-endian float32 bytes with the X-Map-* headers."""
    ages = np.ascontiguousarray(read.data, dtype="<f4")
    if fmt == "raw":
        return Response(
            ages.tobytes(),
            media_type="application/octet-stream",
            headers=raw_headers(read, geometry),
        )
    # null: never observed (NaN); also an age beyond float32's range (an absurd ``at``)
    values = [v if math.isfinite(v) else None for v in ages.ravel().tolist()]
    return JSONResponse({"info": _info(meta, read), "data": values})


def _info(meta: dict[str, Any], read: GridRead) -> dict[str, Any]:
    """The metadata of a json grid reply: the map's, at the read's version and stamp."""
    return dict(meta, version=read.version, stamp=read.stamp if math.isfinite(read.stamp) else None)


def cost_palette() -> np.ndarray:
    """RGB per cost: free white, graded yellow to red, inscribed purple, lethal black,
    unknown grey."""
    palette = np.zeros((256, 3), dtype=np.uint8)
    graded = np.arange(1, INSCRIBED)
    palette[graded, 0] = 255
    palette[graded, 1] = (230 - graded * 200 // 252).astype(np.uint8)
    palette[graded, 2] = 40
    palette[FREE] = (255, 255, 255)
    palette[INSCRIBED] = (120, 40, 160)
    palette[LETHAL] = (0, 0, 0)
    palette[UNKNOWN] = (128, 128, 128)
    return palette


def occupancy_palette() -> np.ndarray:
    """RGB per OccupancyGrid value viewed as uint8: 0..100 white to black, -1 (255) grey."""
    palette = np.full((256, 3), 128, dtype=np.uint8)
    shade = (255 - np.arange(101) * 255 // 100).astype(np.uint8)
    palette[:101] = shade[:, None]
    return palette
