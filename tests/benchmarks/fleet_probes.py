"""Fleet probes (issue 23): a fleet that comes and goes, against a real map server, one row each.

Run: ``python -m tests.benchmarks.fleet_probes [--only dock,ahead,storage] [--json]`` (or
``python tests/benchmarks/fleet_probes.py``); about six minutes for all.

Each probe starts its own ``fleetmap serve`` (``server_process.LoggedServer`` via
``fault_probes.Context``: a fresh data dir, the default 100 m x 50 m grid, a free loopback
port), drives synthetic units (``fleet_load.SyntheticUnit``: 1,080-beam binary scans
unless a row says otherwise, a thread and a keep-alive connection per unit, closed loop
at 10 Hz) and prints one row: the probe, what happened (statuses as ``{status: count}``;
``timeout`` or a connection error's name where no reply came) and a verdict,
``survives`` or ``damaged`` (``error``: the probe itself failed, a bug here). Each probe
has a time limit (an overrun counts as ``damaged``). Stamps are "sim" (seconds from 0,
0.1 s per scan) or "epoch" (``time.time()``). Probes, with what makes them damaged:

- dock.sim: 10 units post for 1 s, then 5 go quiet while 5 keep posting at 10 Hz for
  15 s. Damaged: any scan of the 5 driving units refused.
- dock.epoch: 5 units post 10 scans each with stamps 120 s in the past (the half that
  docked 2 minutes ago), then 5 others post current epoch stamps at 10 Hz for 10 s.
  Damaged: any of the latter refused.
- oneshot: 5 units at 10 Hz (sim); after 1 s one ``/v1/scans/batch`` of 5 scans from 5
  one-shot unit ids at the fleet's time; the 5 units go on for 12 s. Damaged: a scan of
  the 5 units refused after the batch.
- lag: 2 units whose clocks lag 30 s (epoch - 30 s: a unit replaying a buffer) beside 2
  good ones, all at 10 Hz for 10 s. Damaged: any scan refused (good or lagging).
- ahead.epoch / ahead.sim: 3 honest units at 10 Hz for 2 s; a unit posts a stamp 5
  minutes ahead of them, then 1e15; the honest units go on for 2 s. Printed: the two
  replies with their message (does it name the unit's own offset, ``300`` s?), the
  honest units' statuses after, and the map's stamp (``GET /v1/map/meta``) before and
  after. Damaged: an ahead scan accepted, an honest scan refused, or the map's stamp
  more than 5 s past the honest units' newest stamp.
- fastsim: one client posts 300 scans with sim stamps from 0 (+0.1 s each) back to
  back, no clock declared (3x-30x faster than real time). Damaged: any refused.
- surrogate: a unit ``"evil\\ud800"`` (JSON text with the escape, stamps at the fleet's
  time) posts flat out beside 5 normal units at 10 Hz for 10 s. Damaged: a normal
  unit's scan refused.
- bigid: 150 scans, each from a distinct 1 MiB unit id (JSON), one by one; then the last
  id again at the same stamp with a different scan (a 409 under today's rules). Printed:
  statuses, RSS growth [MiB], data dir growth [MiB], the longest reply [bytes]. Damaged:
  a 1 MiB id accepted, or a reply over 1,000 bytes.
- storage.bytes: bytes per scan on disk for 360- and 1,080-beam scans (5 units flat out
  for 6 s each): after a SIGTERM, the scans table with its indexes (SQLite ``dbstat``) /
  scans, and the whole journal file (snapshots included) / scans; while live, (journal
  + WAL growth) / acknowledged. Damaged: a 1,080-beam scan takes more than 2x its ranges
  as float32 (8,640 bytes) in the scans table.
- storage.20k: 360-beam scans flat out until the journal holds 20,000; a unit
  ``retry`` posts one scan at the map's stamp; restart (timed); the very same scan again
  5 times (timed: the same-stamp lookup) and a different scan at that stamp 5 times (409
  expected); SIGTERM, ``fleetmap journal drop --unit u0`` of u0's last second (timed),
  restart (timed: the replay it forces). Damaged: the repeat not 200, the different
  scan not 409, the lookup's p50 over 10 ms, or ``drop`` over 5 s.
- fair: 5 units at 10 Hz alone for 8 s, then 8 s beside a greedy client posting
  16,384-beam scans flat out on 8 connections (unit ids ``greedy-0..7``, stamps at the
  fleet's time). Printed: the 5 units' achieved rate [Hz per unit] and p50/p99 latency
  [ms] in each phase, the greedy client's statuses. Damaged: under 95 % of the lone
  rate, or a normal scan refused.

The machine has 2 shared cores: absolute times are noisy, compare the rows of one run.
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
import http.client  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import sqlite3  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from mapserver.store.journal import journal_path  # noqa: E402
from tests.benchmarks.fault_probes import (  # noqa: E402
    Context,
    Row,
    call,
    client,
    post_json,
    print_table,
    run_probe,
    verdict,
)
from tests.benchmarks.fleet_load import (  # noqa: E402
    CONTENT_TYPE,
    HEADERS,
    SyntheticUnit,
    Tally,
    lattice_columns,
    post_once,
    run_unit,
)
from tests.benchmarks.server_process import MIB, ROOT, LoggedServer  # noqa: E402
from tests.server_helpers import scan_body  # noqa: E402

COLUMNS = lattice_columns(100)  # units' lattice on the default 100 m x 50 m grid
PERIOD = 0.1  # [s] 10 Hz
TIMEOUT = 10.0  # [s] per request
OK = "200"


# ---------------------------------------------------------------------------- units
class ClockedUnit(SyntheticUnit):
    """A ``SyntheticUnit`` whose stamps continue across runs: ``stamp0`` then +``step`` [s]
    per scan, or (``clock`` given) ``clock()`` [s] when the scan is made; strictly
    increasing either way (at least 1 ms apart)."""

    def __init__(
        self, k: int, unit_id: str | None = None, beams: int = 1080, encoding: str = "binary",
        stamp0: float = 0.0, step: float = PERIOD, clock: Callable[[], float] | None = None,
    ) -> None:  # fmt: skip
        super().__init__(k, COLUMNS, beams, encoding)
        self.unit_id = unit_id or self.unit_id
        self.step, self.clock = step, clock
        self.last = stamp0 - step  # [s] the latest stamp made

    def next_stamp(self) -> float:
        """[s] the next stamp (and remember it)."""
        stamp = self.clock() if self.clock else self.last + self.step
        self.last = round(max(stamp, self.last + 1e-3), 6)
        return self.last

    def body(self, n: int, batch: bool = False) -> bytes:
        """The next scan (``n`` is ignored: stamps continue from the last one made)."""
        return self.body_at(self.next_stamp(), batch)


def drive(
    port: int, plans: list[tuple[SyntheticUnit, float, float, float]], tallies: list[Tally],
    path: str = "/v1/scans",
) -> float:  # fmt: skip
    """Run ``fleet_load.run_unit`` for each (unit, start [s], stop [s], period [s]; 0: flat
    out) of ``plans``, times relative to now + 0.3 s, each counting into its tally; waits
    for all (at most their stop + TIMEOUT + 5 s). Returns the common start (monotonic)."""
    t0 = time.monotonic() + 0.3
    threads = [
        threading.Thread(
            target=run_unit,
            args=(unit, port, path, t0 + start, t0 + stop, period, TIMEOUT, False, tally),
            daemon=True,
        )
        for (unit, start, stop, period), tally in zip(plans, tallies, strict=True)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(max(0.0, t0 + max(p[2] for p in plans) + TIMEOUT + 5 - time.monotonic()))
    return t0


def codes(*tallies: Tally) -> dict[str, int]:
    """{status or transport error: count} over ``tallies``."""
    total = Tally()
    for tally in tallies:
        total.add(tally)
    out = {str(s): n for s, n in total.statuses.items()}
    out.update(total.transport)
    return dict(sorted(out.items()))


def refused(got: dict[str, int]) -> int:
    return sum(n for code, n in got.items() if code != OK)


def ms(latencies: list[float], q: float) -> float | None:
    """[ms] the ``q`` percentile of ``latencies`` [s] (None if empty)."""
    return round(float(np.percentile(latencies, q)) * 1e3, 1) if latencies else None


def warm(server: LoggedServer, unit: ClockedUnit) -> None:
    """Post ``unit``'s next scan, uncounted (the server compiles numba on its first scan);
    the probe's own unit, so that no extra unit joins the fleet."""
    body = unit.body(0)
    post_json(server.url, "/v1/scans", body, headers=HEADERS[unit.encoding], timeout=120.0)


