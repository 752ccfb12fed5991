"""``create_app(settings)``: the map server's FastAPI application.

The app owns one ``MapService`` (created here, restored from its data directory, closed
at shutdown) and one ``UnitBoard`` (units' poses and paths, in memory), and serves the
live viewer at ``/``. Every error reply is ``{"detail": "<field>: <problem>, got <value>"}``.
"""

from __future__ import annotations

import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from functools import partial
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from mapserver.api import (
    routes_clock,
    routes_docs,
    routes_maps,
    routes_ops,
    routes_plan,
    routes_query,
    routes_scans,
    routes_units,
    routes_viewer,
)
from mapserver.api.admission import Admission
from mapserver.api.auth import openapi_security
from mapserver.api.guards import BodyMiddleware, LocalOnlyMiddleware
from mapserver.api.ingest_budget import budget_from_settings
from mapserver.api.metrics import ServerMetrics, method_label
from mapserver.api.planning import CostmapPlanner, GridPlanning
from mapserver.api.routes_scans import INGEST
from mapserver.api.scan_ingress import ScanIngress
from mapserver.api.schemas import (
    CellsIn,
    ClockIn,
    ErrorOut,
    PlanIn,
    ScanBatchIn,
    ScanIn,
    SegmentsIn,
    UnitsIn,
)
from mapserver.api.unit_board import UnitBoard
from mapserver.core.geometry import GridGeometry
from mapserver.core.text import quote
from mapserver.service.map_process import MapProcess, open_map_service
from mapserver.service.map_service import MapService
from mapserver.service.settings import Settings
from planner.grid_search import GridPlanner


def create_app(
    settings: Settings,
    service: MapService | MapProcess | None = None,
    planner_factory: Callable[[GridGeometry], GridPlanning] | None = None,
) -> FastAPI:
    """The app for ``settings``; ``service`` defaults to the map of its data dir, in this
    process or in its own (``server.map_process``, ``map_process.open_map_service``);
    ``POST /v1/plan`` plans with ``planner_factory(geometry)`` (by default the grid A* /
    Dijkstra of ``planner.grid_search``, with ``reads.plan_landmarks`` landmarks over the
    static map's lower bound when the service has a static map)."""
    service = service or open_map_service(settings)
    if planner_factory is None:
        landmarks = settings.reads.plan_landmarks if service.planning_bounds is not None else 0
        planner_factory = partial(GridPlanner, landmarks=landmarks)

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
        docs_url=None,  # routes_docs serves /docs from packaged files, not a CDN
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.service = service
    app.state.planner = CostmapPlanner(service, planner_factory)
    app.state.metrics = ServerMetrics(service)
    app.state.tokens = settings.token_table()
    app.state.units = UnitBoard()
    app.state.ingest_budget = budget_from_settings(settings.ingest, time.monotonic)
    reads = settings.reads
    app.state.query_admission = Admission(
        "query",
        reads.max_concurrent_queries,
        reads.max_queued_queries,
        reads.retry_after_s,
        reads.nice,
        reads.query_busy_share,
    )
    app.state.plan_admission = Admission(
        "plan", 1, reads.max_queued_plans, reads.retry_after_s, reads.nice
    )
    app.state.metrics.watch_reads(
        {"query": app.state.query_admission, "plan": app.state.plan_admission}
    )
    routers = (
        routes_scans,
        routes_maps,
        routes_query,
        routes_plan,
        routes_units,
        routes_clock,
        routes_ops,
    )
    for module in (*routers, routes_viewer, routes_docs):
        app.include_router(module.router)
    _complete_openapi(app)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    scan_routes = {route.path: route for route in routes_scans.router.routes}
    app.add_middleware(
        ScanIngress, handlers=INGEST, routes=scan_routes, on_error=_http_error
    )  # innermost of the edge: inside the body, Host and latency guards
    app.add_middleware(BodyMiddleware, settings=settings)
    app.add_middleware(LocalOnlyMiddleware, settings=settings)
    app.add_middleware(LatencyMiddleware, metrics=app.state.metrics)  # outermost: sees all
    return app


# What the edge (``guards``) may answer any operation, and any operation with a body.
EDGE_RESPONSES = {
    "403": "an open server refuses a foreign Host or Origin; a token may not do this",
    "408": "the body did not all arrive within server.body_timeout_s",
    "413": "the body is larger than limits.max_body_bytes",
}
BODY_RESPONSES = {
    "400": "the body is not JSON, nests too deep or holds an integer beyond the float range",
    "415": "the body is not declared Content-Type: application/json",
}


def _complete_openapi(app: FastAPI) -> None:
    """Publish the body models of the routes that read raw JSON (every POST and PUT), the
    edge's refusals on every operation (so the schema lists every status it can send) and
    the bearer scheme on the operations that need a token (``auth.openapi_security``)."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = build()
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            for model in (ScanIn, ScanBatchIn, UnitsIn, CellsIn, SegmentsIn, PlanIn, ClockIn):
                model_schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
                components.update(model_schema.pop("$defs", {}))
                components[model.__name__] = model_schema
            components.setdefault("ErrorOut", ErrorOut.model_json_schema())
            for path in schema.get("paths", {}).values():
                for method, operation in path.items():
                    body = method in ("post", "put")
                    edge = {**EDGE_RESPONSES, **(BODY_RESPONSES if body else {})}
                    _add_errors(operation.setdefault("responses", {}), edge)
            openapi_security(schema)
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def _add_errors(responses: dict[str, Any], errors: dict[str, str]) -> None:
    """Add each ``status: description`` not yet documented, with an ErrorOut body."""
    body = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorOut"}}}
    for status, description in errors.items():
        responses.setdefault(status, {"description": description, "content": body})


async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    """422 naming the first offending field (its location) and value."""
    first = exc.errors()[0]
    where = ".".join(str(part) for part in first.get("loc", ()) if part != "body") or "body"
    detail = f"{where}: {first.get('msg', 'invalid')}, got {quote(first.get('input'))}"
    return JSONResponse({"detail": detail}, status_code=422)


async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
    detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
    return JSONResponse({"detail": detail}, status_code=exc.status_code, headers=exc.headers)


class LatencyMiddleware:
    """Observes each HTTP request's latency [s] by method, route template and status
    (plain ASGI: Starlette's BaseHTTPMiddleware costs more than a scan's fusion). Labels
    are bounded: a made-up method is ``OTHER``, a path no route matches ``unmatched``."""

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
            method = method_label(scope["method"])
            self.metrics.request_latency.labels(method, route, str(status)).observe(
                time.perf_counter() - start
            )
