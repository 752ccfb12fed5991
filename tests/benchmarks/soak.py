"""Soak: a fleet that comes and goes for half an hour of fleet time, against a real map server.

Run: ``python -m tests.benchmarks.soak [--units 100] [--rate 10] [--beams 1080]
[--fleet-minutes 30] [--encoding binary|json] [--config EXTRA_SETTINGS_YAML]
[--declare-clock] [--greedy-connections 4] [--greedy-beams 16384] [--json]``; a short
check: ``--units 20 --fleet-minutes 1``.

Starts ``fleetmap serve`` (``server_process.LoggedServer``, a fresh data dir; settings:
``fleet_load.grid_for(units)`` plus the YAML of ``--config``, merged per section, e.g.
``journal: {retain_seconds: 600}``) and drives ``--units`` synthetic units
(``fleet_load.SyntheticUnit``: ``--beams`` beams, a thread and a keep-alive connection
each, ``POST /v1/scans``).

Time is compressed. Fleet time advances in ticks of 1 / ``--rate`` s: a unit's n-th
scan has stamp n / rate [s] (sim stamps from 0), and a unit posts its next tick as soon
as the previous one is acknowledged, held back only so that no unit runs more than
``--skew`` fleet seconds (default 1) ahead of the slowest active unit. So the fleet runs
at whatever multiple of real time the server sustains (printed as "fleet/real"; it can
be below 1 on a slow server, and then 30 fleet minutes take longer than 30 minutes).
With ``--declare-clock`` the fleet's time is declared to the server,
``PUT /v1/clock {"now": SECONDS}``, at every whole fleet second before any unit posts a
stamp past it (a simulation declaring its clock, as ROS ``/clock``); a 404 or 405 means
"not available" (today's server): declaring stops and the run goes on without it.

Churn (fleet times as fractions of the run, T): units with k % 4 == 2 (a quarter) dock
at 0.20-0.30 T and come back 0.3 T later (9 fleet minutes of 30); units with k % 10 == 3
join late, at 0.10-0.30 T; unit u0 reboots at 0.5 T (closes its connection, stays down
``--reboot-seconds`` of real time, then a new connection, stamps going on from the tick
it had reached, or the fleet's if later: a rebooted unit's clock does not go back);
unit u1 lags: its stamps are 30 s behind the fleet's (it joins once the fleet is at
30 s). A greedy client posts ``--greedy-beams``-beam scans flat out on
``--greedy-connections`` connections (unit ids ``greedy-K``, stamps at the fleet's time)
for the whole run; its replies are counted apart from the honest units'.

Printed: a line per ``--sample-seconds`` of fleet time (default 60, less on short
runs): fleet minutes, real seconds, fleet/real, honest scans acknowledged and refused so
far, the greedy client's acknowledged and refused (429 among them), the data dir's size
[MiB] (flat once retention is reached), the journal and WAL [MiB], the server's RSS
[MiB] (flat), p50/p99 honest ingest latency [ms] over the window, and what the journal
holds (read-only beside the server): scans held, snapshots and their MiB, the file's
freelist MiB (freed pages later appends reuse) and the -wal's MiB. Then totals: honest
scans refused (must be 0) by status, the greedy client's statuses, p50/p99/max honest
latency [ms], the slopes of RSS and data dir size over the second half [MiB per real
minute, Theil-Sen], and the restart at the end: SIGTERM (time to exit), start again on
the same data dir, time until ``/healthz`` answers and until ``GET /v1/map/meta``'s
``version`` equals the last acknowledged one. ``--json`` prints the figures as one JSON
object on the last line. Measures only.
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
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from typing import Any  # noqa: E402

import httpx  # noqa: E402
import numpy as np  # noqa: E402
import orjson  # noqa: E402
import yaml  # noqa: E402

from tests.benchmarks.fleet_load import (  # noqa: E402
    HEADERS,
    SyntheticUnit,
    Tally,
    grid_for,
    lattice_columns,
    post_once,
    slope_mib_per_min,
)
from tests.benchmarks.fleet_probes import ClockedUnit, codes, data_dir_bytes  # noqa: E402
from tests.benchmarks.server_process import MIB, LoggedServer, journal_shape  # noqa: E402

LAG_S = 30.0  # [s] the lagging unit's stamps behind the fleet's


# ---------------------------------------------------------------------------- fleet time
class FleetClock:
    """The fleet's time in ticks: ``floor`` is the lowest next tick of the active units
    (ticks below it are done by every unit posting now); a unit may post tick n once
    n <= ``ceiling()`` = floor + ``skew`` ticks (and, while a clock is declared, n <= the
    declared tick). Thread-safe; waiters wake when the floor or the declaration moves."""

    def __init__(self, skew: int) -> None:
        self.cond = threading.Condition()
        self.skew = skew
        self.next: dict[str, int] = {}  # active unit -> its next tick
        self.floor = 0
        self.declared: int | None = None  # None: no clock declared

    def _update(self) -> None:
        floor = min(self.next.values()) if self.next else self.floor
        if floor > self.floor:
            self.floor = floor
            self.cond.notify_all()

    def join(self, unit: str, after: int = 0) -> int:
        """``unit`` becomes active at the fleet's current tick, or at ``after`` if that is
        later (returned): a unit back from a reboot or a dock goes on from the tick it had
        reached, as a real unit's clock does, and never sends a stamp it sent before."""
        with self.cond:
            start = max(self.floor, after)
            self.next[unit] = start
            return start

    def leave(self, unit: str) -> None:
        with self.cond:
            self.next.pop(unit, None)
            self._update()

    def done(self, unit: str, next_tick: int) -> None:
        with self.cond:
            self.next[unit] = next_tick
            self._update()

    def ceiling(self) -> int:
        top = self.floor + self.skew
        return top if self.declared is None else min(top, self.declared)

    def declare(self, tick: int | None) -> None:
        """The server now knows the fleet's time up to ``tick`` (None: stop declaring)."""
        with self.cond:
            self.declared = tick
            self.cond.notify_all()

    def wait_turn(self, tick: int, halt: threading.Event) -> None:
        with self.cond:
            while tick > self.ceiling() and not halt.is_set():
                self.cond.wait(0.5)

    def wait_floor(self, tick: int, halt: threading.Event) -> None:
        with self.cond:
            while self.floor < tick and not halt.is_set():
                self.cond.wait(0.5)


