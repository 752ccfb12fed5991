"""``GET /v1/clock`` and ``PUT /v1/clock``: what "now" is for the map's clock rule, and a
simulation declaring its clock, as ROS's ``/clock`` (docs/map-time.md; an addition to
docs/http-api.md)."""

from __future__ import annotations

import math

from fastapi import APIRouter, Depends, HTTPException, Request

from mapserver.api.auth import DECLARE_CLOCK, READ, require
from mapserver.api.body import body_schema, read_model
from mapserver.api.schemas import ClockIn, ClockOut, DeclaredClock, ErrorOut
from mapserver.service.map_clock import ClockDeclarationError, ClockView

router = APIRouter(tags=["clock"])


def clock_out(view: ClockView) -> ClockOut:
    """The clock's state (``MapClock.view()``) as ``GET /v1/clock`` answers it."""
    reference, declared = view.reference, view.declared
    return ClockOut(
        reference=reference.kind,
        now=reference.value,
        wall=view.wall,
        map_stamp=view.map_stamp if math.isfinite(view.map_stamp) else None,
        declared=None if declared is None else DeclaredClock(now=declared[0], age_s=declared[1]),
        max_lead_s=view.max_lead_s,
    )


@router.get(
    "/v1/clock",
    response_model=ClockOut,
    responses={status: {"model": ErrorOut} for status in (401, 403)},
    dependencies=[Depends(require(READ))],
    summary="What a scan's stamp is judged against now",
)
def get_clock(request: Request) -> ClockOut:
    return clock_out(request.app.state.service.clock.view())


@router.put(
    "/v1/clock",
    response_model=ClockOut,
    responses={status: {"model": ErrorOut} for status in (400, 401, 403, 413, 422)},
    openapi_extra=body_schema(ClockIn),
    dependencies=[Depends(require(DECLARE_CLOCK))],
    summary="Declare a simulation's clock (as ROS's /clock); it binds for clock.sim_ttl_s",
)
async def put_clock(request: Request) -> ClockOut:
    declared = await read_model(request, ClockIn)
    clock = request.app.state.service.clock  # a MapClock, or a map process's (map_process)
    try:
        clock.declare(declared.now)
    except ClockDeclarationError as exc:
        raise HTTPException(422, str(exc)) from None
    return clock_out(clock.view())
