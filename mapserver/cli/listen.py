"""The socket ``fleetmap serve`` listens on, bound before the server starts, so that a
port in use or an address that is not this machine's is one ``error:`` line naming the
setting to change (exit 2), not uvicorn's log line and its exit status 3."""

from __future__ import annotations

import errno
import socket

from mapserver.core.errors import FleetmapError

REASONS = {
    errno.EADDRINUSE: ("--port", "another program listens there (stop it, or choose another "
                       "--port; --port 0 picks a free one)"),
    errno.EADDRNOTAVAIL: ("--host", "not an address of this machine (choose another --host)"),
    errno.EACCES: ("--port", "permission denied (ports below 1024 need privileges: choose a "
                   "--port from 1024)"),
}  # fmt: skip
"""What each bind failure means, the flag it is about and the fix, by errno."""


class ListenError(FleetmapError, OSError):
    """The server cannot listen at ``host``:``port``; the message says why and what to change."""


def listen(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host`` (a name or IPv4 address; IPv6 when it holds a
    colon, as uvicorn reads it) and ``port`` (0: a free one), address reuse on as uvicorn
    sets it; ListenError when the bind fails."""
    address = host.strip("[]")
    family = socket.AF_INET6 if ":" in address else socket.AF_INET
    # proto named, not 0: the connections accepted from it inherit it, and asyncio turns
    # Nagle's algorithm off (TCP_NODELAY) only on sockets whose proto is IPPROTO_TCP.
    # With proto 0 every reply on a kept-alive connection (headers and body written
    # apart) waited for the client's delayed ACK: 44 ms a request on Linux loopback.
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((address, port))
    except OSError as exc:
        sock.close()
        if isinstance(exc, socket.gaierror):
            flag, reason = "--host", f"{exc.strerror} (choose another --host)"
        else:
            flag, reason = REASONS.get(
                exc.errno, ("--port", f"{exc.strerror} (choose another --host or --port)")
            )
        shown = f"[{address}]" if ":" in address else address
        value = port if flag == "--port" else host
        raise ListenError(f"{flag} {value}: cannot listen on {shown}:{port}: {reason}") from None
    sock.set_inheritable(True)
    return sock