@dataclass
class Plan:
    """A unit's churn in ticks (None: not for this unit); ``offset`` [s] added to its
    stamps (the laggard's -30 s)."""

    join: int = 0
    dock: int | None = None
    back: int | None = None
    reboot: int | None = None
    offset: float = 0.0


def plans(units: int, ticks: int, rate: float) -> list[Plan]:
    """Unit k's churn in a run of ``ticks`` (see the module docstring)."""
    out = []
    for k in range(units):
        p = Plan()
        if k == 0:
            p.reboot = round(0.5 * ticks)
        elif k == 1:
            p.offset, p.join = -LAG_S, math.ceil(LAG_S * rate)
        elif k % 4 == 2:
            p.dock = round(ticks * (0.2 + 0.1 * k / units))
            p.back = p.dock + round(0.3 * ticks)
        elif k % 10 == 3:
            p.join = round(ticks * (0.1 + 0.2 * k / units))
        out.append(p)
    return out


@dataclass
class Run:
    """What every thread needs: the server's port, the clock, the run's length [ticks],
    the tick [s], a halt event, request timeout [s], and the highest map version
    acknowledged so far."""

    port: int
    clock: FleetClock
    ticks: int
    step: float
    halt: threading.Event
    timeout: float
    reboot_s: float
    last_version: int = 0

    def connect(self) -> http.client.HTTPConnection:
        return http.client.HTTPConnection("127.0.0.1", self.port, timeout=self.timeout)

    def post(
        self, conn: http.client.HTTPConnection, unit: SyntheticUnit, stamp: float, tally: Tally
    ) -> None:
        """Post ``unit``'s scan at ``stamp`` [s]; note the acknowledged map version."""
        data = post_once(conn, "/v1/scans", unit.body_at(stamp), HEADERS[unit.encoding], tally)
        if data and data.startswith(b'{"seq"'):
            try:
                self.last_version = max(self.last_version, int(orjson.loads(data)["map_version"]))
            except (ValueError, KeyError, TypeError):
                pass


