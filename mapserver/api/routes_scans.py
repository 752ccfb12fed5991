"""``POST /v1/scans`` and ``POST /v1/scans/batch`` (docs/http-api.md 2.1)."""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request

from mapserver.api.auth import WRITE, require, require_unit
from mapserver.api.body import body_schema, quote, read_json
from mapserver.api.schemas import ErrorOut, ScanAck, ScanBatchAck, ScanBatchIn, ScanIn
from mapserver.core.scan import Scan, ScanError
from mapserver.service.map_service import MapService
from mapserver.service.scan_gate import IngestError

router = APIRouter(tags=["scans"])

ERRORS = {status: {"model": ErrorOut} for status in (400, 401, 403, 409, 413, 415, 422, 503)}


def _parse(request: Request, item: Any, prefix: str) -> Scan:
    """The scan in ``item`` (422 naming ``prefix`` + field), one the token may post (403)."""
    try:
        scan = Scan.from_dict(item, max_beams=request.app.state.settings.limits.max_beams)
    except ScanError as exc:
        raise HTTPException(422, f"{prefix}{exc}") from None
    require_unit(request, scan.unit_id, f"{prefix}unit_id")
    return scan


async def _submit(request: Request, scans: list[Scan]) -> list[Any]:
    service: MapService = request.app.state.service
    metrics = request.app.state.metrics
    try:
        acks = await asyncio.wrap_future(service.submit(scans))
    except IngestError as exc:
        metrics.scans_rejected.labels(str(exc.status)).inc()
        raise HTTPException(exc.status, exc.detail) from None
    metrics.scans_fused.inc(len(acks))
    return acks


@router.post(
    "/v1/scans",
    response_model=ScanAck,
    responses=ERRORS,
    openapi_extra=body_schema(ScanIn),
    dependencies=[Depends(require(WRITE))],
    summary="Post one scan; durable once acknowledged",
)
async def post_scan(request: Request) -> ScanAck:
    body = await read_json(request)
    scan = _parse(request, body, "")
    (ack,) = await _submit(request, [scan])
    return ScanAck(seq=ack.seq, map_version=ack.map_version)


@router.post(
    "/v1/scans/batch",
    response_model=ScanBatchAck,
    responses=ERRORS,
    openapi_extra=body_schema(ScanBatchIn),
    dependencies=[Depends(require(WRITE))],
    summary="Post several scans; all are accepted or none",
)
async def post_scans(request: Request) -> ScanBatchAck:
    body = await read_json(request)
    limits = request.app.state.settings.limits
    items = body.get("scans") if isinstance(body, dict) else None
    if not isinstance(items, list) or not items:
        raise HTTPException(422, f"scans: must be a non-empty list of scans, got {quote(items)}")
    if len(items) > limits.max_batch:
        raise HTTPException(422, f"scans: at most {limits.max_batch} per batch, got {len(items)}")
    scans = [_parse(request, item, f"scans[{i}].") for i, item in enumerate(items)]
    acks = await _submit(request, scans)
    return ScanBatchAck(acks=[ScanAck(seq=a.seq, map_version=a.map_version) for a in acks])
