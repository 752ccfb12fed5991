"""Fleet load: many units posting 360-beam scans at 10 Hz to a real map server, closed loop.

Run: ``python -m tests.benchmarks.fleet_load [--units 100] [--rate 10] [--seconds 60]
[--beams 1080] [--encoding binary|json] [--batch-endpoint] [--timeout 10]
[--ceiling-seconds 15] [--json]`` (or ``python tests/benchmarks/fleet_load.py``)

Starts ``fleetmap serve`` (default settings: 100 m x 50 m at 0.05 m, ``decay``, journal
``synchronous=FULL``) on a free loopback port in a subprocess. Each of ``--units``
simulated units (no PyBullet) sits in a 10 m x 5 m lattice cell of the grid, in a
rectangular bay with a doorway, and moves slowly (at most 0.16 m/s) about its spot; its
scans are synthetic (``--beams`` beams over a full turn, 1,080 by default, range_max
20 m; the distance to the bay's walls, no return through the doorway), with its own
stamp clock (0, 0.1, 0.2 ... s, one step per scan) and encoded as ``MapClient`` sends a
``Scan``: ``--encoding binary`` (the default, docs/scan-binary.md) or ``json`` (orjson,
no-return as ``2 * range_max + 1``, ``Content-Type: application/json``).
A unit posts each scan as ``POST /v1/scans`` (``--batch-endpoint``: a one-scan
``POST /v1/scans/batch``, the endpoint the simulator's ``ScanPoster`` uses for a tick) over
its own keep-alive connection (a thread per unit with ``http.client``: a sixth of the CPU
httpx.AsyncClient takes per request, so the generator leaves the 2 cores to the server),
waits for the reply, then sleeps until its next slot (1 / ``--rate`` s; units are
staggered over the first slot). A unit still waiting when its next slot starts posts at
once when the reply comes and counts the slots that passed as missed: offered = units x
rate x seconds slots, of which some were posted and fewer, on a slow server, acknowledged.

Printed: scans offered, posted, acknowledged, missed slots; offered and acknowledged
scans/s; errors by kind (HTTP status other than 200, connection errors, timeouts);
request latency p50/p99/max [ms]; the server's RSS [MiB] every 5 s and its slope over
the second half of the run [MiB/min, Theil-Sen] (flat memory: near 0); journal growth
[bytes] and scans journaled vs acknowledged; the server's mean time per ingest stage
(``fleetmap_ingest_stage_seconds`` on ``/metrics``: queued, journal, fuse_wait, fuse,
answered) and mean group size; the CPU share of a core used by this load generator
and by the server (the machine has 2 shared cores: the generator must not be the
bottleneck).

The ceiling, in the same run (``--ceiling-seconds``, 0 to skip): the same units post the
same bodies flat out (no slots: the next post as soon as a reply comes) for that long,
first to a bare Starlette app under uvicorn whose one route only decodes the body (orjson
for JSON, ``decode_scans`` for binary) and answers an ack, then to the map server (a
fresh one): both scans/s, and the server's share of the ceiling.
``--json`` prints the figures as one JSON object on the last line. Measures only; tests
assert behaviour.
"""

from __future__ import annotations

import sys
from pathlib import Path

# Run as a script, this file's folder comes first on sys.path and would shadow the
# ``fleet`` package (tests/benchmarks/fleet.py): this checkout's root instead.
HERE = Path(__file__).resolve().parent
sys.path[:] = [str(HERE.parents[1])] + [p for p in sys.path if Path(p or ".").resolve() != HERE]

import argparse  # noqa: E402
import http.client  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import resource  # noqa: E402
import socket  # noqa: E402
import struct  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from typing import Any  # noqa: E402

import httpx  # noqa: E402
import numpy as np  # noqa: E402
import orjson  # noqa: E402
from prometheus_client.parser import text_string_to_metric_families  # noqa: E402

from fleet.boxworld import beam_angles  # noqa: E402
from mapserver.core.scan import Pose2D, Scan  # noqa: E402
from mapserver.core.scan_binary import CONTENT_TYPE, encode_batch, encode_scan  # noqa: E402
from scenarios.run.embedded_server import free_port  # noqa: E402
from tests.benchmarks.server_process import LoggedServer  # noqa: E402