def meta_stamp(url: str) -> Any:
    """The map's stamp [s] from ``GET /v1/map/meta`` (None if none or no reply)."""
    with client(url) as http:
        return call(http, "GET", "/v1/map/meta").get("stamp")


def data_dir_bytes(path: Path) -> int:
    """[bytes] every file under ``path``."""
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())


# ---------------------------------------------------------------------------- probes
def probe_dock_sim(ctx: Context) -> Row:
    server = ctx.start("dock.sim", None)
    units = [ClockedUnit(k) for k in range(10)]
    warm(server, units[0])
    tallies = [Tally() for _ in units]
    plans = [(u, 0.0, 1.0 if k >= 5 else 16.0, PERIOD) for k, u in enumerate(units)]
    drive(server.port, plans, tallies)
    server.stop()
    driving, quiet = codes(*tallies[:5]), codes(*tallies[5:])
    f = {"driving": driving, "quiet": quiet, "refused_driving": refused(driving)}
    what = f"5 driving units {driving} (refused {refused(driving)}); 5 docked after 1 s {quiet}"
    return Row("dock.sim", what, verdict(refused(driving) > 0), f)


def probe_dock_epoch(ctx: Context) -> Row:
    server = ctx.start("dock.epoch", None)
    past = time.time() - 120.0
    docked = [ClockedUnit(k, stamp0=past) for k in range(5)]
    warm(server, docked[0])
    driving = [ClockedUnit(k + 5, clock=time.time) for k in range(5)]
    t_docked, t_driving = [Tally() for _ in docked], [Tally() for _ in driving]
    drive(server.port, [(u, 0.0, 1.0, PERIOD) for u in docked], t_docked)  # 10 scans each
    drive(server.port, [(u, 0.0, 10.0, PERIOD) for u in driving], t_driving)
    server.stop()
    a, b = codes(*t_docked), codes(*t_driving)
    f = {"docked_2_min_ago": a, "driving": b, "refused_driving": refused(b)}
    what = f"5 units at epoch - 120 s first {a}; then 5 at epoch, 10 Hz for 10 s {b}"
    return Row("dock.epoch", what, verdict(refused(b) > 0), f)


