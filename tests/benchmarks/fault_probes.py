"""Fault probes: hostile or unlucky requests against a real map server, one row each.

Run: ``python -m tests.benchmarks.fault_probes [--only a,c,f] [--json]`` (or
``python tests/benchmarks/fault_probes.py``); about four minutes for all.

Each probe starts its own ``fleetmap serve`` (``server_process.LoggedServer``, a fresh
data dir) on a free loopback port, sends its requests, and prints one row: the probe,
what happened (statuses as ``{status: count}``; ``timeout`` or a connection error's
name where no reply came) and a verdict: ``survives`` or ``damaged`` (``error``: the
probe itself failed, a bug here). Every reply is recorded, whatever it is, so the rows
read the same against the current server and a hardened one; each probe has a time
limit (it counts as ``damaged``: the server hung). Probes:

- a poison: 30 good scans and one with ``pose_std.xy = 1e200``, concurrently; then
  SIGTERM and a restart on the same data dir. Damaged: a good scan refused, journal and
  acknowledgements differ, or no restart.
- b clock: u1..u3 mark a wall (stamps 0..10 s), u4 posts stamp 300 s, then 1e15;
  u1's wall cells queried after each and after a restart. Damaged: they are no longer
  occupied.
- c identity: tokens ``unitA`` (units [u1]), ``unitB`` (units [u7]), ``adm``; without
  ``units`` if the server refuses that key. unitA posts as u7 with stamp 1e308, then
  unitB as u7 with stamp 1.0. Damaged: the first is accepted or the second refused.
- d cross-site (open server): a scan as ``text/plain``, with ``Origin:
  http://evil.example``, with ``Host: evil.example``. Damaged: any of them fused.
- e readers: a writer at 10 Hz for 15 s alone, then beside a reader of 100k-point
  ``/v1/query/cells``, then beside 50 ``/v1/plan`` (dijkstra, corner to corner) clients,
  ``/healthz`` polled every 0.5 s (429 counts as shedding). Damaged: the writer got under
  80% of its lone posts, or a health check failed or took over 1 s.
- f limits: f.body 100 MB bodies to ``/v1/plan`` and ``/v1/query/cells`` (JSON with a
  100 MB string field; damaged: accepted or RSS up by more than 50 MiB); f.methods 1,000
  made-up HTTP methods, then ``/metrics`` size (damaged: over 100 lines more); f.idle
  1,050 idle connections to a server limited to 1,024 descriptors, then ``/healthz``
  within 5 s (damaged: no reply); f.slow 50 clients sending a header byte per second
  for 30 s: log growth and SIGTERM time (damaged: health check failed, exit over 10 s).
- g nested: 30 innocent scans and one with an extra field nested 1,000 deep,
  concurrently. Damaged: an innocent scan refused.
- h edges: h.bigint stamp 10**400, h.deep a body nested 1,000 deep, h.true stamp
  ``true`` (damaged: 200 or 5xx); h.repeat one scan posted 3 times (damaged: fused more
  than once); h.lock ``server.lock`` deleted, a second server on the same data dir
  (damaged: it starts).

``--json`` prints the rows as one JSON list on the last line. Measures only.
"""

from __future__ import annotations

import sys
from pathlib import Path

# Run as a script, this file's folder comes first on sys.path and would shadow the
# ``fleet`` package (tests/benchmarks/fleet.py): this checkout's root instead.
HERE = Path(__file__).resolve().parent
sys.path[:] = [str(HERE.parents[1])] + [p for p in sys.path if Path(p or ".").resolve() != HERE]

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import socket  # noqa: E402
import tempfile  # noqa: E402
import textwrap  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from typing import Any  # noqa: E402

import httpx  # noqa: E402
import numpy as np  # noqa: E402

from mapserver.service.map_service import LOCK_FILE  # noqa: E402
from tests.benchmarks.server_process import LoggedServer  # noqa: E402
from tests.server_helpers import scan_body  # noqa: E402