def run_honest(run: Run, unit: SyntheticUnit, plan: Plan, tally: Tally) -> None:
    """One honest unit: waits for its join tick, posts tick after tick, docks, reboots."""
    clock, uid = run.clock, unit.unit_id
    if plan.join >= run.ticks:
        return  # joins after the run
    clock.wait_floor(plan.join, run.halt)
    conn, n = run.connect(), clock.join(uid)
    try:
        while not run.halt.is_set() and n < run.ticks:
            if plan.dock is not None and n >= plan.dock:
                clock.leave(uid)
                conn.close()  # docked: the server closes idle keep-alive connections anyway
                clock.wait_floor(plan.back or 0, run.halt)
                plan.dock, conn, n = None, run.connect(), clock.join(uid, n)
                continue
            if plan.reboot is not None and n >= plan.reboot:
                clock.leave(uid)
                conn.close()
                run.halt.wait(run.reboot_s)
                plan.reboot, conn, n = None, run.connect(), clock.join(uid, n)
                continue
            clock.wait_turn(n, run.halt)
            run.post(conn, unit, round(n * run.step + plan.offset, 6), tally)
            n += 1
            clock.done(uid, n)
    finally:
        clock.leave(uid)
        conn.close()


def run_greedy(run: Run, unit: ClockedUnit, tally: Tally) -> None:
    """Flat out until the run halts, stamps at the fleet's time."""
    conn = run.connect()
    try:
        while not run.halt.is_set():
            run.post(conn, unit, unit.next_stamp(), tally)
    finally:
        conn.close()


def run_declarer(run: Run, url: str, state: dict[str, Any]) -> None:
    """``PUT /v1/clock`` at every whole fleet second ahead of the units: they may post up
    to the declared tick. A reply other than 200/204 (404/405: a server without the
    clock) ends declaring: ``state["clock"]``; no reply (a read error or timeout under
    load) is counted in ``state["errors"]`` and the PUT is tried again, as a simulation
    keeps publishing ``/clock``."""
    per_second = round(1.0 / run.step)
    with httpx.Client(base_url=url, timeout=run.timeout) as http:
        while not run.halt.is_set():
            clock = run.clock
            target = math.ceil((clock.floor + clock.skew) / per_second) * per_second
            if clock.declared is None or target > clock.declared:
                state["puts"] = state.get("puts", 0) + 1
                try:
                    status = http.put("/v1/clock", json={"now": target * run.step}).status_code
                except httpx.HTTPError as exc:
                    state["errors"] = state.get("errors", 0) + 1
                    state["last_error"] = type(exc).__name__
                    run.halt.wait(0.1)
                    continue
                if status != 200 and status != 204:
                    state["clock"] = f"not available ({status})"
                    clock.declare(None)
                    return
                state["clock"] = "declared"
                clock.declare(target)
            run.halt.wait(0.01)


# ---------------------------------------------------------------------------- readings
def latencies_since(tallies: list[Tally], marks: list[int]) -> list[float]:
    """[s] the latencies each tally got since ``marks`` (updated to now)."""
    out: list[float] = []
    for i, tally in enumerate(tallies):
        got = len(tally.latencies)
        out += tally.latencies[marks[i] : got]
        marks[i] = got
    return out


def pct(values: list[float], q: float) -> float:
    """[ms] the ``q`` percentile of ``values`` [s] (nan if empty)."""
    return float(np.percentile(values, q)) * 1e3 if values else math.nan


