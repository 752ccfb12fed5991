"""uvicorn's h11 protocol with a deadline for each request's head, room kept for new
connections, and each response sent in one write.

uvicorn closes a keep-alive connection only after a response, and its timer is reset by
any byte: a client that connects and sends nothing, or sends its headers one byte at a
time, holds a connection (and a file descriptor) for ever; 1,050 of them under a 1,024
descriptor limit stopped the server answering ``/healthz``. Here the request line and
headers must all arrive within ``head_timeout_s`` [s] of the connection opening or of
the previous response, else the connection is closed (as nginx's
``client_header_timeout``). Body arrival is bounded in ``guards.BodyMiddleware``.

Connections that sit idle also hold descriptors until that deadline; past
``max_connections`` uvicorn answers every new request 503, and past the process's
descriptor limit it cannot even accept one. So a connection that opens when
``max_connections`` are open evicts the ones idle longest (waiting at least
``MIN_IDLE_S`` for their next request head: they lose nothing); when none is idle,
uvicorn answers the new one 503.

A response's status line, headers and body are sent as one ``send()``
(``write_coalescing.CoalescingTransport``, flushed when the response is complete), not one
for the head and one for the body.

This subclasses uvicorn's ``H11Protocol`` and reads its h11 connection's state (uvicorn
has no hook for it); ``tests/api/test_server_limits.py`` checks it against the installed
uvicorn.
"""

from __future__ import annotations

import asyncio
import time

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from mapserver.api.write_coalescing import CoalescingTransport

MIN_IDLE_S = 0.25  # [s] a connection waiting this long for its request head is idle


class HeadDeadlineProtocol(H11Protocol):
    """``H11Protocol`` that closes a connection whose request head is late and sends a
    response's pieces as one write."""

    head_timeout_s: float = 10.0  # set by ``with_head_timeout``
    max_connections: int | None = None  # likewise; None: no eviction
    _head_timer: asyncio.TimerHandle | None = None
    _idle_since: float | None = None  # [s] monotonic, while waiting for a request head

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)  # flow control and addresses: the socket's own
        self.transport = CoalescingTransport(transport, self.loop)  # type: ignore[assignment]
        self._watch_head()
        self._make_room()

    def _make_room(self) -> None:
        """While ``max_connections`` or more are open, close the connections idle longest
        (idle at least ``MIN_IDLE_S``: a new one's request head may be on its way); if
        some are too young yet, look again when they are old enough."""
        if self.max_connections is None:
            return
        open_ = [c for c in self.connections if not c.transport.is_closing()]
        excess = len(open_) - (self.max_connections - 1)
        if excess <= 0:
            return
        idle = sorted(
            (c._idle_since, id(c), c)
            for c in open_
            if isinstance(c, HeadDeadlineProtocol) and c._idle_since is not None and c is not self
        )
        now = time.monotonic()
        for since, _, connection in idle:
            if excess <= 0:
                return
            if now - since < MIN_IDLE_S:  # the rest are younger still
                self.loop.call_later(MIN_IDLE_S - (now - since), self._make_room)
                return
            connection.transport.close()
            excess -= 1

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_head_timer()
        super().connection_lost(exc)

    def handle_events(self) -> None:
        super().handle_events()
        self._watch_head()

    def on_response_complete(self) -> None:
        self.transport.flush()  # type: ignore[attr-defined]
        super().on_response_complete()
        self._watch_head()

    def handle_websocket_upgrade(self, event: h11.Request) -> None:
        """The upgraded connection's protocol writes to the socket's transport itself."""
        self.transport = self.transport.wrapped  # type: ignore[attr-defined]
        super().handle_websocket_upgrade(event)

    def _watch_head(self) -> None:
        """Run the head timer while the connection waits for a request head, else stop it."""
        waiting = self.conn.their_state is h11.IDLE and not self.transport.is_closing()
        if waiting and self._head_timer is None:
            self._head_timer = self.loop.call_later(self.head_timeout_s, self._head_late)
            self._idle_since = time.monotonic()
        elif not waiting:
            self._cancel_head_timer()

    def _cancel_head_timer(self) -> None:
        self._idle_since = None
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _head_late(self) -> None:
        self._head_timer = None
        if self.conn.their_state is h11.IDLE and not self.transport.is_closing():
            self.transport.close()


def with_head_timeout(
    head_timeout_s: float, max_connections: int | None = None
) -> type[HeadDeadlineProtocol]:
    """A ``HeadDeadlineProtocol`` class for uvicorn's ``http=`` with this deadline [s]
    and this many connections at most."""
    fields = {"head_timeout_s": head_timeout_s, "max_connections": max_connections}
    return type("HeadDeadlineProtocol", (HeadDeadlineProtocol,), fields)
