"""``POST /v1/scans`` and ``POST /v1/scans/batch`` (docs/http-api.md 2.1)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request

from mapserver.api import ingest_budget
from mapserver.api.auth import WRITE, require, require_unit
from mapserver.api.body import body_schema, parse_json
from mapserver.api.future_bridge import wrap_in_bursts
from mapserver.api.guards import media_type
from mapserver.api.scan_fields import unknown_batch_field, unknown_scan_field
from mapserver.api.schemas import ErrorOut, ScanAck, ScanBatchAck, ScanBatchIn, ScanIn
from mapserver.core.scan import Scan, ScanError
from mapserver.core.scan_binary import (
    CONTENT_TYPE,
    ScanEncodingError,
    UnknownFlagError,
    decode_scans,
)
from mapserver.core.text import quote
from mapserver.service.map_service import MapService
from mapserver.service.scan_gate import IngestError

router = APIRouter(tags=["scans"])
ADMIT_WRITE = require(WRITE)

ERRORS = {status: {"model": ErrorOut} for status in (400, 401, 403, 409, 413, 415, 422, 429, 503)}


async def _body(request: Request, batch: bool) -> Any:
    """The body as JSON, or a binary scan body as the same mappings (docs/scan-binary.md):
    one scan, or for a batch ``{"scans": [...]}``; 400 when it is neither."""
    raw = await request.body()
    if media_type(request.headers.get("content-type")) != CONTENT_TYPE:
        return parse_json(raw)
    try:
        scans = decode_scans(raw, batch)
    except ScanEncodingError as exc:  # an unknown flag is a field this server does not know
        raise HTTPException(422 if isinstance(exc, UnknownFlagError) else 400, str(exc)) from None
    return {"scans": scans} if batch else scans[0]


def _parse(request: Request, item: Any, prefix: str) -> Scan:
    """The scan in ``item`` (422 naming ``prefix`` + field, or a key that is no field
    and the nearest one), one the token may post (403)."""
    unknown = unknown_scan_field(item)
    if unknown is not None:
        raise HTTPException(422, f"{prefix}{unknown}")
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
        acks = await wrap_in_bursts(service.submit(scans))
    except IngestError as exc:
        metrics.scans_rejected.labels(str(exc.status)).inc()
        raise HTTPException(exc.status, exc.detail) from None
    metrics.scans_fused.inc(len(acks))
    return acks


async def ingest_scan(request: Request) -> dict[str, int]:
    """``POST /v1/scans``: admit, parse, submit; the ack as a JSON object."""
    await ADMIT_WRITE(request)
    ingest_budget.refuse_token_in_debt(request)
    body = await _body(request, batch=False)
    ingest_budget.look(request, [body])
    scan = _parse(request, body, "")
    ingest_budget.charge(request, [scan])
    (ack,) = await _submit(request, [scan])
    return {"seq": ack.seq, "map_version": ack.map_version}


async def ingest_batch(request: Request) -> dict[str, list[dict[str, int]]]:
    """``POST /v1/scans/batch``: all the scans or none; one ack each, in order."""
    await ADMIT_WRITE(request)
    ingest_budget.refuse_token_in_debt(request)
    body = await _body(request, batch=True)
    limits = request.app.state.settings.limits
    unknown = unknown_batch_field(body)
    if unknown is not None:
        raise HTTPException(422, unknown)
    items = body.get("scans") if isinstance(body, dict) else None
    if not isinstance(items, list) or not items:
        raise HTTPException(422, f"scans: must be a non-empty list of scans, got {quote(items)}")
    if len(items) > limits.max_batch:
        raise HTTPException(422, f"scans: at most {limits.max_batch} per batch, got {len(items)}")
    ingest_budget.look(request, items)
    scans = [_parse(request, item, f"scans[{i}].") for i, item in enumerate(items)]
    ingest_budget.charge(request, scans)
    acks = await _submit(request, scans)
    return {"acks": [{"seq": a.seq, "map_version": a.map_version} for a in acks]}


INGEST = {"/v1/scans": ingest_scan, "/v1/scans/batch": ingest_batch}
"""The scan routes by path, for ``scan_ingress.ScanIngress``, which answers them."""


# The routes below document the two operations in the OpenAPI schema; requests to them are
# answered by ``ScanIngress`` before FastAPI's router (the same handlers, less overhead).
# Their ``dependencies`` document the admission the handlers do (for the bearer scheme).
@router.post(
    "/v1/scans",
    response_model=ScanAck,
    responses=ERRORS,
    openapi_extra=body_schema(ScanIn, CONTENT_TYPE),
    dependencies=[Depends(ADMIT_WRITE)],
    summary="Post one scan; durable once acknowledged",
)
async def post_scan(request: Request) -> dict[str, int]:
    return await ingest_scan(request)


@router.post(
    "/v1/scans/batch",
    response_model=ScanBatchAck,
    responses=ERRORS,
    openapi_extra=body_schema(ScanBatchIn, CONTENT_TYPE),
    dependencies=[Depends(ADMIT_WRITE)],
    summary="Post several scans; all are accepted or none",
)
async def post_scans(request: Request) -> dict[str, list[dict[str, int]]]:
    return await ingest_batch(request)
