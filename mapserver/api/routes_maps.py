"""Map and costmap reads (docs/http-api.md 2.2 and 2.3)."""

from __future__ import annotations

import math
from typing import Literal

from fastapi import APIRouter, Depends, Query, Request, Response

from mapserver.api.auth import READ, require
from mapserver.api.render import age_response, cost_palette, grid_response, occupancy_palette
from mapserver.api.schemas import (
    AgeGridJson,
    CostmapUpdates,
    ErrorOut,
    GridJson,
    MapMeta,
    PatchOut,
)

router = APIRouter(tags=["map"], dependencies=[Depends(require(READ))])

Format = Literal["json", "raw", "png"]
AgeFormat = Literal["json", "raw"]
GRID_RESPONSES = {
    200: {
        "model": GridJson,
        "content": {"application/octet-stream": {}, "image/png": {}},
        "description": "json: {info, data}; raw: row-major bytes with X-Map-* headers; png",
    },
    401: {"model": ErrorOut},
    403: {"model": ErrorOut},
    422: {"model": ErrorOut},
}
AGE_RESPONSES = {
    200: {
        "model": AgeGridJson,
        "content": {"application/octet-stream": {}},
        "description": "json: {info, data} (null: never observed); raw: little-endian float32 "
        "ages [s] row-major (NaN: never observed) with X-Map-* headers",
    },
    401: {"model": ErrorOut},
    403: {"model": ErrorOut},
    422: {"model": ErrorOut},
}
AT = Query(None, allow_inf_nan=False, description="[s] evaluate decay at this stamp")
FORMAT = Query("json", description="json, raw or png")
AGE_FORMAT = Query("json", description="json or raw")
COST_PALETTE = cost_palette()
OCCUPANCY_PALETTE = occupancy_palette()


@router.get("/v1/map/meta", response_model=MapMeta, responses={401: {"model": ErrorOut}})
def map_meta(request: Request) -> dict:
    return request.app.state.service.meta()


@router.get("/v1/map", responses=GRID_RESPONSES, response_class=Response)
def get_map(request: Request, format: Format = FORMAT, at: float | None = AT) -> Response:
    """The belief as ROS OccupancyGrid int8 values: -1 unknown, 0..100 percent."""
    service = request.app.state.service
    read = service.occupancy_read(at)
    return grid_response(format, read, service.geometry, service.meta(), OCCUPANCY_PALETTE)


@router.get("/v1/costmap", responses=GRID_RESPONSES, response_class=Response)
def get_costmap(request: Request, format: Format = FORMAT, at: float | None = AT) -> Response:
    """Nav2 costs: 0 free, 1..252 graded, 253 inscribed, 254 lethal, 255 unknown."""
    service = request.app.state.service
    read = service.costmap_read(at)
    return grid_response(format, read, service.geometry, service.meta(), COST_PALETTE)


@router.get("/v1/map/age", responses=AGE_RESPONSES, response_class=Response)
def get_map_age(
    request: Request,
    format: AgeFormat = AGE_FORMAT,
    at: float | None = AT,
) -> Response:
    """Evidence age [s] per cell at the map's stamp (or ``at``): ``stamp - last_observed``,
    NaN (raw) or null (json) where a cell was never observed."""
    service = request.app.state.service
    return age_response(format, service.age_read(at), service.geometry, service.meta())


@router.get(
    "/v1/costmap/updates",
    response_model=CostmapUpdates,
    responses={401: {"model": ErrorOut}, 422: {"model": ErrorOut}},
)
def costmap_updates(request: Request, since: int = Query(ge=0)) -> CostmapUpdates:
    """Patches (bounding boxes of current costs) since a version, or ``full``."""
    version, stamp, patches = request.app.state.service.updates_since(since)
    stamp = stamp if math.isfinite(stamp) else None
    if patches is None:
        return CostmapUpdates(version=version, stamp=stamp, full=True, patches=[])
    return CostmapUpdates(
        version=version,
        stamp=stamp,
        patches=[
            PatchOut(x0=p.x0, y0=p.y0, width=p.width, height=p.height, data=p.data.ravel().tolist())
            for p in patches
        ],
    )