def probe_oneshot(ctx: Context) -> Row:
    server = ctx.start("oneshot", None)
    units = [ClockedUnit(k) for k in range(5)]
    warm(server, units[0])
    before, after = [Tally() for _ in units], [Tally() for _ in units]
    drive(server.port, [(u, 0.0, 1.0, PERIOD) for u in units], before)
    stamp = max(u.last for u in units)
    oneshots = [ClockedUnit(10 + k, f"oneshot-{k}", encoding="json") for k in range(5)]
    batch = b'{"scans":[' + b",".join(u.body_at(stamp) for u in oneshots) + b"]}"
    reply = post_json(server.url, "/v1/scans/batch", batch)
    drive(server.port, [(u, 0.0, 12.0, PERIOD) for u in units], after)
    server.stop()
    a, b = codes(*before), codes(*after)
    f = {"before": a, "batch": reply.code, "after": b, "refused_after": refused(b)}
    what = f"5 units 1 s {a}; batch of 5 one-shot ids {reply.code}; the 5 units 12 s more {b}"
    return Row("oneshot", what, verdict(refused(b) > 0), f)


def probe_lag(ctx: Context) -> Row:
    server = ctx.start("lag", None)
    good = [ClockedUnit(k, clock=time.time) for k in range(2)]
    warm(server, good[0])
    lagging = [ClockedUnit(k + 2, clock=lambda: time.time() - 30.0) for k in range(2)]
    tallies = [Tally() for _ in range(4)]
    drive(server.port, [(u, 0.0, 10.0, PERIOD) for u in good + lagging], tallies)
    server.stop()
    a, b = codes(*tallies[:2]), codes(*tallies[2:])
    f = {"good": a, "lagging_30s": b}
    what = f"2 good units (epoch) {a}; 2 lagging 30 s {b}; 10 Hz for 10 s"
    return Row("lag", what, verdict(refused(a) + refused(b) > 0), f)