def totals(tallies: list[Tally]) -> Tally:
    total = Tally()
    for tally in tallies:
        total.add(tally)
    return total


def refused(tallies: list[Tally]) -> int:
    """Replies other than 200, and requests that got no reply (in flight: not counted)."""
    return sum(n for t in tallies for s, n in t.statuses.items() if s != 200) + sum(
        n for t in tallies for n in t.transport.values()
    )


def restart(server: LoggedServer, settings: dict, last_version: int) -> dict[str, Any]:
    """SIGTERM, then a new server on the same data dir: [s] to exit, to ``/healthz``, to
    the map version ``last_version``."""
    stop_s, code = server.timed_stop()
    t0 = time.monotonic()
    again = LoggedServer(server.data_dir, settings, ready_timeout=600.0)
    healthz_s = time.monotonic() - t0
    version, version_s = None, None
    try:
        with httpx.Client(base_url=again.url, timeout=10.0) as http:
            deadline = time.monotonic() + 300.0
            while time.monotonic() < deadline:
                version = http.get("/v1/map/meta").json().get("version")
                if version == last_version:
                    version_s = time.monotonic() - t0
                    break
                time.sleep(0.05)
    finally:
        again.stop()
    return {
        "sigterm_s": round(stop_s, 2),
        "exit_code": code,
        "healthz_s": round(healthz_s, 2),
        "version_s": None if version_s is None else round(version_s, 2),
        "version": version,
        "last_acknowledged_version": last_version,
    }


def merged(base: dict, extra: dict) -> dict:
    """``base`` with ``extra``'s sections merged in (a dict section key by key)."""
    out = dict(base)
    for key, value in extra.items():
        both = isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = {**out[key], **value} if both else value
    return out