RANGE_MIN, RANGE_MAX = 0.05, 20.0  # [m], fleet.lidar.LidarConfig's defaults
CELL_X, CELL_Y = 10.0, 5.0  # [m] lattice spacing of the units on the 100 m x 50 m grid
BAY_X, BAY_Y = 4.0, 2.0  # [m] half sizes of a unit's bay
SWAY_X, SWAY_Y, SWAY_PERIOD = 1.5, 0.5, 60.0  # [m], [m], [s]: the slow motion
DOOR = (0.22, 0.28)  # [fraction of the turn] beams through the doorway: no return
RESOLUTION = 0.05  # [m/cell], the server's default
RSS_EVERY = 5.0  # [s]
HEADERS = {"json": {"Content-Type": "application/json"}, "binary": {"Content-Type": CONTENT_TYPE}}
CEILING_APP = """
import sys, orjson, uvicorn
from starlette.applications import Starlette
from starlette.responses import Response
from starlette.routing import Route
from mapserver.core.scan_binary import CONTENT_TYPE, decode_scans
count = 0
async def scans(request):
    global count
    body = await request.body()
    batch = request.url.path.endswith("/batch")
    if request.headers.get("content-type") == CONTENT_TYPE:
        n = len(decode_scans(body, batch))
    else:
        parsed = orjson.loads(body)
        n = len(parsed["scans"]) if batch else 1
    acks = [{"seq": count + i + 1, "map_version": count + n} for i in range(n)]
    count += n
    return Response(orjson.dumps({"acks": acks} if batch else acks[0]),
                    media_type="application/json")
app = Starlette(routes=[Route("/v1/scans", scans, methods=["POST"]),
                        Route("/v1/scans/batch", scans, methods=["POST"])])
uvicorn.run(app, host="127.0.0.1", port=int(sys.argv[1]), log_level="warning")
"""


