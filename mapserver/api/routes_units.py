"""``POST /v1/units`` and ``GET /v1/units``: unit poses, paths and freezes for the viewer
(a project extension of docs/http-api.md; ``unit_board`` keeps them)."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Request

from mapserver.api.auth import READ, WRITE, require, require_unit
from mapserver.api.body import body_schema, read_model
from mapserver.api.schemas import ErrorOut, UnitsAck, UnitsIn, UnitsOut
from mapserver.api.unit_board import UnitBoardError

router = APIRouter(tags=["units"])


@router.post(
    "/v1/units",
    response_model=UnitsAck,
    responses={status: {"model": ErrorOut} for status in (400, 401, 403, 409, 413, 422)},
    openapi_extra=body_schema(UnitsIn),
    dependencies=[Depends(require(WRITE))],
    summary="Publish units' poses, planned paths and freezes (all or none)",
)
async def post_units(request: Request) -> UnitsAck:
    posted = await read_model(request, UnitsIn)
    for i, state in enumerate(posted.units):
        require_unit(request, state.unit_id, f"units[{i}].unit_id")
    try:
        tracked = request.app.state.units.publish(posted.units)
    except UnitBoardError as exc:
        raise HTTPException(exc.status, exc.detail) from None
    return UnitsAck(accepted=len(posted.units), tracked=tracked)


@router.get(
    "/v1/units",
    response_model=UnitsOut,
    responses={status: {"model": ErrorOut} for status in (401, 403)},
    dependencies=[Depends(require(READ))],
)
def get_units(request: Request) -> UnitsOut:
    """The latest published state of every unit, ordered by ``unit_id``."""
    return UnitsOut(units=request.app.state.units.latest())
