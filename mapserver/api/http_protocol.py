"""uvicorn's h11 protocol with a deadline for each request's head.

uvicorn closes a keep-alive connection only after a response, and its timer is reset by
any byte: a client that connects and sends nothing, or sends its headers one byte at a
time, holds a connection (and a file descriptor) for ever; 1,050 of them under a 1,024
descriptor limit stopped the server answering ``/healthz``. Here the request line and
headers must all arrive within ``head_timeout_s`` [s] of the connection opening or of
the previous response, else the connection is closed (as nginx's
``client_header_timeout``). Body arrival is bounded in ``guards.BodyMiddleware``.

This subclasses uvicorn's ``H11Protocol`` and reads its h11 connection's state (uvicorn
has no hook for it); ``tests/test_server_limits.py`` checks it against the installed
uvicorn.
"""

from __future__ import annotations

import asyncio

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol


class HeadDeadlineProtocol(H11Protocol):
    """``H11Protocol`` that closes a connection whose request head is late."""

    head_timeout_s: float = 10.0  # set by ``with_head_timeout``
    _head_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._watch_head()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_head_timer()
        super().connection_lost(exc)

    def handle_events(self) -> None:
        super().handle_events()
        self._watch_head()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._watch_head()

    def _watch_head(self) -> None:
        """Run the head timer while the connection waits for a request head, else stop it."""
        waiting = self.conn.their_state is h11.IDLE and not self.transport.is_closing()
        if waiting and self._head_timer is None:
            self._head_timer = self.loop.call_later(self.head_timeout_s, self._head_late)
        elif not waiting:
            self._cancel_head_timer()

    def _cancel_head_timer(self) -> None:
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _head_late(self) -> None:
        self._head_timer = None
        if self.conn.their_state is h11.IDLE and not self.transport.is_closing():
            self.transport.close()


def with_head_timeout(head_timeout_s: float) -> type[HeadDeadlineProtocol]:
    """A ``HeadDeadlineProtocol`` class for uvicorn's ``http=`` with this deadline [s]."""
    return type("HeadDeadlineProtocol", (HeadDeadlineProtocol,), {"head_timeout_s": head_timeout_s})
