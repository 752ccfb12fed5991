"""Operations: ``/healthz`` and ``/metrics`` (``/docs``: ``routes_docs``)."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from mapserver.api.schemas import Health

router = APIRouter(tags=["operations"])


@router.get("/healthz", response_model=Health)
async def healthz(request: Request) -> Health:
    """200 once the map is restored and the server accepts scans. Answered on the event
    loop itself (no worker thread), so busy readers cannot hold it up."""
    return Health(status="ok", version=request.app.state.service.version)


@router.get("/metrics", response_class=Response, responses={200: {"content": {"text/plain": {}}}})
def metrics(request: Request) -> Response:
    """Prometheus text format."""
    body = generate_latest(request.app.state.metrics.registry)
    return Response(body, media_type=CONTENT_TYPE_LATEST)
