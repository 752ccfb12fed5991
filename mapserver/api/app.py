"""``create_app(settings)``: the map server's FastAPI application.

The app owns one ``MapService`` (created here, restored from its data directory, closed
at shutdown) and one ``UnitBoard`` (units' poses and paths, in memory), and serves the
live viewer at ``/``. Every error reply is ``{"detail": "<field>: <problem>, got <value>"}``.
"""

from __future__ import annotations

import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from mapserver.api import (
    routes_maps,
    routes_ops,
    routes_plan,
    routes_query,
    routes_scans,
    routes_units,
    routes_viewer,
)
from mapserver.api.admission import Admission
from mapserver.api.metrics import ServerMetrics
from mapserver.api.schemas import CellsIn, PlanIn, ScanBatchIn, ScanIn, SegmentsIn, UnitsIn
from mapserver.api.unit_board import UnitBoard
from mapserver.service import MapService
from mapserver.settings import Settings


def create_app(settings: Settings, service: MapService | None = None) -> FastAPI:
    """The app for ``settings``; ``service`` defaults to a new MapService on its data dir."""
    service = service or MapService(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        yield
        app.state.query_admission.close()
        app.state.plan_admission.close()
        service.close()

    app = FastAPI(
        title="fleetmap map server",
        version="1",
        description="The fleet's shared occupancy map and Nav2-compatible costmap.",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.service = service
    app.state.metrics = ServerMetrics(service)
    app.state.token_roles = settings.token_roles()
    app.state.units = UnitBoard()
    reads = settings.reads
    app.state.query_admission = Admission(
        "query",
        reads.max_concurrent_queries,
        reads.max_queued_queries,
        reads.retry_after_s,
        reads.nice,
    )
    app.state.plan_admission = Admission(
        "plan", 1, reads.max_queued_plans, reads.retry_after_s, reads.nice
    )
    routers = (routes_scans, routes_maps, routes_query, routes_plan, routes_units, routes_ops)
    for module in (*routers, routes_viewer):
        app.include_router(module.router)
    _add_body_schemas(app)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    app.add_middleware(LatencyMiddleware, metrics=app.state.metrics)
    return app


def _add_body_schemas(app: FastAPI) -> None:
    """Publish the body models of the routes that read raw JSON (all POST routes)."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = build()
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            for model in (ScanIn, ScanBatchIn, UnitsIn, CellsIn, SegmentsIn, PlanIn):
                model_schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
                components.update(model_schema.pop("$defs", {}))
                components[model.__name__] = model_schema
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    """422 naming the first offending field (its location) and value."""
    first = exc.errors()[0]
    where = ".".join(str(part) for part in first.get("loc", ()) if part != "body") or "body"
    value = first.get("input")
    detail = f"{where}: {first.get('msg', 'invalid')}, got {value!r:.80}"
    return JSONResponse({"detail": detail}, status_code=422)


async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
    detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
    return JSONResponse({"detail": detail}, status_code=exc.status_code, headers=exc.headers)


class LatencyMiddleware:
    """Observes each HTTP request's latency [s] by method, route template and status
    (plain ASGI: Starlette's BaseHTTPMiddleware costs more than a scan's fusion)."""

    def __init__(self, app: ASGIApp, metrics: ServerMetrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status = 500

        async def send_and_record(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_and_record)
        finally:
            route = getattr(scope.get("route"), "path", "unmatched")
            self.metrics.request_latency.labels(scope["method"], route, str(status)).observe(
                time.perf_counter() - start
            )
