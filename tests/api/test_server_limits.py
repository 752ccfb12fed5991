"""The edge's bounds on a real ``fleetmap serve`` (uvicorn on 127.0.0.1): huge bodies,
idle and slow connections, the connection cap, SIGTERM with slow clients, log floods."""

import logging
import select
import signal
import socket
import time

import httpx
import pytest
import yaml
from server_helpers import ServerProcess

from mapserver.api.http_protocol import MIN_IDLE_S
from mapserver.service.lograte import RateLimitFilter

LIMITS = {
    "keep_alive_s": 1.0,
    "header_timeout_s": 2.0,
    "body_timeout_s": 60.0,
    "shutdown_timeout_s": 2.0,
    "max_connections": 40,
    "log_burst": 5,
}
WAIT_S = 10.0  # liveness bound for every "eventually closed / exited" below


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    folder = tmp_path_factory.mktemp("limits")
    config = folder / "server.yaml"
    config.write_text(yaml.safe_dump({"server": LIMITS}))
    process = ServerProcess(folder / "data", config)
    yield process
    process.stop()


def connect(server, data=b""):
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S)
    sock.sendall(data)
    return sock


def closed_within(sock, seconds):
    """True if the server closes ``sock`` within ``seconds`` (whatever it sent first)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        ready, _, _ = select.select([sock], [], [], deadline - time.monotonic())
        if ready:
            try:
                if sock.recv(65536) == b"":
                    return True
            except OSError:
                return True
    return False


def rss_kib(pid):
    with open(f"/proc/{pid}/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmRSS"))


def reply_of(sock) -> bytes:
    """Everything the server sends on ``sock`` until it closes it."""
    parts = []
    while part := sock.recv(65536):
        parts.append(part)
    return b"".join(parts)


def status_of(reply: bytes) -> int:
    return int(reply.split(b" ", 2)[1])


def test_a_100_mb_body_to_plan_is_a_413_without_reading_it(server):
    rss = rss_kib(server.proc.pid)
    head = b"POST /v1/plan HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
    declared = connect(server, head + b"Content-Length: 100000000\r\n\r\n{")
    reply = reply_of(declared)
    assert status_of(reply) == 413 and b"at most 2097152 bytes" in reply
    streamed = connect(server, head + b"Transfer-Encoding: chunked\r\n\r\n")
    chunk = b"100000\r\n" + b"x" * 0x100000 + b"\r\n"  # 1 MiB chunks, up to 100 MB
    for _ in range(100):
        if select.select([streamed], [], [], 0)[0]:
            break
        try:
            streamed.sendall(chunk)
        except OSError:
            break
    assert status_of(streamed.recv(4096)) == 413
    assert rss_kib(server.proc.pid) - rss < 30_000  # [KiB] far below the 100 MB sent


def test_idle_connections_are_closed_after_the_keep_alive_timeout(server):
    kept = connect(server, b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    assert status_of(kept.recv(4096)) == 200
    assert closed_within(kept, WAIT_S)


def test_a_silent_or_trickling_client_is_closed_after_the_header_timeout(server):
    silent = connect(server)
    trickling = connect(server, b"GET /healthz HTTP/1.1\r\n")
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:  # a byte every 0.2 s: uvicorn's own timer resets
        try:
            trickling.sendall(b"X")
        except OSError:
            break
        if select.select([trickling], [], [], 0.2)[0] and trickling.recv(4096) == b"":
            break
    assert closed_within(silent, 0.5) and time.monotonic() < deadline
    assert httpx.get(server.url + "/healthz", timeout=5).status_code == 200


def test_past_max_connections_the_longest_idle_connection_makes_room(server):
    idle = [connect(server) for _ in range(LIMITS["max_connections"] + 10)]
    try:  # 1,050 such connections under 1,024 descriptors once kept /healthz out
        time.sleep(2 * MIN_IDLE_S)  # younger ones may have a request head on its way
        probe = connect(server, b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert status_of(probe.recv(4096)) == 200
        assert closed_within(idle[0], WAIT_S)  # the oldest idle ones were closed
        assert not closed_within(idle[-1], 0.2)  # the newest still open
    finally:
        for sock in idle:
            sock.close()


def test_past_max_connections_all_busy_a_request_is_answered_503(server):
    head = b"POST /v1/plan HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
    busy = []
    for _ in range(LIMITS["max_connections"] - 1):  # with the probe: max_connections
        busy.append(connect(server, head + b"Content-Length: 100\r\n\r\n{"))  # body due
        time.sleep(0.01)  # each head taken before the next connection counts
    try:
        time.sleep(2 * MIN_IDLE_S)
        probe = connect(server, b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert status_of(probe.recv(4096)) == 503
    finally:
        for sock in busy:
            sock.close()


def test_a_log_flood_is_cut_to_a_burst_and_summed_up(tmp_path):
    config = tmp_path / "server.yaml"
    config.write_text(yaml.safe_dump({"server": {**LIMITS, "log_interval_s": 3.0}}))
    server = ServerProcess(tmp_path / "data", config)
    try:
        for _ in range(300):  # well within one 3 s interval
            connect(server, b"\x00garbage\r\n\r\n").recv(4096)
        time.sleep(3.2)
        connect(server, b"\x00garbage\r\n\r\n").recv(4096)
    finally:
        server.stop()
    log = server.proc.stderr.read()
    assert log.count("Invalid HTTP request received.") == 5 + 1 + 1  # burst, summary, next
    assert "suppressed 295 similar messages in the last " in log


def test_sigterm_with_slow_clients_exits_within_the_shutdown_bound(tmp_path):
    config = tmp_path / "server.yaml"
    config.write_text(yaml.safe_dump({"server": LIMITS}))
    server = ServerProcess(tmp_path / "data", config)
    head = b"POST /v1/scans HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
    slow = [connect(server, head + b"Content-Length: 100000\r\n\r\n{") for _ in range(10)]
    slow += [connect(server, b"GET /healthz HTTP/1.1\r\nX-Slow: ") for _ in range(10)]
    time.sleep(0.3)
    server.proc.terminate()
    deadline = time.monotonic() + LIMITS["shutdown_timeout_s"] + WAIT_S
    while server.proc.poll() is None and time.monotonic() < deadline:
        for sock in slow:
            try:
                sock.send(b"a")
            except OSError:
                pass
        time.sleep(0.2)
    exited = server.proc.poll() is not None
    server.stop()
    # uvicorn re-raises SIGTERM once shut down (lifespan and journal closed)
    assert exited and server.proc.returncode == -signal.SIGTERM
    assert "Traceback" not in server.proc.stderr.read()


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_the_filter_passes_a_burst_per_template_and_then_one_summary(caplog):
    clock = Clock()
    logger = logging.getLogger("fleetmap.test.lograte")
    rate = RateLimitFilter(burst=3, interval_s=10.0, clock=clock)
    caplog.handler.addFilter(rate)
    try:
        with caplog.at_level(logging.WARNING, logger=logger.name):
            for i in range(50):
                logger.warning("bad request from %s", f"client {i}")
                logger.warning("other %d", i)
            clock.now = 10.0
            logger.warning("bad request from %s", "client 50")
    finally:
        caplog.handler.removeFilter(rate)
    lines = [record.getMessage() for record in caplog.records]
    assert lines[:6] == [
        "bad request from client 0",
        "other 0",
        "bad request from client 1",
        "other 1",
        "bad request from client 2",
        "other 2",
    ]
    assert lines[6:] == [
        "suppressed 47 similar messages in the last 10 s: bad request from %s",
        "bad request from client 50",
    ]