class SyntheticUnit:
    """Unit ``k``: its bay, its pose at a stamp and its scan bodies (``encoding``: "json"
    or "binary" bytes, as ``MapClient`` sends a ``Scan``)."""

    def __init__(self, k: int, columns: int, beams: int = 1080, encoding: str = "binary") -> None:
        self.unit_id = f"u{k}"
        self.cx = CELL_X * (k % columns + 0.5)
        self.cy = CELL_Y * (k // columns + 0.5)
        self.phase = 2 * math.pi * k / 17.0
        self.angle_min, self.angle_increment = beam_angles(beams, 2 * math.pi)  # a full turn
        self.angles = self.angle_min + self.angle_increment * np.arange(beams)
        self.door = slice(round(DOOR[0] * beams), round(DOOR[1] * beams))
        self.encoding = encoding

    def pose(self, stamp: float) -> tuple[float, float, float]:
        w = 2 * math.pi * stamp / SWAY_PERIOD + self.phase
        return (self.cx + SWAY_X * math.sin(w), self.cy + SWAY_Y * math.sin(2 * w),
                0.3 * math.sin(w))  # fmt: skip

    def ranges(self, x: float, y: float, yaw: float) -> np.ndarray:
        """[m] distance from (x, y) to the bay's walls along each beam; doorway beams and
        any beyond range_max read ``2 * range_max + 1`` (no return, as MapClient sends)."""
        a = yaw + self.angles
        dx, dy = np.cos(a), np.sin(a)
        with np.errstate(divide="ignore"):
            tx = np.where(dx > 0, self.cx + BAY_X - x, self.cx - BAY_X - x) / dx
            ty = np.where(dy > 0, self.cy + BAY_Y - y, self.cy - BAY_Y - y) / dy
        r = np.minimum(np.abs(tx), np.abs(ty))
        no_return = 2.0 * RANGE_MAX + 1.0
        r[self.door] = no_return
        r[r > RANGE_MAX] = no_return
        return r

    def body(self, n: int, batch: bool = False) -> bytes:
        """The unit's ``n``-th scan (stamp n * 0.1 s) in the unit's encoding; ``batch``:
        as a one-scan ``/v1/scans/batch`` body."""
        return self.body_at(round(n * 0.1, 6), batch)

    def body_at(self, stamp: float, batch: bool = False) -> bytes:
        """The unit's scan at ``stamp`` [s] (its pose then) in the unit's encoding;
        ``batch``: as a one-scan ``/v1/scans/batch`` body."""
        x, y, yaw = self.pose(stamp)
        ranges = self.ranges(x, y, yaw)
        if self.encoding == "binary":
            scan = Scan(self.unit_id, stamp, Pose2D(x, y, yaw), self.angle_min,
                        self.angle_increment, RANGE_MIN, RANGE_MAX, ranges)  # fmt: skip
            return encode_batch([scan]) if batch else encode_scan(scan)
        scan = {
            "unit_id": self.unit_id,
            "stamp": stamp,
            "frame": "map",
            "pose": {"x": x, "y": y, "yaw": yaw},
            "angle_min": self.angle_min,
            "angle_increment": self.angle_increment,
            "range_min": RANGE_MIN,
            "range_max": RANGE_MAX,
            "ranges": ranges,
        }
        content = orjson.dumps(scan, option=orjson.OPT_SERIALIZE_NUMPY)
        return b'{"scans":[' + content + b"]}" if batch else content


@dataclass
class Tally:
    """What a unit saw: posts, replies by status, transport errors, latencies (the slots
    not posted in are the missed ones: every unit has rate x seconds slots)."""

    posted: int = 0
    acknowledged: int = 0
    statuses: Counter = field(default_factory=Counter)
    transport: Counter = field(default_factory=Counter)  # "timeout" or the error's name
    latencies: list[float] = field(default_factory=list)  # [s] of every reply
    last_reply: float = 0.0  # time.monotonic()

    def add(self, other: Tally) -> None:
        self.posted += other.posted
        self.acknowledged += other.acknowledged
        self.statuses.update(other.statuses)
        self.transport.update(other.transport)
        self.latencies += other.latencies
        self.last_reply = max(self.last_reply, other.last_reply)


def post_once(
    conn: http.client.HTTPConnection, path: str, content: bytes, headers: dict[str, str],
    tally: Tally, method: str = "POST",
) -> bytes | None:  # fmt: skip
    """One request on ``conn``, counted in ``tally`` (posted, status or transport error,
    latency [s], acknowledged if 200); the reply's body, or None when no reply came
    (the connection is then closed: the next request reconnects)."""
    tally.posted += 1
    t0 = time.perf_counter()
    try:
        conn.request(method, path, body=content, headers=headers)
        reply = conn.getresponse()
        data = reply.read()
    except TimeoutError:
        tally.transport["timeout"] += 1
        conn.close()
        data = None
    except (OSError, http.client.HTTPException) as exc:
        tally.transport[type(exc).__name__] += 1
        conn.close()
        data = None
    else:
        tally.latencies.append(time.perf_counter() - t0)
        tally.statuses[reply.status] += 1
        tally.acknowledged += reply.status == 200
    tally.last_reply = time.monotonic()
    return data


def run_unit(
    unit: SyntheticUnit, port: int, path: str, start: float, stop: float, period: float,
    timeout: float, batch: bool, tally: Tally, first_scan: int = 0,
) -> None:  # fmt: skip
    """Closed loop on one keep-alive connection: post, read the reply, sleep to the next
    slot (late: post at once; ``period`` 0: flat out, the next post at once until
    ``stop``). After a transport error the next post reconnects. The unit's scans are
    numbered from ``first_scan`` (a later run on the same server: new stamps)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    headers = HEADERS[unit.encoding]
    slot, n = 0, first_scan
    try:
        while (start + slot * period if period else time.monotonic()) < stop:
            delay = start + slot * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            content = unit.body(n, batch)
            n += 1
            if post_once(conn, path, content, headers, tally) is None:
                time.sleep(period)  # a refused connection would spin otherwise
            if period:
                due = math.floor((time.monotonic() - start) / period)  # the slot running now
                slot = max(slot + 1, due)  # late: post at once; the slots passed are missed
    finally:
        conn.close()


def load(
    port: int, args: argparse.Namespace, seconds: float, flat_out: bool = False,
    rss_of: LoggedServer | None = None, first_scan: int = 0,
) -> tuple[Tally, list, float]:  # fmt: skip
    """Run every unit in its own thread against ``port`` for ``seconds`` (``flat_out``: no
    slots; scans numbered from ``first_scan``) and sample ``rss_of``'s RSS every
    RSS_EVERY s; (the units' tally, [(t [s], RSS [MiB])], wall time [s])."""
    columns = lattice_columns(args.units)
    units = [SyntheticUnit(k, columns, args.beams, args.encoding) for k in range(args.units)]
    for unit in units:
        unit.body(0)  # warm numpy and orjson outside the measured run
    period = 0.0 if flat_out else 1.0 / args.rate
    path = "/v1/scans/batch" if args.batch_endpoint else "/v1/scans"
    tallies = [Tally() for _ in units]
    start = time.monotonic() + 0.5
    stop = start + seconds
    threads = [
        threading.Thread(
            target=run_unit,
            args=(
                unit,
                port,
                path,
                start + period * k / len(units),
                stop,
                period,
                args.timeout,
                args.batch_endpoint,
                tally,
                first_scan,
            ),
            daemon=True,
        )
        for k, (unit, tally) in enumerate(zip(units, tallies, strict=True))
    ]
    for thread in threads:
        thread.start()
    rss = []
    for k in range(int(seconds // RSS_EVERY) + 1):
        time.sleep(max(0.0, start + k * RSS_EVERY - time.monotonic()))
        rss.append((round(time.monotonic() - start, 1), rss_of and rss_of.rss_mib()))
    for thread in threads:
        thread.join()
    total = Tally()
    for tally in tallies:
        total.add(tally)
    return total, rss, max(total.last_reply, stop) - start


def warm_up(url: str, args: argparse.Namespace, scans: int = 3) -> list[float]:
    """Post a few scans of a unit "warmup" before the run (the server compiles its numba
    kernels on the first scan); their latencies [ms]."""
    unit = SyntheticUnit(0, 1, args.beams, args.encoding)
    unit.unit_id = "warmup"
    times = []
    with httpx.Client(base_url=url, timeout=120) as client:
        for n in range(scans):
            t0 = time.perf_counter()
            client.post("/v1/scans", content=unit.body(n), headers=HEADERS[unit.encoding])
            times.append((time.perf_counter() - t0) * 1e3)
    return times


def flat_out_rates(args: argparse.Namespace, tmp: Path) -> dict[str, float]:
    """Scans/s of the units posting flat out to the bare Starlette app, then to a fresh
    map server, ``args.ceiling_seconds`` each."""
    port = free_port()
    ceiling = subprocess.Popen([sys.executable, "-c", CEILING_APP, str(port)],
                               cwd=HERE.parents[1], stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        wait_for_port(port)
        bare, _, bare_wall = load(port, args, args.ceiling_seconds, flat_out=True)
    finally:
        ceiling.terminate()
        ceiling.wait()
    server = LoggedServer(tmp / "flat-out", server_settings(args))
    try:
        warm_up(server.url, args)
        ours, _, our_wall = load(server.port, args, args.ceiling_seconds, flat_out=True)
    finally:
        server.stop()
    bare_rate, our_rate = bare.acknowledged / bare_wall, ours.acknowledged / our_wall
    p99 = float(np.percentile(np.array(ours.latencies) * 1e3, 99)) if ours.latencies else math.nan
    return {"ceiling_per_s": bare_rate, "flat_out_per_s": our_rate,
            "share_of_ceiling": our_rate / bare_rate, "flat_out_p99_ms": p99}  # fmt: skip


class GreedyClient:
    """One client posting ``--greedy-beams``-beam scans flat out on
    ``--greedy-connections`` keep-alive connections, as ``--greedy-units`` unit ids in
    turn (``greedy-0`` ...), ignoring ``Retry-After`` (``--greedy-honours-retry-after``:
    it waits as told). Its stamps follow the normal units' clock (``stamp0`` + the time
    since ``clock0`` [s], unique), so the clock rule does not refuse them; each body is
    encoded once and only its stamp changes (the generator must not eat the cores)."""

    def __init__(self, args: argparse.Namespace, port: int, stamp0: float) -> None:
        self.args, self.port, self.stamp0 = args, port, stamp0
        self.clock0 = time.monotonic()
        self.last_stamp = 0.0
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.tally = Tally()
        self.retry_after: Counter = Counter()  # Retry-After value [s] -> 429s carrying it
        self.templates = [self._template(f"greedy-{k}") for k in range(args.greedy_units)]
        self.threads = [
            threading.Thread(target=self._run, args=(c,), daemon=True)
            for c in range(args.greedy_connections)
        ]

    def _template(self, unit_id: str) -> tuple[bytes, bytes]:
        """(bytes before the stamp, bytes after it) of the unit's scan body."""
        unit = SyntheticUnit(0, 1, self.args.greedy_beams, self.args.encoding)
        unit.unit_id = unit_id
        if self.args.encoding == "binary":
            body = unit.body_at(0.0)
            return body[:12], body[20:]  # the stamp is the float64 at byte 12
        content = unit.body_at(0.0)
        marker = b'"stamp":0.0'
        before, _, after = content.partition(marker)
        return before + b'"stamp":', after

    def _stamp(self) -> float:
        with self.lock:
            self.last_stamp = max(
                self.last_stamp + 1e-4, round(self.stamp0 + time.monotonic() - self.clock0, 4)
            )
            return self.last_stamp

    def body(self, n: int) -> bytes:
        before, after = self.templates[n % len(self.templates)]
        stamp = self._stamp()
        if self.args.encoding == "binary":
            return before + struct.pack("<d", stamp) + after
        return before + repr(stamp).encode() + after

    def _run(self, connection: int) -> None:
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=self.args.timeout)
        headers = HEADERS[self.args.encoding]
        n = connection
        tally = Tally()
        while not self.stop.is_set():
            content = self.body(n)
            n += self.args.greedy_connections
            tally.posted += 1
            t0 = time.perf_counter()
            try:
                conn.request("POST", "/v1/scans", body=content, headers=headers)
                reply = conn.getresponse()
                reply.read()
            except (OSError, http.client.HTTPException) as exc:
                tally.transport[type(exc).__name__] += 1
                conn.close()
                continue
            tally.latencies.append(time.perf_counter() - t0)
            tally.statuses[reply.status] += 1
            tally.acknowledged += reply.status == 200
            if reply.status == 429:
                wait = reply.getheader("Retry-After")
                with self.lock:
                    self.retry_after[wait] += 1
                if self.args.greedy_honours_retry_after and wait is not None:
                    self.stop.wait(float(wait))
            if reply.getheader("connection", "").lower() == "close":
                conn.close()
        conn.close()
        with self.lock:
            self.tally.add(tally)

    def __enter__(self) -> GreedyClient:
        for thread in self.threads:
            thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        for thread in self.threads:
            thread.join()


def rate_line(label: str, tally: Tally, args: argparse.Namespace, wall: float) -> dict:
    """Print and return the normal units' rate, share of offered and latency."""
    ms = np.array(tally.latencies) * 1e3 if tally.latencies else np.array([math.nan])
    offered = args.units * args.rate
    figures = {
        "acknowledged_per_s": tally.acknowledged / wall,
        "share_of_offered": tally.acknowledged / wall / offered,
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": float(np.percentile(ms, 99)),
        "statuses": {str(k): v for k, v in sorted(tally.statuses.items())},
        "transport_errors": dict(tally.transport),
    }
    print(
        f"{label:<22} acknowledged {figures['acknowledged_per_s']:.1f}/s of {offered:g}/s "
        f"({figures['share_of_offered']:.0%})  p50 {figures['p50_ms']:.1f} ms  "
        f"p99 {figures['p99_ms']:.1f} ms  statuses {figures['statuses']}"
        f"{'  transport ' + str(figures['transport_errors']) if tally.transport else ''}"
    )
    return figures


def greedy_compare(args: argparse.Namespace, tmp: Path) -> dict:
    """The normal units for ``--seconds`` alone, then as long again beside the greedy
    client, on one server (default settings but the grid); their rate and latency in
    each phase, and the greedy client's replies and acknowledged beams/s."""
    server = LoggedServer(tmp / "greedy", server_settings(args))
    try:
        warm_up(server.url, args)
        alone, _, wall_alone = load(server.port, args, args.seconds)
        first = math.ceil(args.seconds * args.rate) + 20  # the next phase's scans: new stamps
        with GreedyClient(args, server.port, stamp0=first * 0.1) as greedy:
            time.sleep(1.0)  # the greedy client first
            beside, _, wall_beside = load(server.port, args, args.seconds, first_scan=first)
            greedy_wall = time.monotonic() - greedy.clock0
        metrics = httpx.get(server.url + "/metrics", timeout=10).text
    finally:
        server.stop()
    print(
        f"normal units: {args.units} x {args.rate:g} Hz x {args.beams} beams ({args.encoding}); "
        f"greedy: {args.greedy_connections} connections x {args.greedy_beams} beams as "
        f"{args.greedy_units} unit id(s), flat out, "
        f"{'honouring' if args.greedy_honours_retry_after else 'ignoring'} Retry-After"
    )
    figures = {
        "alone": rate_line("alone", alone, args, wall_alone),
        "beside_greedy": rate_line("beside the greedy", beside, args, wall_beside),
    }
    g = greedy.tally
    figures["greedy"] = {
        "statuses": {str(k): v for k, v in sorted(g.statuses.items())},
        "acknowledged_beams_per_s": g.acknowledged * args.greedy_beams / greedy_wall,
        "retry_after": dict(greedy.retry_after),
        "p50_ms": float(np.percentile(g.latencies, 50)) * 1e3 if g.latencies else math.nan,
    }
    throttled = [
        line for line in metrics.splitlines() if line.startswith("fleetmap_scans_throttled_total")
    ]
    print(
        f"greedy client: statuses {figures['greedy']['statuses']}  acknowledged "
        f"{figures['greedy']['acknowledged_beams_per_s']:.0f} beams/s  p50 "
        f"{figures['greedy']['p50_ms']:.1f} ms  Retry-After {figures['greedy']['retry_after']}"
    )
    print("metrics: " + ("; ".join(throttled) if throttled else "no fleetmap_scans_throttled"))
    return figures


def ingest_stage_totals(url: str) -> tuple[dict[str, float], dict[str, float]]:
    """The server's ingest stage histograms' sums [s] and counts by stage, and its group
    sizes' as ``group_scans`` (``fleetmap_ingest_stage_seconds``, ``/metrics``)."""
    sums: dict[str, float] = {}
    counts: dict[str, float] = {}
    metrics = httpx.get(url + "/metrics", timeout=10).text
    for family in text_string_to_metric_families(metrics):
        for sample in family.samples:
            key = sample.labels.get("stage", "group_scans")
            if sample.name in (
                "fleetmap_ingest_stage_seconds_sum",
                "fleetmap_ingest_group_scans_sum",
            ):
                sums[key] = sample.value
            elif sample.name in (
                "fleetmap_ingest_stage_seconds_count",
                "fleetmap_ingest_group_scans_count",
            ):
                counts[key] = sample.value
    return sums, counts


def ingest_stage_means(
    before: tuple[dict[str, float], dict[str, float]],
    after: tuple[dict[str, float], dict[str, float]],
) -> dict[str, float]:
    """Mean time per ingest stage [ms] and mean group size (``group_scans``) of what was
    recorded between two ``ingest_stage_totals``."""
    means = {}
    for key, total in after[0].items():
        count = after[1].get(key, 0.0) - before[1].get(key, 0.0)
        mean = (total - before[0].get(key, 0.0)) / count if count else math.nan
        means[key] = mean if key == "group_scans" else mean * 1e3
    return means


def wait_for_port(port: int, timeout: float = 60.0) -> None:
    """Until something accepts connections on 127.0.0.1:``port``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.1)
    raise RuntimeError(f"nothing listens on port {port}")


def server_settings(args: argparse.Namespace) -> dict[str, Any]:
    """The settings of the server under load: a grid for the units' lattice and, with
    ``--map-process``, the map in a process of its own."""
    settings: dict[str, Any] = {"grid": grid_for(args.units)}
    if args.map_process:
        settings["server"] = {"map_process": True}
    return settings


def lattice_columns(units: int) -> int:
    """Columns of the units' lattice: about square in metres (10 x 10 cells for 100)."""
    return max(1, math.ceil(math.sqrt(units * CELL_Y / CELL_X * 2)))


def grid_for(units: int) -> dict[str, float]:
    """The server's grid: the default 100 m x 50 m at 0.05 m, larger if the lattice is."""
    columns = lattice_columns(units)
    rows = math.ceil(units / columns)
    width, height = max(100.0, columns * CELL_X), max(50.0, rows * CELL_Y)
    return {"width": round(width / RESOLUTION), "height": round(height / RESOLUTION),
            "resolution": RESOLUTION}  # fmt: skip


def slope_mib_per_min(samples: list[tuple[float, float | None]], after: float) -> float | None:
    """Theil-Sen slope [MiB/min] of the RSS samples taken at t >= ``after`` [s]: the
    median of the pairwise slopes, so one odd sample (a snapshot's copy) does not sway it."""
    points = [(t, r) for t, r in samples if t >= after and r is not None]
    pairs = [(r1 - r0) / (t1 - t0) for i, (t0, r0) in enumerate(points)
             for t1, r1 in points[i + 1:] if t1 > t0]  # fmt: skip
    return float(np.median(pairs)) * 60.0 if pairs else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=100, help="simulated units")
    parser.add_argument("--rate", type=float, default=10.0, help="[Hz] scans per unit")
    parser.add_argument("--seconds", type=float, default=60.0, help="[s] load duration")
    parser.add_argument("--timeout", type=float, default=10.0, help="[s] per request")
    parser.add_argument("--beams", type=int, default=1080, help="beams per scan (a full turn)")
    parser.add_argument(
        "--encoding", choices=("binary", "json"), default="binary", help="scan bodies"
    )
    parser.add_argument(
        "--ceiling-seconds", type=float, default=15.0,
        help="[s] flat out against a bare Starlette app, then the server (0: skip)",
    )  # fmt: skip
    parser.add_argument(
        "--batch-endpoint", action="store_true", help="one-scan POST /v1/scans/batch"
    )
    parser.add_argument(
        "--greedy-connections", type=int, default=0,
        help="instead of the run above: the units alone, then beside a greedy client "
        "posting flat out on this many connections",
    )  # fmt: skip
    parser.add_argument("--greedy-beams", type=int, default=16384, help="its beams per scan")
    parser.add_argument("--greedy-units", type=int, default=1, help="unit ids it posts as")
    parser.add_argument(
        "--greedy-honours-retry-after", action="store_true", help="it waits after a 429"
    )
    parser.add_argument(
        "--map-process", action="store_true",
        help="the server runs its map in a process of its own (server.map_process)",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print figures as JSON last")
    args = parser.parse_args()
    if args.greedy_connections > 0:
        with tempfile.TemporaryDirectory(prefix="fleet-load-") as tmp:
            figures = greedy_compare(args, Path(tmp))
        if args.json:
            print(json.dumps(figures))
        return

    with tempfile.TemporaryDirectory(prefix="fleet-load-") as tmp:
        server = LoggedServer(Path(tmp) / "data", server_settings(args))
        try:
            warm_ms = warm_up(server.url, args)
            stages_before = ingest_stage_totals(server.url)
            journal_before = server.journal_bytes()
            journaled_before = server.journal_count() or 0
            cpu_server0 = server.cpu_seconds() or 0.0
            usage0 = resource.getrusage(resource.RUSAGE_SELF)
            tally, rss, wall = load(server.port, args, args.seconds, rss_of=server)
            usage1 = resource.getrusage(resource.RUSAGE_SELF)
            cpu_server = (server.cpu_seconds() or 0.0) - cpu_server0
            journal_after = server.journal_bytes()
            stages = ingest_stage_means(stages_before, ingest_stage_totals(server.url))
        finally:
            server.stop()
        journaled = (server.journal_count() or 0) - journaled_before
        log_tail = server.log_text()[-2000:]
        ceiling = flat_out_rates(args, Path(tmp)) if args.ceiling_seconds > 0 else {}

    gen_cpu = (usage1.ru_utime - usage0.ru_utime) + (usage1.ru_stime - usage0.ru_stime)
    ms = np.array(tally.latencies) * 1e3 if tally.latencies else np.array([math.nan])
    offered = round(args.units * args.rate * args.seconds)
    errors = {f"http_{s}": n for s, n in sorted(tally.statuses.items()) if s != 200}
    errors.update(tally.transport)
    f = {
        "units": args.units,
        "rate_hz": args.rate,
        "seconds": args.seconds,
        "endpoint": "/v1/scans/batch" if args.batch_endpoint else "/v1/scans",
        "wall_s": round(wall, 2),
        "warm_up_ms": [round(t, 1) for t in warm_ms],
        "offered": offered,
        "posted": tally.posted,
        "acknowledged": tally.acknowledged,
        "missed_slots": offered - tally.posted,
        "offered_per_s": args.units * args.rate,
        "acknowledged_per_s": tally.acknowledged / wall,
        "errors": errors,
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "rss_mib": [[t, None if r is None else round(r, 1)] for t, r in rss],
        "rss_slope_second_half_mib_per_min": slope_mib_per_min(rss, args.seconds / 2),
        "journal_bytes_before": journal_before,
        "journal_bytes_after": journal_after,
        "journal_growth_bytes": journal_after - journal_before,
        "journaled_scans": journaled,
        "generator_cpu_share": gen_cpu / wall,
        "server_cpu_share": cpu_server / wall,
        "beams": args.beams,
        "encoding": args.encoding,
        "ingest_stage_mean_ms": stages,
        **ceiling,
    }
    print(f"fleet load: {args.units} units x {args.rate:g} Hz for {args.seconds:g} s, "
          f"{f['endpoint']}, closed loop (wall {wall:.1f} s)")  # fmt: skip
    print(f"warm-up scans before the run (numba compiles on the first) [ms]: "
          f"{', '.join(f'{t:.0f}' for t in warm_ms)}")  # fmt: skip
    print(f"scans  offered {offered}  posted {tally.posted}  acknowledged {tally.acknowledged}"
          f"  missed slots {offered - tally.posted}")  # fmt: skip
    print(
        f"rate   offered {f['offered_per_s']:.0f}/s  acknowledged "
        f"{f['acknowledged_per_s']:.1f}/s ({f['acknowledged_per_s'] / f['offered_per_s']:.0%})"
    )
    print(f"errors {errors or 'none'}")
    print(f"latency p50 {f['p50_ms']:.1f} ms  p99 {f['p99_ms']:.1f} ms  max {f['max_ms']:.1f} ms")
    series = "  ".join(f"{t:g}s:{r if r is None else round(r)}" for t, r in rss)
    print(f"server RSS [MiB] every {RSS_EVERY:g} s: {series}")
    slope = f["rss_slope_second_half_mib_per_min"]
    print("RSS slope over the second half: "
          + ("n/a (too few samples)" if slope is None else f"{slope:+.1f} MiB/min"))  # fmt: skip
    group = stages.pop("group_scans", math.nan)
    print("ingest stages, mean per accepted submission [ms]: "
          + "  ".join(f"{k} {v:.1f}" for k, v in stages.items())
          + f"; mean group {group:.1f} scans")  # fmt: skip
    stages["group_scans"] = group
    growth = f["journal_growth_bytes"]
    per_scan = growth / tally.acknowledged if tally.acknowledged else math.nan
    print(
        f"journal {journal_before} -> {journal_after} bytes (+{growth / 2**20:.1f} MiB, "
        f"{per_scan:.0f} B per acknowledged scan); journaled scans {journaled} vs "
        f"acknowledged {tally.acknowledged}"
    )
    print(
        f"CPU share of one core: load generator {f['generator_cpu_share']:.0%}, "
        f"server {f['server_cpu_share']:.0%} (2 shared cores)"
    )
    if ceiling:
        print(
            f"flat out for {args.ceiling_seconds:g} s each, the same bodies: bare Starlette "
            f"{ceiling['ceiling_per_s']:.0f} scans/s, map server {ceiling['flat_out_per_s']:.0f}"
            f" scans/s ({ceiling['share_of_ceiling']:.0%} of the ceiling; p99 "
            f"{ceiling['flat_out_p99_ms']:.0f} ms)"
        )
    if errors and log_tail.strip():
        print("server log tail:\n" + log_tail)
    if args.json:
        print(json.dumps(f))


if __name__ == "__main__":
    main()