# ---------------------------------------------------------------------------- main
def soak(args: argparse.Namespace, data_dir: Path) -> dict[str, Any]:
    """The run; its figures (also printed as it goes)."""
    extra = yaml.safe_load(args.config.read_text()) if args.config else {}
    settings = merged({"grid": grid_for(args.units)}, extra or {})
    step = 1.0 / args.rate
    ticks = round(args.fleet_minutes * 60 * args.rate)
    columns = lattice_columns(args.units)
    units = [SyntheticUnit(k, columns, args.beams, args.encoding) for k in range(args.units)]
    server = LoggedServer(data_dir, settings)
    run = Run(
        server.port,
        FleetClock(max(1, round(args.skew * args.rate))),
        ticks,
        step,
        threading.Event(),
        args.timeout,
        args.reboot_seconds,
    )
    greedy = [
        ClockedUnit(
            k % 100,  # a bay on the map (beside honest units)
            f"greedy-{k}",
            args.greedy_beams,
            args.encoding,
            clock=lambda: run.clock.floor * step,
        )
        for k in range(args.greedy_connections)
    ]
    honest_t, greedy_t = [Tally() for _ in units], [Tally() for _ in greedy]
    clock_state: dict[str, Any] = {"clock": "not asked (no --declare-clock)"}
    samples: list[dict[str, Any]] = []
    figures: dict[str, Any] = {}
    try:
        with httpx.Client(base_url=server.url, timeout=120.0) as http:  # numba compiles
            http.post("/v1/scans", content=units[0].body_at(0.0), headers=HEADERS[args.encoding])
        threads = [
            threading.Thread(target=run_honest, args=(run, u, p, t), daemon=True)
            for u, p, t in zip(units, plans(args.units, ticks, args.rate), honest_t, strict=True)
        ]
        threads += [
            threading.Thread(target=run_greedy, args=(run, u, t), daemon=True)
            for u, t in zip(greedy, greedy_t, strict=True)
        ]
        if args.declare_clock:
            threads.append(
                threading.Thread(
                    target=run_declarer, args=(run, server.url, clock_state), daemon=True
                )
            )
        every = args.sample_seconds or min(60.0, args.fleet_minutes * 60 / 6)
        print(
            f"soak: {args.units} units x {args.rate:g} Hz x {args.beams} beams ({args.encoding}),"
            f" {args.fleet_minutes:g} fleet minutes ({ticks} ticks), greedy "
            f"{args.greedy_connections} x {args.greedy_beams} beams; settings {settings}",
            flush=True,
        )
        print(
            f"{'fleet min':>9} {'real s':>7} {'x real':>6} {'honest ok':>9} {'refused':>7} "
            f"{'greedy ok':>9} {'refused':>7} {'(429)':>6} {'data MiB':>8} {'journal':>8} "
            f"{'RSS MiB':>7} {'p50 ms':>7} {'p99 ms':>7} {'held':>8} {'snaps':>5} {'snap MiB':>8} "
            f"{'free MiB':>8} {'wal MiB':>7}",
            flush=True,
        )
        t0 = time.monotonic()
        deadline = t0 + args.max_real_minutes * 60
        for thread in threads:
            thread.start()
        marks, next_sample = [0] * len(units), every
        while time.monotonic() < deadline:
            fleet_s = run.clock.floor * step
            finished = fleet_s >= ticks * step or not any(
                t.is_alive() for t in threads[: len(units)]
            )
            if fleet_s >= next_sample or finished:
                window = latencies_since(honest_t, marks)
                real = time.monotonic() - t0
                g = totals(greedy_t)
                s = {
                    "fleet_min": round(fleet_s / 60, 2),
                    "real_s": round(real, 1),
                    "honest_ok": sum(t.acknowledged for t in honest_t),
                    "honest_refused": refused(honest_t),
                    "greedy_ok": g.acknowledged,
                    "greedy_refused": refused(greedy_t),
                    "greedy_429": g.statuses.get(429, 0),
                    "data_mib": round(data_dir_bytes(data_dir) / MIB, 1),
                    "journal_mib": round(server.journal_bytes() / MIB, 1),
                    "rss_mib": round(server.rss_mib() or math.nan, 1),
                    "p50_ms": round(pct(window, 50), 1),
                    "p99_ms": round(pct(window, 99), 1),
                    **(journal_shape(data_dir) or {}),
                }
                samples.append(s)
                print(
                    f"{s['fleet_min']:9.2f} {real:7.0f} {fleet_s / max(real, 1e-9):6.2f} "
                    f"{s['honest_ok']:9d} {s['honest_refused']:7d} {s['greedy_ok']:9d} "
                    f"{s['greedy_refused']:7d} {s['greedy_429']:6d} {s['data_mib']:8.1f} "
                    f"{s['journal_mib']:8.1f} {s['rss_mib']:7.1f} {s['p50_ms']:7.1f} "
                    f"{s['p99_ms']:7.1f} {s.get('held', -1):8d} {s.get('snapshots', -1):5d} "
                    f"{s.get('snapshot_mib', math.nan):8.1f} {s.get('free_mib', math.nan):8.1f} "
                    f"{s.get('wal_mib', math.nan):7.1f}",
                    flush=True,
                )
                next_sample += every
                if finished:
                    break
            time.sleep(0.2)
        real = time.monotonic() - t0
        fleet_s = run.clock.floor * step
        run.halt.set()
        for thread in threads:
            thread.join(args.timeout + 5)
        honest, g = totals(honest_t), totals(greedy_t)
        lat = honest.latencies
        figures = {
            "units": args.units,
            "rate_hz": args.rate,
            "beams": args.beams,
            "encoding": args.encoding,
            "fleet_minutes_planned": args.fleet_minutes,
            "fleet_s": round(fleet_s, 1),
            "real_s": round(real, 1),
            "fleet_per_real": round(fleet_s / real, 3),
            "completed": fleet_s >= ticks * step,
            "declared_clock": clock_state,
            "settings": settings,
            "honest_posted": honest.posted,
            "honest_acknowledged": honest.acknowledged,
            "honest_refused": refused(honest_t),
            "honest_statuses": codes(honest),
            "greedy_statuses": codes(g),
            "greedy_acknowledged": g.acknowledged,
            "p50_ms": round(pct(lat, 50), 1),
            "p99_ms": round(pct(lat, 99), 1),
            "max_ms": round(max(lat, default=math.nan) * 1e3, 1),
            "rss_slope_mib_per_min": slope_mib_per_min(
                [(s["real_s"], s["rss_mib"]) for s in samples], real / 2
            ),
            "data_slope_mib_per_min": slope_mib_per_min(
                [(s["real_s"], s["data_mib"]) for s in samples], real / 2
            ),
            "samples": samples,
        }
        figures["restart"] = restart(server, settings, run.last_version)
    finally:
        run.halt.set()
        if server.alive():
            server.stop()
    return figures


