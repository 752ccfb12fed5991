"""A response leaves the server in one write: ``CoalescingTransport`` on its own, and
under ``HeadDeadlineProtocol`` (the server's uvicorn protocol) answering a real ASGI app,
with a recording transport in place of the socket."""

import asyncio

import pytest
from uvicorn.config import Config
from uvicorn.server import ServerState

from mapserver.api.http_protocol import with_head_timeout
from mapserver.api.write_coalescing import CoalescingTransport


class RecordingTransport:
    """The socket transport's surface that uvicorn's protocol uses; records each write."""

    def __init__(self) -> None:
        self.writes: list[bytes] = []
        self.closed = False
        self.aborted = False
        self.eof = False
        self.protocol = None

    def write(self, data: bytes) -> None:
        assert not self.closed, "a write after close"
        self.writes.append(bytes(data))

    def write_eof(self) -> None:
        self.eof = True

    def is_closing(self) -> bool:
        return self.closed

    def close(self) -> None:
        self.closed = True

    def abort(self) -> None:
        self.aborted = self.closed = True

    def get_write_buffer_size(self) -> int:
        return 7

    def get_extra_info(self, name: str, default=None):
        return {"sockname": ("127.0.0.1", 8000), "peername": ("127.0.0.1", 50000)}.get(
            name, default
        )

    def pause_reading(self) -> None:
        pass

    def resume_reading(self) -> None:
        pass

    def set_protocol(self, protocol) -> None:
        self.protocol = protocol


@pytest.fixture
def loop():
    loop = asyncio.new_event_loop()
    yield loop
    loop.close()


def one_turn(loop) -> None:
    """Run the loop's callbacks that are ready now (one turn)."""
    loop.run_until_complete(asyncio.sleep(0))


def test_writes_are_held_and_sent_joined_on_flush(loop):
    socket = RecordingTransport()
    transport = CoalescingTransport(socket, loop)
    transport.write(b"HTTP/1.1 200 OK\r\n\r\n")
    transport.write(bytearray(b"{"))
    transport.writelines([memoryview(b'"a"'), b"}", b""])
    assert socket.writes == []
    assert transport.get_write_buffer_size() == 7 + 19 + 1 + 3 + 1
    transport.flush()
    assert socket.writes == [b'HTTP/1.1 200 OK\r\n\r\n{"a"}']
    transport.flush()
    one_turn(loop)  # the turn's flush finds nothing held
    assert socket.writes == [b'HTTP/1.1 200 OK\r\n\r\n{"a"}']


def test_a_streaming_write_is_sent_at_the_next_turn_of_the_loop(loop):
    socket = RecordingTransport()
    transport = CoalescingTransport(socket, loop)
    transport.write(b"chunk one ")
    transport.write(b"chunk two")
    one_turn(loop)
    assert socket.writes == [b"chunk one chunk two"]
    transport.write(b"three")
    one_turn(loop)
    assert socket.writes == [b"chunk one chunk two", b"three"]


def test_close_and_write_eof_send_what_is_held_first_and_abort_drops_it(loop):
    socket = RecordingTransport()
    transport = CoalescingTransport(socket, loop)
    transport.write(b"last")
    transport.write_eof()
    assert socket.writes == [b"last"] and socket.eof
    transport.write(b"bye")
    transport.close()
    assert socket.writes == [b"last", b"bye"] and socket.closed
    one_turn(loop)  # the scheduled flush after close sends nothing
    assert socket.writes == [b"last", b"bye"]

    dropped = RecordingTransport()
    transport = CoalescingTransport(dropped, loop)
    transport.write(b"never")
    transport.abort()
    one_turn(loop)
    assert dropped.writes == [] and dropped.aborted


def test_held_bytes_are_not_written_to_a_closing_transport(loop):
    socket = RecordingTransport()
    transport = CoalescingTransport(socket, loop)
    transport.write(b"late")
    socket.closed = True  # the peer went away; the socket transport is closing
    transport.flush()
    assert socket.writes == []


def test_other_attributes_are_the_wrapped_transports(loop):
    socket = RecordingTransport()
    transport = CoalescingTransport(socket, loop)
    assert transport.wrapped is socket
    assert transport.get_extra_info("peername") == ("127.0.0.1", 50000)
    assert not transport.is_closing()


async def json_app(scope, receive, send):
    """An ASGI app that answers every request with a two-part body."""
    assert scope["type"] == "http"
    await send({"type": "http.response.start", "status": 200, "headers": []})
    await send({"type": "http.response.body", "body": b'{"part": 1,', "more_body": True})
    await send({"type": "http.response.body", "body": b' "part2": 2}'})


def serve_requests(loop, requests: bytes, responses: int) -> RecordingTransport:
    """Feed ``requests`` to a ``HeadDeadlineProtocol`` over a recording transport and run
    the loop until ``responses`` responses are complete."""
    config = Config(app=json_app, http=with_head_timeout(5.0), log_level="warning")
    config.load()
    state = ServerState()
    protocol = config.http_protocol_class(config, state, app_state={}, _loop=loop)
    socket = RecordingTransport()
    protocol.connection_made(socket)
    protocol.data_received(requests)

    async def until_answered():
        for _ in range(1000):
            if state.total_requests >= responses:
                return
            await asyncio.sleep(0)
        raise AssertionError(f"{state.total_requests} of {responses} responses after 1000 turns")

    loop.run_until_complete(until_answered())
    one_turn(loop)
    protocol.connection_lost(None)
    return socket


def test_the_server_protocol_sends_each_response_in_one_write(loop):
    request = b"GET /v1/map HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    socket = serve_requests(loop, request * 3, responses=3)  # keep-alive, pipelined
    assert len(socket.writes) == 3
    for write in socket.writes:
        head, body = write.split(b"\r\n\r\n", 1)
        assert head.startswith(b"HTTP/1.1 200 OK\r\n")
        assert b"transfer-encoding: chunked" in head.lower()
        assert body == b'b\r\n{"part": 1,\r\nc\r\n "part2": 2}\r\n0\r\n\r\n'


def test_an_upgraded_connection_writes_to_the_socket_itself(loop):
    """A WebSocket upgrade hands the socket's own transport to uvicorn's WebSocket
    protocol: its frames are not held for a turn of the loop by the response coalescer."""
    config = Config(app=json_app, http=with_head_timeout(5.0), log_level="warning")
    config.load()
    protocol = config.http_protocol_class(config, ServerState(), app_state={}, _loop=loop)
    socket = RecordingTransport()
    protocol.connection_made(socket)
    assert isinstance(protocol.transport, CoalescingTransport)
    request = (
        b"GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
    )

    async def receive() -> None:  # as the server's loop calls it (the WebSocket protocol
        protocol.data_received(request)  # takes the running loop)

    loop.run_until_complete(receive())
    upgraded = socket.protocol
    assert upgraded is not None and upgraded is not protocol
    assert upgraded.transport is socket
    assert protocol.transport is socket
    upgraded.connection_lost(None)
    one_turn(loop)