def probe_ahead(epoch: bool) -> Callable[[Context], Row]:
    """A unit 5 minutes ahead, then at 1e15, beside 3 honest units (``epoch`` or sim stamps)."""
    name = "ahead.epoch" if epoch else "ahead.sim"

    def probe(ctx: Context) -> Row:
        server = ctx.start(name, None)
        honest = [ClockedUnit(k, clock=time.time if epoch else None) for k in range(3)]
        warm(server, honest[0])
        before, after = [Tally() for _ in honest], [Tally() for _ in honest]
        drive(server.port, [(u, 0.0, 2.0, PERIOD) for u in honest], before)
        stamp0 = meta_stamp(server.url)
        fleet = max(u.last for u in honest)
        rogue = ClockedUnit(20, "ahead", encoding="json")
        replies = {
            label: post_json(server.url, "/v1/scans", rogue.body_at(stamp))
            for label, stamp in (("+300s", fleet + 300.0), ("1e15", 1e15))
        }
        stamp1 = meta_stamp(server.url)
        drive(server.port, [(u, 0.0, 2.0, PERIOD) for u in honest], after)
        stamp2 = meta_stamp(server.url)
        newest = max(u.last for u in honest)
        server.stop()
        details = {k: str(r.get("detail"))[:140] for k, r in replies.items()}
        numbers = [float(x) for x in re.findall(r"\d+(?:\.\d+)?", details["+300s"])]
        names_offset = any(abs(x - 300.0) < 2.0 for x in numbers)  # its own offset, ~300 s
        a, b = codes(*before), codes(*after)
        jumped = any(s is not None and s > newest + 5.0 for s in (stamp1, stamp2))
        f = {
            "honest_before": a,
            "ahead": {k: r.code for k, r in replies.items()},
            "details": details,
            "names_its_offset_300": names_offset,
            "honest_after": b,
            "map_stamp": [stamp0, stamp1, stamp2],
            "honest_newest_stamp": round(newest, 3),
        }
        what = (
            f"honest {a}; ahead +300 s: {replies['+300s'].code} {details['+300s']!r}; 1e15: "
            f"{replies['1e15'].code}; honest after {b}; map stamp {stamp0} -> {stamp1} -> "
            f"{stamp2} (honest newest {newest:.1f}); message names +300: {names_offset}"
        )
        damaged = any(r.status == 200 for r in replies.values()) or refused(b) > 0 or jumped
        return Row(name, what, verdict(damaged), f)

    return probe


def probe_fastsim(ctx: Context) -> Row:
    server = ctx.start("fastsim", None)
    unit, tally = ClockedUnit(0), Tally()
    warm(server, unit)
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=TIMEOUT)
    t0 = time.monotonic()
    for _ in range(300):
        post_once(conn, "/v1/scans", unit.body(0), HEADERS["binary"], tally)
    wall = time.monotonic() - t0
    conn.close()
    server.stop()
    got = codes(tally)
    f = {"statuses": got, "sim_s": round(unit.last, 1), "wall_s": round(wall, 2)}
    what = (
        f"300 scans, sim stamps 0 .. {unit.last:.1f} s posted in {wall:.1f} s "
        f"({unit.last / wall:.0f}x real time): {got}"
    )
    return Row("fastsim", what, verdict(refused(got) > 0), f)