SMALL_GRID = {"grid": {"width": 300, "height": 200, "resolution": 0.1}}  # 30 m x 20 m
TIMEOUT = 10.0  # [s] per request unless a probe says otherwise


# ---------------------------------------------------------------------------- requests
@dataclass
class Reply:
    """A request's outcome: ``status`` (None: no reply), ``error`` ("timeout" or the
    transport error's name), the JSON ``data`` if any, ``seconds`` it took."""

    status: int | None
    error: str | None = None
    data: Any = None
    seconds: float = 0.0
    headers: dict[str, str] = field(default_factory=dict)

    @property
    def code(self) -> str:
        return str(self.status) if self.status is not None else str(self.error)

    def get(self, key: str) -> Any:
        return self.data.get(key) if isinstance(self.data, dict) else None


MAX_DECODED_BYTES = 65536  # replies larger than this are timed and counted, not decoded


def call(client: httpx.Client, method: str, path: str, **kwargs: Any) -> Reply:
    """One request; never raises for what the server does (no reply is an ``error``)."""
    t0 = time.perf_counter()
    try:
        r = client.request(method, path, **kwargs)
    except httpx.TimeoutException:
        return Reply(None, "timeout", seconds=time.perf_counter() - t0)
    except httpx.HTTPError as exc:
        return Reply(None, type(exc).__name__, seconds=time.perf_counter() - t0)
    seconds = time.perf_counter() - t0
    try:  # a 100k-cell reply is 10 MB: decoding it here would take this process's GIL
        data = r.json() if len(r.content) <= MAX_DECODED_BYTES else None  # from the writer
    except ValueError:
        data = None
    return Reply(r.status_code, None, data, seconds, dict(r.headers))


def client(url: str, timeout: float = TIMEOUT) -> httpx.Client:
    return httpx.Client(base_url=url, timeout=timeout)


def post_json(url: str, path: str, body: Any, **kwargs: Any) -> Reply:
    """POST ``body`` (bytes as they are, else JSON) as application/json unless the
    caller's headers say otherwise."""
    content = body if isinstance(body, bytes) else json.dumps(body).encode()
    headers = {"Content-Type": "application/json", **kwargs.pop("headers", {})}
    with client(url, kwargs.pop("timeout", TIMEOUT)) as http:
        return call(http, "POST", path, content=content, headers=headers, **kwargs)


