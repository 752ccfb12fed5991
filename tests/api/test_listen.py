"""The socket ``fleetmap serve`` listens on: the connections the server accepts from it
have Nagle's algorithm off, so a reply written in two parts (headers, then body) is not
held back for the client's delayed ACK on a kept-alive connection."""

import asyncio
import socket

import pytest

from mapserver.cli.listen import listen


def _accepted_nodelay(host: str) -> int:
    """TCP_NODELAY of a connection accepted by asyncio's server on ``listen(host, 0)``,
    as uvicorn serves it (``create_server(sock=...)``)."""
    listener = listen(host, 0)
    port = listener.getsockname()[1]
    seen: asyncio.Future

    class Record(asyncio.Protocol):
        def connection_made(self, transport: asyncio.BaseTransport) -> None:
            sock = transport.get_extra_info("socket")
            seen.set_result(sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
            transport.close()

    async def run() -> int:
        nonlocal seen
        seen = asyncio.get_running_loop().create_future()
        server = await asyncio.get_running_loop().create_server(Record, sock=listener)
        async with server:
            _, writer = await asyncio.open_connection(host.strip("[]"), port)
            value = await asyncio.wait_for(seen, 10)
            writer.close()
            return value

    return asyncio.run(run())


def test_connections_accepted_on_ipv4_loopback_have_nagle_off():
    assert _accepted_nodelay("127.0.0.1") != 0


def test_connections_accepted_on_ipv6_loopback_have_nagle_off():
    if not socket.has_ipv6:
        pytest.skip("no IPv6 on this machine")
    try:
        socket.create_server(("::1", 0)).close()
    except OSError:
        pytest.skip("no IPv6 loopback on this machine")
    assert _accepted_nodelay("::1") != 0


def test_the_listener_is_tcp_on_the_asked_family():
    listener = listen("127.0.0.1", 0)
    try:
        assert (listener.family, listener.type, listener.proto) == (
            socket.AF_INET,
            socket.SOCK_STREAM,
            socket.IPPROTO_TCP,
        )
    finally:
        listener.close()