def probe_surrogate(ctx: Context) -> Row:
    server = ctx.start("surrogate", None)
    units = [ClockedUnit(k) for k in range(5)]
    warm(server, units[0])
    tallies, evil = [Tally() for _ in units], Tally()
    halt = threading.Event()

    def flood(start: float) -> None:
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=TIMEOUT)
        headers = {"Content-Type": "application/json"}
        last = 0.0
        while not halt.is_set():
            last = round(max(time.monotonic() - start, last + 1e-3), 3)  # the fleet's time
            body = json.dumps(scan_body(last, "evil\ud800", 60.0, 40.0)).encode()  # \ud800
            post_once(conn, "/v1/scans", body, headers, evil)
        conn.close()

    flooder = threading.Thread(target=flood, args=(time.monotonic() + 0.3,), daemon=True)
    flooder.start()
    drive(server.port, [(u, 0.0, 10.0, PERIOD) for u in units], tallies)
    halt.set()
    flooder.join(TIMEOUT + 2)
    logged = sum("evil" in line or "surrogate" in line for line in server.log_text().splitlines())
    server.stop()
    normal, bad = codes(*tallies), codes(evil)
    f = {"normal": normal, "evil": bad, "log_lines_naming_it": logged}
    what = (
        f'5 normal units 10 s {normal}; "evil\\ud800" flat out {bad}; '
        f"server log lines naming it: {logged}"
    )
    return Row("surrogate", what, verdict(refused(normal) > 0), f)


def probe_bigid(ctx: Context) -> Row:
    server = ctx.start("bigid", None)
    warm(server, ClockedUnit(0, encoding="json"))
    rss0, disk0 = server.rss_mib() or 0.0, data_dir_bytes(server.data_dir)
    ids = [f"{i:03d}" + "x" * (MIB - 3) for i in range(150)]
    replies = []
    with client(server.url, 30.0) as http:
        for i, unit in enumerate(ids):
            body = json.dumps(scan_body(1.0, unit, 5.0 + 0.5 * (i % 150), 10.0)).encode()
            replies.append(call(http, "POST", "/v1/scans", content=body, headers=HEADERS["json"]))
        other = scan_body(1.0, ids[-1], 7.0, 12.0, ranges=[4.0] * 200)
        again = call(http, "POST", "/v1/scans", json=other)
        raw = http.post("/v1/scans", json=other)  # once more, for the reply's size undecoded
    time.sleep(1.0)  # the journal writes the last group
    rss1, disk1 = server.rss_mib() or 0.0, data_dir_bytes(server.data_dir)
    longest = max(
        len(raw.content), *(len(json.dumps(r.data)) for r in replies if r.data is not None)
    )
    server.stop()
    got = codes_of(replies)
    f = {
        "statuses": got,
        "same_id_same_stamp_other_scan": again.code,
        "rss_growth_mib": round(rss1 - rss0, 1),
        "data_dir_growth_mib": round((disk1 - disk0) / MIB, 1),
        "longest_reply_bytes": longest,
    }
    what = (
        f"150 distinct 1 MiB ids {got}; last id again, other scan: {again.code}; RSS "
        f"+{rss1 - rss0:.0f} MiB; data dir +{(disk1 - disk0) / MIB:.0f} MiB; longest reply "
        f"{longest} bytes"
    )
    return Row("bigid", what, verdict(got.get(OK, 0) > 0 or longest > 1000), f)


def fill(server: LoggedServer, units: list[ClockedUnit], seconds: float) -> Tally:
    """``units`` flat out for ``seconds`` (stamps continue); their total tally."""
    tallies = [Tally() for _ in units]
    drive(server.port, [(u, 0.0, seconds, 0.0) for u in units], tallies)
    total = Tally()
    for tally in tallies:
        total.add(tally)
    return total