def concurrently(url: str, path: str, bodies: list[Any], headers: dict | None = None) -> list:
    """POST each body on its own connection, all released at once; replies in order."""
    clients = [client(url) for _ in bodies]
    gate = threading.Barrier(len(bodies))
    replies: list[Reply | None] = [None] * len(bodies)

    def send(i: int) -> None:
        content = bodies[i] if isinstance(bodies[i], bytes) else json.dumps(bodies[i]).encode()
        gate.wait()
        replies[i] = call(
            clients[i],
            "POST",
            path,
            content=content,
            headers={"Content-Type": "application/json", **(headers or {})},
        )

    threads = [threading.Thread(target=send, args=(i,), daemon=True) for i in range(len(bodies))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(TIMEOUT + 5)
    for c in clients:
        c.close()
    return [r or Reply(None, "no reply") for r in replies]


def statuses(replies: list[Reply]) -> dict[str, int]:
    return dict(sorted(Counter(r.code for r in replies).items()))


def health(url: str, timeout: float = TIMEOUT) -> Reply:
    with client(url, timeout) as http:
        return call(http, "GET", "/healthz")


def version(url: str) -> Any:
    """The map version from ``/healthz`` (None when it does not answer)."""
    return health(url).get("version")


def nested(depth: int) -> bytes:
    return b"[" * depth + b"]" * depth


def scan_bytes(extra: bytes = b"", **fields: Any) -> bytes:
    """``scan_body(**fields)`` as JSON, with raw ``extra`` members (``b'"k":v'``) added."""
    raw = json.dumps(scan_body(**fields)).encode()
    return raw[:-1] + b"," + extra + b"}" if extra else raw


def wall_scan(unit: str, stamp: float, y: float) -> dict:
    """A unit at (5, y) facing +x seeing a wall at x = 10.05 m (cell column 100)."""
    angles = -0.5 + 0.01 * np.arange(101)
    ranges = (5.05 / np.cos(angles)).tolist()
    return scan_body(stamp, unit, 5.0, y, angle_min=-0.5, ranges=ranges)


# ---------------------------------------------------------------------------- probes
@dataclass
class Row:
    probe: str
    what: str
    verdict: str
    figures: dict = field(default_factory=dict)


class Context:
    """A probe's folder and the servers it starts (killed if the probe overruns)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.servers: list[LoggedServer] = []

    def start(self, name: str, settings: dict | None = SMALL_GRID, **kwargs: Any) -> LoggedServer:
        server = LoggedServer(self.folder / name, settings, **kwargs)
        self.servers.append(server)
        return server

    def cleanup(self) -> None:
        for server in self.servers:
            if server.alive():
                server.kill()
            server.proc.stderr.close()


def last_error(server: LoggedServer) -> str:
    """The last ``SomethingError: ...`` line of the server's log ("" if none)."""
    lines = [ln for ln in server.log_text().splitlines() if "Error" in ln.split(":")[0]]
    return lines[-1][:80] if lines else ""


def verdict(damaged: bool) -> str:
    return "damaged" if damaged else "survives"


def probe_poison(ctx: Context) -> Row:
    server = ctx.start("a")
    good = [scan_body(1.0, f"g{i}", 2.0 + 0.8 * i, 10.0) for i in range(30)]
    poison = scan_body(1.0, "p1", 15.0, 15.0, pose_std={"xy": 1e200, "yaw": 0.0})
    replies = concurrently(server.url, "/v1/scans", [*good, poison])
    acked = sum(r.status == 200 for r in replies)
    journaled = server.journal_count()
    before = version(server.url)
    exit_s, code = server.timed_stop()
    try:
        again = ctx.start("a")
        restarted, after = True, version(again.url)
        again.stop()
    except RuntimeError as exc:
        restarted, after = False, str(exc).splitlines()[-1][:80]
    good_codes = statuses(replies[:30])
    f = {
        "good": good_codes,
        "poison": replies[30].code,
        "acknowledged": acked,
        "journaled": journaled,
        "sigterm_s": round(exit_s, 2),
        "exit_code": code,
        "restarted": restarted,
        "version_before": before,
        "version_after": after,
    }
    what = (
        f"good {good_codes}, poison {replies[30].code}; journal {journaled} vs acked "
        f"{acked}; SIGTERM exit {code} in {exit_s:.1f} s; restart "
        f"{'ok' if restarted else 'FAILED'}, version {before} -> {after}"
    )
    damaged = good_codes != {"200": 30} or journaled != acked or not restarted
    return Row("a poison", what, verdict(damaged or before != after), f)


def probe_clock(ctx: Context) -> Row:
    server = ctx.start("b")
    walls = statuses(
        [
            post_json(server.url, "/v1/scans", wall_scan(unit, float(stamp), y))
            for stamp in range(11)
            for unit, y in (("u1", 10.0), ("u2", 12.0), ("u3", 8.0))
        ]
    )
    points = [[10.05, 10.0 + 0.5 * k] for k in range(-5, 6)]  # u1's wall: y 7.5 .. 12.5
    seen = {"before": {"post": walls, **cell_states(server.url, points)}}
    for stamp in (300.0, 1e15):  # u4, far from the wall, with a clock ahead
        far = post_json(server.url, "/v1/scans", scan_body(stamp, "u4", 25.0, 15.0))
        seen[f"u4@{stamp:g}"] = {"post": far.code, **cell_states(server.url, points)}
    server.stop()
    seen["restart"] = cells_after_restart(ctx, "b", points)
    occupied = [s.get("states", {}).get("occupied", 0) for s in seen.values()]
    what = "; ".join(
        f"{k}: {v.get('post', '')}{' ' if 'post' in v else ''}{v.get('states')} "
        f"p_occ {v.get('mean_p_occ')}"
        for k, v in seen.items()
    )
    return Row("b clock", what, verdict(min(occupied) < occupied[0] or occupied[0] == 0), seen)


def cells_after_restart(ctx: Context, name: str, points: list) -> dict:
    try:
        server = ctx.start(name)
    except RuntimeError as exc:
        return {"states": {"restart failed": str(exc)[-80:]}}
    states = cell_states(server.url, points)
    server.stop()
    return states


def cell_states(url: str, points: list) -> dict:
    """``/v1/query/cells`` at ``points``: status, count of each state, mean p_occ."""
    reply = post_json(url, "/v1/query/cells", {"points": points})
    got = [c for c in reply.get("cells") or [] if isinstance(c, dict)]
    p = [c["p_occ"] for c in got if c.get("p_occ") is not None]
    return {
        "status": reply.code,
        "states": dict(Counter(c.get("state") for c in got)),
        "mean_p_occ": round(float(np.mean(p)), 3) if p else None,
    }


def probe_identity(ctx: Context) -> Row:
    scoped = [
        {"token": "unitA", "role": "unit", "units": ["u1"]},
        {"token": "unitB", "role": "unit", "units": ["u7"]},
        {"token": "adm", "role": "admin"},
    ]
    try:
        server, mode = ctx.start("c", {**SMALL_GRID, "tokens": scoped}), "units key taken"
    except RuntimeError:
        plain = [{k: v for k, v in t.items() if k != "units"} for t in scoped]
        server, mode = ctx.start("c2", {**SMALL_GRID, "tokens": plain}), "units key refused"
    forged = post_json(
        server.url, "/v1/scans", scan_body(1e308, "u7"), headers={"Authorization": "Bearer unitA"}
    )
    real = post_json(
        server.url, "/v1/scans", scan_body(1.0, "u7"), headers={"Authorization": "Bearer unitB"}
    )
    with client(server.url) as http:
        meta = call(http, "GET", "/v1/map/meta", headers={"Authorization": "Bearer adm"})
    server.stop()
    f = {
        "config": mode,
        "unitA_as_u7_1e308": forged.code,
        "unitB_as_u7_1.0": real.code,
        "map_stamp": meta.get("stamp"),
        "detail_real": str(real.get("detail"))[:100],
    }
    what = (
        f"server {mode}; unitA as u7 stamp 1e308: {forged.code}; unitB as u7 stamp 1.0: "
        f"{real.code}; map stamp now {meta.get('stamp')}"
    )
    return Row("c identity", what, verdict(forged.status == 200 or real.status != 200), f)


def probe_cross_site(ctx: Context) -> Row:
    server = ctx.start("d")
    tries = {
        "text/plain": {"Content-Type": "text/plain"},
        "Origin evil": {"Origin": "http://evil.example"},
        "Host evil": {"Host": "evil.example"},
    }
    f, fused = {}, False
    for k, (name, headers) in enumerate(tries.items()):
        v0 = version(server.url)
        reply = post_json(server.url, "/v1/scans", scan_body(1.0, f"x{k}"), headers=headers)
        v1 = version(server.url)
        allow = reply.headers.get("access-control-allow-origin")
        f[name] = {"status": reply.code, "fused": v1 != v0, "version": [v0, v1], "acao": allow}
        fused |= v1 != v0
    server.stop()
    what = "; ".join(
        f"{k}: {v['status']} {'fused' if v['fused'] else 'not fused'}"
        + (f" ACAO {v['acao']}" if v["acao"] else "")
        for k, v in f.items()
    )
    return Row("d cross-site", what, verdict(fused), f)


class Loop(threading.Thread):
    """Calls ``fn(http)`` until stopped, ``every`` [s] apart at the most; keeps replies."""

    def __init__(self, url: str, fn: Callable, every: float = 0.0, timeout: float = 30.0):
        super().__init__(daemon=True)
        self.url, self.fn, self.every, self.timeout = url, fn, every, timeout
        self.replies: list[Reply] = []
        self.halt = threading.Event()

    def run(self) -> None:
        with client(self.url, self.timeout) as http:
            while not self.halt.is_set():
                t0 = time.monotonic()
                self.replies.append(self.fn(http))
                self.halt.wait(max(0.0, self.every - (time.monotonic() - t0)))


def probe_readers(ctx: Context) -> Row:
    server = ctx.start("e", None)  # the default 100 m x 50 m grid at 0.05 m
    xs, ys = np.meshgrid(np.linspace(0.1, 99.9, 400), np.linspace(0.1, 49.9, 250))
    points = np.round(np.column_stack([xs.ravel(), ys.ravel()]), 2).tolist()  # 100k
    cells_body = json.dumps({"points": points}).encode()
    plan_body = {"start": [0.1, 0.1], "goal": [99.9, 49.9], "algorithm": "dijkstra"}
    stamp = [0.0]

    def write(http: httpx.Client) -> Reply:
        stamp[0] += 0.1
        body = scan_body(round(stamp[0], 3), "w1", 50.0, 25.0)
        return call(http, "POST", "/v1/scans", json=body)

    def phase(loads: list[Loop]) -> dict:
        writer = Loop(server.url, write, every=0.1)
        poll = Loop(server.url, lambda http: call(http, "GET", "/healthz"), 0.5, 5.0)
        for t in (writer, poll, *loads):
            t.start()
        time.sleep(15.0)
        for t in (writer, poll, *loads):
            t.halt.set()
        writer.join(35), poll.join(10)
        for t in loads:
            t.join(2.0 if len(loads) > 1 else 35.0)  # 50 planners: their backlog is not waited
        ok = [r for r in writer.replies if r.status == 200]
        hz = [r.seconds * 1e3 for r in poll.replies if r.status == 200]
        others = [r for t in loads for r in t.replies]
        return {
            "posts_ok": len(ok),
            "writer": statuses(writer.replies),
            "writer_max_ms": round(max((r.seconds for r in writer.replies), default=0) * 1e3),
            "healthz": statuses(poll.replies),
            "healthz_p50_ms": round(float(np.median(hz)), 1) if hz else None,
            "healthz_max_ms": round(max(r.seconds for r in poll.replies) * 1e3, 1),
            "load": statuses(others),
            "shed_429": sum(r.status == 429 for r in others),
        }

    def poster(path: str, content: bytes) -> Callable[[httpx.Client], Reply]:
        headers = {"Content-Type": "application/json"}
        return lambda http: call(http, "POST", path, content=content, headers=headers)

    read_cells = poster("/v1/query/cells", cells_body)
    plan = poster("/v1/plan", json.dumps(plan_body).encode())
    f = {"alone": phase([])}
    f["1 cells reader"] = phase([Loop(server.url, read_cells)])
    f["50 planners"] = phase([Loop(server.url, plan) for _ in range(50)])
    server.stop()
    base = f["alone"]["posts_ok"]
    what = "; ".join(
        f"{k}: writer {v['posts_ok']} ok in 15 s {v['writer']} max {v['writer_max_ms']} ms, "
        f"healthz p50 {v['healthz_p50_ms']} max {v['healthz_max_ms']} ms {v['healthz']}"
        + (f", load {v['load']}" if k != "alone" else "")
        for k, v in f.items()
    )
    damaged = any(
        v["posts_ok"] < 0.8 * base or v["healthz_max_ms"] > 1000 or set(v["healthz"]) != {"200"}
        for v in f.values()
    )
    return Row("e readers", what, verdict(damaged), f)


class RssPeak(threading.Thread):
    """The server's peak RSS [MiB] while it runs (sampled every 50 ms until stopped)."""

    def __init__(self, server: LoggedServer) -> None:
        super().__init__(daemon=True)
        self.server, self.peak, self.halt = server, server.rss_mib() or 0.0, threading.Event()

    def run(self) -> None:
        while not self.halt.wait(0.05):
            self.peak = max(self.peak, self.server.rss_mib() or 0.0)

    def __enter__(self) -> RssPeak:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.halt.set()
        self.join()


def probe_big_body(ctx: Context) -> Row:
    server = ctx.start("f.body")
    pad = b"a" * (100 * 2**20)
    bodies = {
        "/v1/plan": b'{"start":[1,1],"goal":[2,2],"pad":"' + pad + b'"}',
        "/v1/query/cells": b'{"points":[[1,1]],"pad":"' + pad + b'"}',
    }
    f, damaged = {}, False
    for path, body in bodies.items():
        before = server.rss_mib()
        with RssPeak(server) as peak:
            reply = post_json(server.url, path, body, timeout=60.0)
        after = server.rss_mib()
        f[path] = {
            "status": reply.code,
            "rss_before": round(before or 0),
            "rss_peak": round(peak.peak),
            "rss_after": round(after or 0),
            "s": round(reply.seconds, 2),
        }
        damaged |= reply.status == 200 or peak.peak - (before or 0) > 50
    server.stop()
    what = "; ".join(
        f"{k}: {v['status']} in {v['s']} s, RSS {v['rss_before']} -> peak {v['rss_peak']} "
        f"-> {v['rss_after']} MiB"
        for k, v in f.items()
    )
    return Row("f.body", what, verdict(damaged), f)


def metrics_size(url: str) -> tuple[int, int]:
    with client(url) as http:
        r = http.get("/metrics")
    return len(r.content), r.text.count("\n")


def probe_methods(ctx: Context) -> Row:
    server = ctx.start("f.methods")
    size0, lines0 = metrics_size(server.url)
    with client(server.url) as http:
        replies = [call(http, f"X{i:04d}", "/healthz") for i in range(1000)]
    size1, lines1 = metrics_size(server.url)
    log = server.log_bytes()
    server.stop()
    f = {
        "statuses": statuses(replies),
        "metrics_bytes": [size0, size1],
        "metrics_lines": [lines0, lines1],
        "log_bytes": log,
    }
    what = (
        f"1000 made-up methods: {f['statuses']}; /metrics {size0} -> {size1} bytes, "
        f"{lines0} -> {lines1} lines; server log {log} bytes"
    )
    return Row("f.methods", what, verdict(lines1 - lines0 > 100), f)


def probe_idle(ctx: Context) -> Row:
    server = ctx.start("f.idle", nofile=1024)
    log0 = server.log_bytes()
    conns, refused = [], Counter()
    for _ in range(1050):
        try:
            conns.append(socket.create_connection(("127.0.0.1", server.port), timeout=2.0))
        except OSError as exc:
            refused[type(exc).__name__] += 1
    time.sleep(0.5)
    during = health(server.url, timeout=5.0)
    for c in conns:
        c.close()
    time.sleep(1.0)
    after = health(server.url, timeout=5.0)
    log = server.log_bytes() - log0
    exit_s, code = server.timed_stop()
    f = {
        "opened": len(conns),
        "refused": dict(refused),
        "healthz": during.code,
        "healthz_s": round(during.seconds, 2),
        "healthz_after_close": after.code,
        "log_growth_bytes": log,
        "sigterm_s": round(exit_s, 2),
        "exit_code": code,
    }
    what = (
        f"{len(conns)} idle connections open (refused {dict(refused) or 0}); /healthz "
        f"{during.code} in {during.seconds:.1f} s; after closing them {after.code}; log "
        f"+{log} bytes; SIGTERM exit {code} in {exit_s:.1f} s"
    )
    return Row("f.idle", what, verdict(during.status != 200), f)


def probe_slow(ctx: Context) -> Row:
    server = ctx.start("f.slow")
    log0 = server.log_bytes()
    slow = []
    for _ in range(50):
        try:
            s = socket.create_connection(("127.0.0.1", server.port), timeout=2.0)
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
            slow.append(s)
        except OSError:
            pass
    checks, dropped = [], 0
    for _ in range(30):
        t0 = time.monotonic()
        for s in list(slow):
            try:
                s.sendall(b"a")
            except OSError:
                slow.remove(s)
                dropped += 1
        checks.append(health(server.url, timeout=5.0))
        time.sleep(max(0.0, 1.0 - (time.monotonic() - t0)))
    log = server.log_bytes() - log0
    exit_s, code = server.timed_stop()  # the slow clients still connected
    for s in slow:
        s.close()
    worst = max(r.seconds for r in checks)
    f = {
        "slow_open_at_end": len(slow),
        "dropped_by_server": dropped,
        "healthz": statuses(checks),
        "healthz_max_s": round(worst, 2),
        "log_growth_bytes": log,
        "sigterm_s": round(exit_s, 2),
        "exit_code": code,
    }
    what = (
        f"50 slow clients for 30 s ({dropped} dropped by the server); /healthz "
        f"{f['healthz']} max {worst:.2f} s; log +{log} bytes; SIGTERM exit {code} in "
        f"{exit_s:.1f} s"
    )
    damaged = set(f["healthz"]) != {"200"} or exit_s > 10 or code == -9
    return Row("f.slow", what, verdict(damaged), f)


def probe_nested_extra(ctx: Context) -> Row:
    server = ctx.start("g")
    innocent = [scan_body(1.0, f"i{i}", 2.0 + 0.8 * i, 10.0) for i in range(30)]
    hurt = scan_bytes(b'"extra":' + nested(1000), stamp=1.0, unit="bad", x=15.0, y=15.0)
    replies = concurrently(server.url, "/v1/scans", [*innocent, hurt])
    later = post_json(server.url, "/v1/scans", scan_body(2.0, "i0", 2.0, 10.0))
    log = server.log_bytes()
    server.stop()
    refused = [r for r in replies[:30] if r.status != 200]
    detail = str(refused[0].get("detail"))[:70] if refused else ""
    f = {
        "innocent": statuses(replies[:30]),
        "nested": replies[30].code,
        "next_scan": later.code,
        "log_bytes": log,
        "refused_detail": detail,
    }
    what = (
        f"innocent {f['innocent']}{f' ({detail!r})' if detail else ''}; nested "
        f"{replies[30].code}; a scan after them {later.code}; server log {log} bytes"
    )
    return Row("g nested", what, verdict(f["innocent"] != {"200": 30}), f)


def probe_body(name: str, body: bytes) -> Callable[[Context], Row]:
    """A probe posting ``body`` once, then a good scan: damaged by a 200 or a 5xx."""

    def probe(ctx: Context) -> Row:
        server = ctx.start(name)
        reply = post_json(server.url, "/v1/scans", body)
        later = post_json(server.url, "/v1/scans", scan_body(5.0, "u2"))
        server.stop()
        detail = str(reply.get("detail"))[:60] if reply.get("detail") else ""
        logged = last_error(server)
        what = f"{reply.code} {detail!r}; a good scan after it {later.code}".replace(" ''", "")
        what += f"; server log: {logged}" if logged else ""
        bad = reply.status is None or reply.status == 200 or reply.status >= 500
        return Row(
            name,
            what,
            verdict(bad or later.status != 200),
            {"status": reply.code, "detail": detail, "next_scan": later.code, "log": logged},
        )

    return probe


def probe_repeat(ctx: Context) -> Row:
    server = ctx.start("h.repeat")
    replies = [post_json(server.url, "/v1/scans", scan_body(1.0, "u1")) for _ in range(3)]
    server.stop()
    seqs = [r.get("seq") for r in replies]
    fused = len({s for r, s in zip(replies, seqs, strict=True) if r.status == 200})
    what = f"statuses {[r.code for r in replies]}, seqs {seqs}: fused {fused} time(s)"
    return Row(
        "h.repeat", what, verdict(fused > 1), {"statuses": [r.code for r in replies], "seqs": seqs}
    )


def probe_lock(ctx: Context) -> Row:
    first = ctx.start("h.lock")
    lock = first.data_dir / LOCK_FILE
    existed = lock.exists()
    lock.unlink(missing_ok=True)
    try:
        second = ctx.start("h.lock", ready_timeout=30.0)
        a = post_json(first.url, "/v1/scans", scan_body(1.0, "u1"))
        b = post_json(second.url, "/v1/scans", scan_body(1.0, "u1"))
        second.stop()
        started = (
            f"second server STARTED; u1 stamp 1.0 to each: {a.code} seq {a.get('seq')}, "
            f"{b.code} seq {b.get('seq')}"
        )
        damaged = True
    except RuntimeError as exc:
        started = f"second server refused to start ({str(exc).strip().splitlines()[-1][:70]})"
        damaged = False
    first.stop()
    return Row("h.lock", f"lock file existed {existed}, deleted; {started}", verdict(damaged))


PROBES: list[tuple[str, Callable[[Context], Row], float]] = [
    ("a", probe_poison, 90.0),
    ("b", probe_clock, 90.0),
    ("c", probe_identity, 60.0),
    ("d", probe_cross_site, 60.0),
    ("e", probe_readers, 150.0),
    ("f.body", probe_big_body, 120.0),
    ("f.methods", probe_methods, 60.0),
    ("f.idle", probe_idle, 60.0),
    ("f.slow", probe_slow, 80.0),
    ("g", probe_nested_extra, 60.0),
    (
        "h.bigint",
        probe_body(
            "h.bigint", scan_bytes(stamp=1.0).replace(b'"stamp": 1.0', b'"stamp": 1' + b"0" * 400)
        ),
        30.0,
    ),
    ("h.deep", probe_body("h.deep", nested(1000)), 30.0),
    ("h.true", probe_body("h.true", scan_bytes(stamp=True)), 30.0),
    ("h.repeat", probe_repeat, 30.0),
    ("h.lock", probe_lock, 60.0),
]


def run_probe(fn: Callable[[Context], Row], limit: float, folder: Path, name: str) -> Row:
    """``fn`` in a thread with ``limit`` [s]; an overrun or an exception is a row too."""
    ctx = Context(folder)
    out: list[Row] = []
    failure: list[str] = []

    def target() -> None:
        try:
            out.append(fn(ctx))
        except Exception as exc:  # the probe's own failure, reported as a row
            failure.append(f"{type(exc).__name__}: {exc}"[:200])

    t0 = time.monotonic()
    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(limit)
    ctx.cleanup()
    if thread.is_alive():
        return Row(name, f"timed out after {limit:.0f} s (the probe was still waiting)", "damaged")
    if failure:
        return Row(name, f"probe failed: {failure[0]}", "error")
    out[0].figures["probe_s"] = round(time.monotonic() - t0, 1)
    return out[0]


def print_table(rows: list[Row]) -> None:
    width = max(len(r.probe) for r in rows)
    print(f"{'probe':{width}s}  {'verdict':8s}  what happened")
    for r in rows:
        lines = textwrap.wrap(r.what, 100 - width - 12) or [""]
        print(f"{r.probe:{width}s}  {r.verdict:8s}  {lines[0]}")
        for line in lines[1:]:
            print(f"{'':{width}s}  {'':8s}  {line}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="comma-separated probe letters, e.g. a,c,f")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON last")
    args = parser.parse_args()
    wanted = set(args.only.split(",")) if args.only else None
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, 4096)), hard))
    rows = []
    with tempfile.TemporaryDirectory(prefix="fault-probes-") as tmp:
        for name, fn, limit in PROBES:
            if wanted is None or name.split(".")[0] in wanted:
                rows.append(run_probe(fn, limit, Path(tmp) / name, name))
                print(f"[{rows[-1].probe}: {rows[-1].verdict}]", file=sys.stderr, flush=True)
    print_table(rows)
    if args.json:
        print(json.dumps([r.__dict__ for r in rows]))


if __name__ == "__main__":
    main()
