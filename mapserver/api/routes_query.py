"""Cell and segment queries (docs/http-api.md 2.4 and 2.5).

A query is parsed, computed and encoded on a worker thread under the app's query
admission (``admission``): the event loop only receives the body and sends the bytes,
so a reader asking for 100,000 cells in a loop never holds up scan ingest or ``/healthz``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import orjson
from fastapi import APIRouter, Depends, HTTPException, Request, Response
from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, ValidationError

from mapserver.api.admission import Admission
from mapserver.api.auth import READ, require
from mapserver.api.body import body_schema
from mapserver.api.schemas import CellsIn, CellsOut, ErrorOut, SegmentsIn, SegmentsOut
from mapserver.core.queries import CELL_FIELDS

router = APIRouter(tags=["query"], dependencies=[Depends(require(READ))])
ERRORS = {status: {"model": ErrorOut} for status in (400, 401, 403, 413, 415, 422, 429)}


def parse_body(model: type[BaseModel], raw: bytes) -> Any:
    """The JSON text ``raw`` parsed and validated as ``model`` in one pass of pydantic's
    parser (a third of the time of parsing, then validating, a 100,000-point body, held
    in one call without a break for other threads): 400 when it is not JSON, else a 422
    naming the field, as for any route."""
    try:
        return model.model_validate_json(raw)
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        if errors and errors[0]["type"] == "json_invalid":
            reason = errors[0].get("ctx", {}).get("error", errors[0]["msg"])
            raise HTTPException(400, f"body: not valid JSON ({reason})") from None
        raise RequestValidationError(errors) from None


def json_response(content: Any) -> Response:
    """``content`` (dicts, lists, numbers) encoded with orjson."""
    return Response(orjson.dumps(content), media_type="application/json")


async def answer_on_worker(
    request: Request, model: type[BaseModel], admission: Admission, respond: Callable[[Any], Any]
) -> Response:
    """Receive the body, then on a worker thread under ``admission``: parse it, validate it
    as ``model``, compute ``respond(query)`` and encode it (the loop only moves bytes)."""
    raw = await request.body()
    return await admission.run(lambda: json_response(respond(parse_body(model, raw))))


@router.post(
    "/v1/query/cells",
    response_model=CellsOut,
    responses=ERRORS,
    openapi_extra=body_schema(CellsIn),
    summary="State, probability, cost and age of the cells at points",
)
async def query_cells(request: Request) -> Response:
    service = request.app.state.service

    def respond(query: CellsIn) -> dict[str, Any]:
        points = np.array(query.points, dtype=np.float64).reshape(-1, 2)
        columns = service.cell_columns(points, query.at)
        rows = zip(*(columns[f] for f in CELL_FIELDS), strict=True)
        return {"cells": [dict(zip(CELL_FIELDS, row, strict=True)) for row in rows]}

    return await answer_on_worker(request, CellsIn, request.app.state.query_admission, respond)


@router.post(
    "/v1/query/segments",
    response_model=SegmentsOut,
    responses=ERRORS,
    openapi_extra=body_schema(SegmentsIn),
    summary="Highest cost, blocked and unknown share along segments",
)
async def query_segments(request: Request) -> Response:
    service = request.app.state.service

    def respond(query: SegmentsIn) -> dict[str, Any]:
        reports = service.segments([list(s) for s in query.segments])
        return {
            "segments": [
                {
                    "max_cost": r.max_cost,
                    "blocked": r.blocked,
                    "unknown_fraction": r.unknown_fraction,
                    "first_blocked": list(r.first_blocked) if r.first_blocked else None,
                }
                for r in reports
            ]
        }

    return await answer_on_worker(request, SegmentsIn, request.app.state.query_admission, respond)
