"""Cell and segment queries (CONTRACT 2.4 and 2.5)."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request

from mapserver.api.auth import READ, require
from mapserver.api.schemas import (
    CellOut,
    CellsIn,
    CellsOut,
    ErrorOut,
    SegmentOut,
    SegmentsIn,
    SegmentsOut,
)

router = APIRouter(tags=["query"], dependencies=[Depends(require(READ))])
ERRORS = {status: {"model": ErrorOut} for status in (401, 403, 422)}


@router.post("/v1/query/cells", response_model=CellsOut, responses=ERRORS)
def query_cells(request: Request, body: CellsIn) -> CellsOut:
    reports = request.app.state.service.cells([list(p) for p in body.points], body.at)
    return CellsOut(cells=[CellOut(**r.__dict__) for r in reports])


@router.post("/v1/query/segments", response_model=SegmentsOut, responses=ERRORS)
def query_segments(request: Request, body: SegmentsIn) -> SegmentsOut:
    reports = request.app.state.service.segments([list(s) for s in body.segments])
    return SegmentsOut(
        segments=[
            SegmentOut(
                max_cost=r.max_cost,
                blocked=r.blocked,
                unknown_fraction=r.unknown_fraction,
                first_blocked=list(r.first_blocked) if r.first_blocked else None,
            )
            for r in reports
        ]
    )
