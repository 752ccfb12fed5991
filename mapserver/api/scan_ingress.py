"""Scan ingest as plain ASGI: ``POST /v1/scans`` and ``POST /v1/scans/batch`` answered
before FastAPI's exception, routing and dependency layers.

At a hundred units posting at 10 Hz the server answers a thousand requests a second on
the same cores that fuse the scans; FastAPI's per-request machinery (its middleware
stack, route matching, dependency solving, response model validation) cost more event
loop time than the scan's own parsing. ``ScanIngress`` sits inside the server's edge
middleware (``guards``: Host and Origin, content type, body size and time; the latency
metrics), so those bounds hold as for every route, and runs the same handlers
(``routes_scans.INGEST``): the same admission, validation, errors and replies. An
``HTTPException`` (a refusal, or a body bound from ``guards``) is answered as the app's
handler answers it; anything else propagates to the app's server-error handling.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping
from typing import Any

import orjson
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import Response
from starlette.types import ASGIApp, Receive, Scope, Send

Handler = Callable[[Request], Awaitable[Any]]
ErrorHandler = Callable[[Request, HTTPException], Awaitable[Response]]


class ScanIngress:
    """Answers POSTs to ``handlers``' paths with their JSON reply; passes the rest on.

    routes: the app's route object for each path (set as ``scope["route"]``, which the
    latency metrics label requests by); on_error: the app's ``HTTPException`` handler.
    """

    def __init__(
        self,
        app: ASGIApp,
        handlers: Mapping[str, Handler],
        routes: Mapping[str, Any],
        on_error: ErrorHandler,
    ) -> None:
        self.app = app
        self.handlers = handlers
        self.routes = routes
        self.on_error = on_error

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        handler = self.handlers.get(scope.get("path", "")) if scope["type"] == "http" else None
        if handler is None or scope["method"] != "POST":
            await self.app(scope, receive, send)
            return
        scope["route"] = self.routes[scope["path"]]
        request = Request(scope, receive)
        try:
            reply = await handler(request)
        except HTTPException as exc:
            response = await self.on_error(request, exc)
        else:
            response = Response(orjson.dumps(reply), media_type="application/json")
        await response(scope, receive, send)
