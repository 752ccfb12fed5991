"""A transport that sends a response's writes as one ``send()``.

uvicorn's h11 protocol writes a response in pieces: the status line and headers, then the
body (then an empty end of message). With ``TCP_NODELAY`` on (asyncio sets it on the
server's connections: a round trip must not wait for a delayed ACK, docs/scaling.md),
every ``write`` is a ``send()`` system call and a segment of its own, and on loopback the
kernel delivers each segment to the reader within the writer's system call. Under the
fleet load benchmark's 360-beam scans those sends were 27 % of the event loop's busy time
(py-spy), half of it for the headers alone.

``CoalescingTransport`` holds the writes and sends them joined when the response is
complete (``flush``, called by the protocol), before the connection closes, or, for a
response that is still streaming, at the event loop's next turn (``call_soon``): a byte
is never held longer than one turn of the loop. Everything else is the wrapped
transport's.
"""

from __future__ import annotations

import asyncio
from typing import Any


class CoalescingTransport:
    """Wraps ``transport``; ``write`` holds bytes until ``flush`` (see the module)."""

    def __init__(self, transport: asyncio.Transport, loop: asyncio.AbstractEventLoop) -> None:
        self._transport = transport
        self._loop = loop
        self._held: list[bytes] = []

    @property
    def wrapped(self) -> asyncio.Transport:
        """The transport the bytes are sent on."""
        return self._transport

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if not data:
            return
        if not self._held:
            self._loop.call_soon(self.flush)
        self._held.append(bytes(data))

    def writelines(self, chunks: Any) -> None:
        for data in chunks:
            self.write(data)

    def flush(self) -> None:
        """Send what is held as one write (nothing when nothing is)."""
        if not self._held:
            return
        data = self._held[0] if len(self._held) == 1 else b"".join(self._held)
        self._held.clear()
        if not self._transport.is_closing():
            self._transport.write(data)

    def close(self) -> None:
        self.flush()
        self._transport.close()

    def write_eof(self) -> None:
        self.flush()
        self._transport.write_eof()

    def abort(self) -> None:
        self._held.clear()
        self._transport.abort()

    def get_write_buffer_size(self) -> int:
        return self._transport.get_write_buffer_size() + sum(map(len, self._held))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._transport, name)
