"""The server's edge, as plain ASGI middleware (before routing, auth and body parsing).

``LocalOnlyMiddleware``: an open server (no tokens) answers only requests whose ``Host``
is loopback and whose ``Origin``, when sent, is a loopback origin (403 otherwise): a web
page in a browser on the same machine can neither post to it nor read it by DNS
rebinding.

``BodyMiddleware``: a POST, PUT or PATCH must declare ``Content-Type: application/json``
(parameters such as ``charset`` allowed), or for scans (``SCAN_PATHS``) the binary scan
encoding's ``application/vnd.fleetmap.scan`` (415 otherwise); every request may send at most
``limits.max_body_bytes`` bytes of body, declared or streamed (413), and must send all
of it within ``server.body_timeout_s`` seconds of its headers (408). Every route gets these bounds,
whether it reads its body itself or through a pydantic model.
"""

from __future__ import annotations

import asyncio
import json
import time
from urllib.parse import urlsplit

from fastapi import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from mapserver.core.errors import FleetmapError
from mapserver.core.scan_binary import CONTENT_TYPE as BINARY_SCAN_TYPE
from mapserver.service.settings import Settings, is_loopback

BODY_METHODS = frozenset({"POST", "PUT", "PATCH"})
JSON_TYPE = "application/json"
SCAN_PATHS = frozenset({"/v1/scans", "/v1/scans/batch"})  # also take binary scan bodies


class BodyRefused(FleetmapError, HTTPException):
    """A request body past a limit; raised from ``receive`` inside the app, whose error
    handler answers it (and ``BodyMiddleware`` answers it if it escapes the app)."""


async def refuse(send: Send, status: int, detail: str) -> None:
    """Answer ``{"detail": detail}`` with ``status`` and close the connection."""
    body = json.dumps({"detail": detail}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


def media_type(content_type: str | None) -> str:
    """The media type of a Content-Type header, lower case, without parameters."""
    return (content_type or "").partition(";")[0].strip().lower()


def header(scope: Scope, name: bytes) -> str | None:
    """The first value of header ``name`` (lower case) as text, or None."""
    for key, value in scope.get("headers", ()):
        if key == name:
            return value.decode("latin-1")
    return None


class LocalOnlyMiddleware:
    """403 for an open server's requests with a foreign Host or Origin (see module)."""

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.enabled = settings.open_access
        self.local_names = {"localhost", *(n.lower() for n in settings.server.local_hostnames)}

    def is_local(self, host: str) -> bool:
        """True for loopback addresses, ``localhost`` and ``server.local_hostnames``."""
        name = host.lower()
        return name in self.local_names or is_loopback(name)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if self.enabled and scope["type"] == "http":
            problem = self.problem(header(scope, b"host"), header(scope, b"origin"))
            if problem is not None:
                await refuse(send, 403, problem)
                return
        await self.app(scope, receive, send)

    def problem(self, host: str | None, origin: str | None) -> str | None:
        """Why an open server refuses these headers, or None to let the request in."""
        name = _host_name(host or "")
        if name is None or not self.is_local(name):
            return (
                f"host: an open server (no tokens) answers only loopback Host headers, got {host!r}"
            )
        if origin is not None:
            parts = urlsplit(origin)
            origin_name = _host_name(parts.netloc) if parts.scheme in ("http", "https") else None
            if origin_name is None or not self.is_local(origin_name):
                return (
                    f"origin: an open server (no tokens) answers only requests from loopback "
                    f"origins (http://127.0.0.1:PORT, http://localhost:PORT), got {origin!r}"
                )
        return None


def _host_name(netloc: str) -> str | None:
    """The host of ``host[:port]`` or ``[v6]:port`` (brackets dropped), None if malformed."""
    text = netloc.strip()
    if text.startswith("["):
        name, bracket, rest = text[1:].partition("]")
        if not bracket or (rest and not (rest.startswith(":") and rest[1:].isdigit())):
            return None
        return name
    name, colon, port = text.partition(":")
    if not name or (colon and not port.isdigit()):
        return None
    return name


class BodyMiddleware:
    """Content type (415), size (413) and arrival time (408) of request bodies."""

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.limit = settings.limits.max_body_bytes
        self.timeout = settings.server.body_timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        content_type = header(scope, b"content-type")
        if scope["method"] not in BODY_METHODS:
            content_type = JSON_TYPE  # a GET's body, if any, is only bounded
        problem = self.problem(content_type, header(scope, b"content-length"), scope["path"])
        if problem is not None:
            await refuse(send, *problem)
            return
        started = False

        async def send_tracked(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, self.bounded(receive), send_tracked)
        except BodyRefused as exc:
            if started:
                raise
            await refuse(send, exc.status_code, exc.detail)

    def problem(
        self, content_type: str | None, length: str | None, path: str = ""
    ) -> tuple[int, str] | None:
        """(status, detail) refusing a request to ``path`` by its headers alone, or None."""
        media = media_type(content_type)
        if media != JSON_TYPE and not (media == BINARY_SCAN_TYPE and path in SCAN_PATHS):
            also = f" (or {BINARY_SCAN_TYPE})" if path in SCAN_PATHS else ""
            return 415, f"content-type: must be {JSON_TYPE}{also}, got {content_type!r}"
        if length is not None and (not length.strip().isdigit() or int(length) > self.limit):
            return 413, f"body: at most {self.limit} bytes (limits.max_body_bytes), got {length}"
        return None

    def bounded(self, receive: Receive) -> Receive:
        """``receive`` that raises BodyRefused past the size limit or the body deadline."""
        deadline = time.monotonic() + self.timeout
        size = 0
        done = False

        async def bounded_receive() -> Message:
            nonlocal size, done
            if done:
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), deadline - time.monotonic())
            except TimeoutError:
                raise BodyRefused(
                    408,
                    f"body: not all of it arrived within {self.timeout} s "
                    f"(server.body_timeout_s), got {size} bytes",
                ) from None
            if message["type"] == "http.request":
                size += len(message.get("body", b""))
                if size > self.limit:
                    raise BodyRefused(
                        413,
                        f"body: at most {self.limit} bytes (limits.max_body_bytes), got more",
                    )
                done = not message.get("more_body", False)
            return message

        return bounded_receive