def probe_storage_bytes(ctx: Context) -> Row:
    f: dict[str, Any] = {}
    for beams in (360, 1080):
        server = ctx.start(f"storage.bytes.{beams}", None)
        units = [ClockedUnit(k, beams=beams) for k in range(5)]
        warm(server, units[0])
        journal0 = server.journal_bytes()
        total = fill(server, units, 6.0)
        live = (server.journal_bytes() - journal0) / max(1, total.acknowledged)
        server.stop()
        scans = server.journal_count() or 1
        tables = table_bytes(journal_path(server.data_dir))
        f[beams] = {
            "scans": scans,
            "live_B": round(live),
            "file_B": round(server.journal_bytes() / scans),
            "scans_table_B": round(tables.get("scans", server.journal_bytes()) / scans),
            "tables_bytes": tables,
        }
    what = "; ".join(
        f"{b} beams: {v['scans_table_B']} B/scan in the scans table (and its indexes), "
        f"{v['file_B']} B/scan of the whole file after SIGTERM (snapshots included, "
        f"{v['scans']} scans), {v['live_B']} B/scan of journal + WAL growth while live"
        for b, v in f.items()
    )
    return Row("storage.bytes", what, verdict(f[1080]["scans_table_B"] > 2 * 4 * 1080), f)


def table_bytes(db: Path) -> dict[str, int]:
    """[bytes] of each table of the SQLite file ``db``, its indexes counted with it
    (``dbstat``; read-only)."""
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        owner = dict(conn.execute("SELECT name, tbl_name FROM sqlite_master").fetchall())
        out: dict[str, int] = {}
        for name, size in conn.execute("SELECT name, SUM(pgsize) FROM dbstat GROUP BY name"):
            table = owner.get(name, name)
            out[table] = out.get(table, 0) + int(size)
    return out