def report(f: dict[str, Any]) -> None:
    """The totals, after the per-sample lines."""
    short = "" if f["completed"] else " (NOT completed: --max-real-minutes)"
    print(
        f"fleet {f['fleet_s'] / 60:.2f} min in {f['real_s'] / 60:.2f} real min: fleet/real "
        f"{f['fleet_per_real']:.2f}{short}"
        f"; declared clock: {f['declared_clock'].get('clock')}"
    )
    print(
        f"honest scans: posted {f['honest_posted']}, acknowledged {f['honest_acknowledged']}, "
        f"REFUSED {f['honest_refused']} (must be 0) {f['honest_statuses']}"
    )
    print(
        f"greedy client (counted apart): acknowledged {f['greedy_acknowledged']} "
        f"{f['greedy_statuses']}"
    )
    print(f"honest ingest latency p50 {f['p50_ms']} ms  p99 {f['p99_ms']} ms  max {f['max_ms']} ms")
    for key, name in (("rss_slope_mib_per_min", "RSS"), ("data_slope_mib_per_min", "data dir")):
        v = f[key]
        print(
            f"{name} slope over the second half: "
            + ("n/a (too few samples)" if v is None else f"{v:+.1f} MiB per real minute")
        )
    r = f["restart"]
    print(
        f"restart: SIGTERM exit {r['exit_code']} in {r['sigterm_s']} s; start to /healthz "
        f"{r['healthz_s']} s; to map version {r['last_acknowledged_version']} (the last "
        f"acknowledged): {r['version_s']} s (got {r['version']})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=100, help="honest units")
    parser.add_argument("--rate", type=float, default=10.0, help="[Hz] of fleet time per unit")
    parser.add_argument("--beams", type=int, default=1080, help="beams per scan (a full turn)")
    parser.add_argument("--fleet-minutes", type=float, default=30.0, help="[min] of fleet time")
    parser.add_argument("--encoding", choices=("binary", "json"), default="binary")
    parser.add_argument("--config", type=Path, help="extra server settings (YAML), merged")
    parser.add_argument("--declare-clock", action="store_true", help="PUT /v1/clock per second")
    parser.add_argument("--greedy-connections", type=int, default=4, help="0: no greedy client")
    parser.add_argument("--greedy-beams", type=int, default=16384)
    parser.add_argument(
        "--skew",
        type=float,
        default=1.0,
        help="[s] of fleet time a unit may run ahead of the slowest",
    )
    parser.add_argument("--reboot-seconds", type=float, default=2.0, help="[s] u0 is down")
    parser.add_argument("--sample-seconds", type=float, help="[s] of fleet time per line")
    parser.add_argument("--timeout", type=float, default=10.0, help="[s] per request")
    parser.add_argument(
        "--max-real-minutes",
        type=float,
        default=120.0,
        help="[min] stop there even if the fleet time is not reached",
    )
    parser.add_argument("--json", action="store_true", help="print figures as JSON last")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="soak-") as tmp:
        f = soak(args, Path(tmp) / "data")
    report(f)
    if args.json:
        print(json.dumps(f, default=str))


if __name__ == "__main__":
    main()
