"""Ingest benchmark: concurrent units posting 1080-beam scans to a real map server.

Run: ``python tests/benchmarks/ingest.py [--units 100] [--seconds 10] [--batch 1] [--json]``

Starts ``fleetmap serve`` (uvicorn, default settings: 100 m x 50 m at 0.05 m, ``decay``,
journal ``synchronous=FULL``) on 127.0.0.1 in a subprocess, and in the same run a bare
Starlette app under uvicorn whose one route only parses the same JSON (the ceiling: HTTP
plus JSON, no map). ``--units`` concurrent clients (asyncio + httpx, one connection
each, pre-encoded bodies of 200 warehouse scans from ``fleet.boxworld`` replayed with
increasing stamps) post scans as fast as the server acknowledges them for
``--seconds``; with ``--batch N`` each request carries N scans (``/v1/scans/batch``, as
the simulator posts one batch per tick). Printed for each: scans/s, p50 and p99 request
latency [ms]. The load generator runs on the same 2 cores as the servers. Then the time
to GET the raw costmap of a 2000 x 2000 grid (a second server
with that grid), median of 20 [ms]. ``--json`` prints the figures as one JSON object on
the last line. Measures only; tests assert behaviour.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import textwrap
import time

import httpx
import numpy as np

from fleet.boxworld import sample_scans, warehouse_layout
from scenarios.run.embedded_server import free_port

CEILING_APP = textwrap.dedent(
    """
    import json, sys
    import uvicorn
    from starlette.applications import Starlette
    from starlette.responses import JSONResponse
    from starlette.routing import Route

    count = 0

    async def scans(request):
        global count
        json.loads(await request.body())
        count += 1
        return JSONResponse({"seq": count, "map_version": count})

    app = Starlette(routes=[Route("/v1/scans", scans, methods=["POST"]),
                            Route("/v1/scans/batch", scans, methods=["POST"])])
    uvicorn.run(app, host="127.0.0.1", port=int(sys.argv[1]), log_level="warning")
    """
)


def start(cmd: list[str], port: int, env: dict[str, str] | None = None) -> subprocess.Popen:
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return proc
        except OSError:
            if proc.poll() is not None:
                raise RuntimeError(proc.stderr.read().decode()) from None
            time.sleep(0.1)
    proc.kill()
    raise RuntimeError("server did not start")


def serve_cmd(port: int, data_dir: str) -> list[str]:
    return [sys.executable, "-m", "scenarios.cli.main", "serve", "--port", str(port),
            "--data-dir", data_dir]  # fmt: skip


async def load(
    url: str, scans: list[bytes], units: int, batch: int, seconds: float
) -> tuple[list[float], int]:
    """(request latencies [s], scans acknowledged); unit k posts its own stamps in order."""
    latencies: list[float] = []
    acknowledged = 0
    deadline = time.monotonic() + seconds
    headers = {"content-type": "application/json"}
    path = "/v1/scans" if batch == 1 else "/v1/scans/batch"

    async def unit(k: int) -> None:
        nonlocal acknowledged
        async with httpx.AsyncClient(base_url=url, timeout=60) as client:
            tick = 0
            while time.monotonic() < deadline:
                bodies = [body(scans, k, tick + j) for j in range(batch)]
                content = bodies[0] if batch == 1 else b'{"scans":[' + b",".join(bodies) + b"]}"
                t0 = time.perf_counter()
                reply = await client.post(path, content=content, headers=headers)
                reply.raise_for_status()
                latencies.append(time.perf_counter() - t0)
                acknowledged += batch
                tick += batch

    await asyncio.gather(*(unit(k) for k in range(units)))
    return latencies, acknowledged


def body(scans: list[bytes], unit: int, tick: int) -> bytes:
    """Scan ``(unit + tick) % len(scans)`` as unit ``u{unit}`` at stamp tick * 0.1 s."""
    head = f'{{"unit_id":"u{unit}","stamp":{tick * 0.1!r},'.encode()
    return head + scans[(unit * 7 + tick) % len(scans)]


def scan_tails(count: int) -> list[bytes]:
    """JSON of ``count`` 1080-beam warehouse scans without the leading unit and stamp."""
    warehouse = warehouse_layout(seed=0)
    tails = []
    for scan in sample_scans(warehouse, count, beams=1080, seed=0, units=8):
        data = scan.to_dict()
        no_return = 2 * scan.range_max + 1  # strict JSON, as MapClient sends it
        data["ranges"] = [no_return if r == float("inf") else r for r in data["ranges"]]
        del data["unit_id"], data["stamp"]
        tails.append(json.dumps(data).encode()[1:])  # drop "{": body() supplies it
    return tails


def figures(latencies: list[float], count: int, seconds: float) -> dict[str, float]:
    ms = np.array(latencies) * 1e3
    return {
        "scans_per_s": count / seconds,
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": float(np.percentile(ms, 99)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=100, help="concurrent clients")
    parser.add_argument("--seconds", type=float, default=10.0, help="load duration per server")
    parser.add_argument("--batch", type=int, default=1, help="scans per request")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    scans = scan_tails(200)
    results: dict[str, object] = {"units": args.units, "batch": args.batch}
    with tempfile.TemporaryDirectory() as tmp:
        for name, cmd_of in (
            ("fleetmap", lambda p: serve_cmd(p, os.path.join(tmp, "data"))),
            ("ceiling", lambda p: [sys.executable, "-c", CEILING_APP, str(p)]),
        ):
            port = free_port()
            proc = start(cmd_of(port), port)
            try:
                latencies, count = asyncio.run(
                    load(f"http://127.0.0.1:{port}", scans, args.units, args.batch, args.seconds)
                )
            finally:
                proc.terminate()
                proc.wait(timeout=30)
            results[name] = figures(latencies, count, args.seconds)
            f = results[name]
            print(f"{name:9s} {f['scans_per_s']:8.0f} scans/s  p50 {f['p50_ms']:6.1f} ms  "
                  f"p99 {f['p99_ms']:6.1f} ms")  # fmt: skip
        port = free_port()
        env = dict(os.environ, FLEETMAP_GRID__WIDTH="2000", FLEETMAP_GRID__HEIGHT="2000")
        proc = start(serve_cmd(port, os.path.join(tmp, "big")), port, env)
        try:
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30) as client:
                times = []
                for _ in range(20):
                    t0 = time.perf_counter()
                    reply = client.get("/v1/costmap", params={"format": "raw"})
                    times.append((time.perf_counter() - t0) * 1e3)
                    assert len(reply.content) == 2000 * 2000
        finally:
            proc.terminate()
            proc.wait(timeout=30)
        results["raw_costmap_2000x2000_ms"] = float(np.median(times))
        print(f"GET /v1/costmap?format=raw, 2000 x 2000: median {np.median(times):.1f} ms")
    if args.json:
        print(json.dumps(results))


if __name__ == "__main__":
    main()