def probe_storage_20k(ctx: Context, target: int = 20_000) -> Row:
    server = ctx.start("storage.20k", None)
    units = [ClockedUnit(k, beams=360) for k in range(5)]
    warm(server, units[0])
    deadline = time.monotonic() + 150.0
    while (server.journal_count() or 0) < target and time.monotonic() < deadline:
        fill(server, units, 10.0)
    rows = server.journal_count() or 0
    stamp = meta_stamp(server.url)
    retry = ClockedUnit(30, "retry", beams=360)
    same, other = retry.body_at(stamp), ClockedUnit(31, "retry", beams=360).body_at(stamp)
    first = post_json(server.url, "/v1/scans", same, headers={"Content-Type": CONTENT_TYPE})
    server.stop()
    t0 = time.monotonic()
    server = ctx.start("storage.20k", None)
    restart_s = time.monotonic() - t0
    headers = {"Content-Type": CONTENT_TYPE}
    with client(server.url) as http:
        repeats = [call(http, "POST", "/v1/scans", content=same, headers=headers) for _ in range(5)]
        others = [call(http, "POST", "/v1/scans", content=other, headers=headers) for _ in range(5)]
    server.stop()
    after = round(units[0].last - 1.0, 3)  # u0's last second
    t0 = time.monotonic()
    dropped = subprocess.run(
        [sys.executable, "-m", "scenarios.cli.main", "journal", "drop", str(server.data_dir),
         "--unit", "u0", "--after", str(after)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    drop_s = time.monotonic() - t0
    t0 = time.monotonic()
    server = ctx.start("storage.20k", None, ready_timeout=300.0)
    replay_s = time.monotonic() - t0
    server.stop()
    rep_ms = float(np.median([r.seconds for r in repeats])) * 1e3
    oth_ms = float(np.median([r.seconds for r in others])) * 1e3
    rep, oth = codes_of(repeats), codes_of(others)
    f = {
        "journal_rows": rows,
        "first_post": first.code,
        "restart_s": round(restart_s, 2),
        "same_scan_again": rep,
        "same_scan_p50_ms": round(rep_ms, 1),
        "other_scan_same_stamp": oth,
        "other_scan_p50_ms": round(oth_ms, 1),
        "drop_exit": dropped.returncode,
        "drop_s": round(drop_s, 2),
        "restart_after_drop_s": round(replay_s, 2),
    }
    what = (
        f"{rows} rows; restart {restart_s:.1f} s; the same scan again {rep} p50 "
        f"{rep_ms:.1f} ms; another scan at that stamp {oth} p50 {oth_ms:.1f} ms; journal "
        f"drop (exit {dropped.returncode}) {drop_s:.1f} s; restart after it {replay_s:.1f} s"
    )
    damaged = set(rep) != {OK} or set(oth) != {"409"} or rep_ms > 10 or drop_s > 5 or rows < target
    return Row("storage.20k", what, verdict(damaged), f)


def codes_of(replies: list) -> dict[str, int]:
    """{status: count} of ``fault_probes.Reply`` objects."""
    out: dict[str, int] = {}
    for r in replies:
        out[r.code] = out.get(r.code, 0) + 1
    return dict(sorted(out.items()))


def probe_fair(ctx: Context) -> Row:
    server = ctx.start("fair", None)
    units = [ClockedUnit(k) for k in range(5)]
    warm(server, units[0])
    alone = [Tally() for _ in units]
    drive(server.port, [(u, 0.0, 8.0, PERIOD) for u in units], alone)
    start = time.monotonic() - max(u.last for u in units)  # the fleet's time, as the units'
    greedy = [
        ClockedUnit(40 + k, f"greedy-{k}", 16384, clock=lambda: time.monotonic() - start)
        for k in range(8)
    ]
    beside, g = [Tally() for _ in units], [Tally() for _ in greedy]
    plans = [(u, 0.0, 8.0, PERIOD) for u in units] + [(u, 0.0, 8.0, 0.0) for u in greedy]
    drive(server.port, plans, beside + g)
    server.stop()
    f: dict[str, Any] = {}
    for label, tallies in (("alone", alone), ("beside greedy", beside)):
        total = Tally()
        for tally in tallies:
            total.add(tally)
        f[label] = {
            "rate_hz": round(total.acknowledged / 8.0 / len(units), 2),
            "p50_ms": ms(total.latencies, 50),
            "p99_ms": ms(total.latencies, 99),
            "statuses": codes(*tallies),
        }
    f["greedy"] = codes(*g)
    share = f["beside greedy"]["rate_hz"] / max(1e-9, f["alone"]["rate_hz"])
    f["share_of_lone_rate"] = round(share, 3)
    what = (
        "; ".join(
            f"{k}: {v['rate_hz']} Hz/unit, p50 {v['p50_ms']} p99 {v['p99_ms']} ms {v['statuses']}"
            for k, v in f.items()
            if k in ("alone", "beside greedy")
        )
        + f" ({share:.0%} of the lone rate); greedy 16,384 beams x 8 conns {f['greedy']}"
    )
    bad = share < 0.95 or refused(f["beside greedy"]["statuses"]) > 0
    return Row("fair", what, verdict(bad), f)


PROBES: list[tuple[str, Callable[[Context], Row], float]] = [
    ("dock.sim", probe_dock_sim, 90.0),
    ("dock.epoch", probe_dock_epoch, 90.0),
    ("oneshot", probe_oneshot, 90.0),
    ("lag", probe_lag, 90.0),
    ("ahead.epoch", probe_ahead(True), 90.0),
    ("ahead.sim", probe_ahead(False), 90.0),
    ("fastsim", probe_fastsim, 90.0),
    ("surrogate", probe_surrogate, 90.0),
    ("bigid", probe_bigid, 180.0),
    ("storage.bytes", probe_storage_bytes, 120.0),
    ("storage.20k", probe_storage_20k, 600.0),
    ("fair", probe_fair, 120.0),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="comma-separated probes or prefixes, e.g. dock,fair")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON last")
    args = parser.parse_args()
    wanted = set(args.only.split(",")) if args.only else None
    rows = []
    with tempfile.TemporaryDirectory(prefix="fleet-probes-") as tmp:
        for name, fn, limit in PROBES:
            if wanted is None or name in wanted or name.split(".")[0] in wanted:
                rows.append(run_probe(fn, limit, Path(tmp) / name, name))
                print(f"[{rows[-1].probe}: {rows[-1].verdict}]", file=sys.stderr, flush=True)
    print_table(rows)
    if args.json:
        print(json.dumps([r.__dict__ for r in rows], default=str))


if __name__ == "__main__":
    main()
