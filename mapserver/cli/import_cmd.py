"""``fleetmap import RECORDING --server URL``: stream a recording into a running map
server (docs/recordings.md "Importing into a server").

The server refuses a stamp ahead of its reference (docs/map-time.md: its wall clock, a
declared simulation clock or the map's simulated time), so the stamps are designed here:

- ``--restamp`` (default): the recording is shifted in time so that it happened just now.
  At ``--rate 1`` the first scan is stamped with the wall clock at the start and each
  scan is sent when its stamp comes: the map fills as if the robot were driving now,
  beside a live fleet, with the evidence's ages as recorded. At any other rate the
  recording is shifted to end at the start (its span from the recording's index, e.g.
  a bag's metadata), so every stamp is in the past and may be sent at once. Either way
  no scan is sent before its stamp is due on this machine's clock (epoch seconds), so
  none leads the server's wall clock; only clock skew between the two machines beyond
  ``clock.max_lead_s`` could still get a 422.
- ``--no-restamp``: the stamps as recorded. Epoch stamps of a past recording are behind
  the wall clock and accepted at any rate; simulated stamps (from 0, ``use_sim_time``)
  are judged against the map's simulated time, which refuses a gap of more than
  ``max_lead_s`` in the recording unless ``--declare-clock`` (an ``admin`` token)
  declares the clock as each batch's last stamp: on a server of its own only, since a
  declared clock binds every unit.

Pacing: ``--rate R`` sends R seconds of the recording per second (default 1: as
recorded); ``--rate max`` as fast as the server accepts. Scans go in batches (``POST
/v1/scans/batch``, binary) of up to ``--batch`` scans that are due. Replies: 429 waits
its Retry-After and sends again (``MapClient`` retries, then here without end); a 409
(a stamp behind the unit's last, or a different scan at a stamp already taken, e.g.
an import run twice without ``--restamp``) refuses that scan, counted, and the import
goes on; a 422, 413 or 400 stops with the server's message; an unreachable server is
retried ``UNAVAILABLE_RETRIES`` times. Ctrl-C stops after the batch in flight and prints
the summary: sent, accepted, refused by reason.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from mapserver.cli.progress import ScanProgress
from mapserver.cli.recording_args import add_recording_args, recording_options_from_args
from mapserver.client.map_client import (
    Conflict,
    MapClient,
    MapClientError,
    MapRequestError,
    MapServerUnavailable,
)
from mapserver.core.errors import FleetmapError
from mapserver.core.scan import Scan
from mapserver.store.recordings import Recording, open_recording

UNAVAILABLE_RETRIES = 5
"""How many times a batch is sent again to a server that did not answer (1, 2, 4, 8,
16 s apart); a retried batch is fused once (the server answers a retry with its acks)."""
THROTTLE_WAIT_S = 1.0  # [s] the wait after a 429 that MapClient's own retries did not clear


def rate_arg(text: str) -> float:
    """argparse type for ``--rate``: a positive factor of real time, or ``max`` (inf)."""
    if text.strip().lower() == "max":
        return math.inf
    try:
        rate = float(text)
    except ValueError:
        rate = math.nan
    if not rate > 0 or math.isnan(rate):
        raise argparse.ArgumentTypeError(f"expected a factor > 0 or 'max', got {text!r}")
    return rate


def add_import_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``import``."""
    parser = subparsers.add_parser(
        "import",
        help="stream a recording (ROS bag, CARMEN log, scan file) into a running map server",
        description="Send a recording's scans to a map server, paced and restamped so the "
        "server's clock rules accept them (docs/recordings.md).",
    )
    parser.add_argument("recording", type=Path, help="ROS 1 or 2 bag, CARMEN log or scan file")
    parser.add_argument("--server", required=True, help="the server's URL, e.g. http://host:8700")
    parser.add_argument("--token", help="a unit (or admin) token of the server")
    parser.add_argument(
        "--restamp",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="shift the stamps so the recording happened now (default: on)",
    )
    parser.add_argument(
        "--rate",
        type=rate_arg,
        default=1.0,
        help="seconds of recording per second, or 'max' (default 1: as recorded)",
    )
    parser.add_argument("--batch", type=int, default=50, help="most scans per request (50)")
    parser.add_argument(
        "--declare-clock",
        action="store_true",
        help="declare the server's clock as each batch's last stamp (admin token; "
        "a server of its own)",
    )
    add_recording_args(parser)
    parser.set_defaults(handler=run_import)


@dataclass
class ImportSummary:
    """What an import did: scans sent, accepted and refused (by reason)."""

    sent: int = 0
    accepted: int = 0
    refused: Counter[str] = field(default_factory=Counter)
    throttled: int = 0
    first_stamp: float | None = None
    last_stamp: float | None = None
    shift_s: float = 0.0
    stopped: str | None = None

    def line(self) -> str:
        refused = sum(self.refused.values())
        reasons = "; ".join(f"{n} {reason}" for reason, n in self.refused.most_common())
        text = f"sent {self.sent} scans, accepted {self.accepted}, refused {refused}"
        text += f" ({reasons})" if reasons else ""
        if self.throttled:
            text += f"; throttled {self.throttled} times (429)"
        if self.first_stamp is not None:
            text += (
                f"; stamps {self.first_stamp:.3f} .. {self.last_stamp:.3f} s "
                f"(shifted {self.shift_s:+.3f} s)"
            )
        return text


class ImportStopped(FleetmapError):
    """The server refused a batch in a way that sending on cannot help (its message)."""


@dataclass
class Importer:
    """Sends a recording's scans through ``client`` (module docstring); ``clock`` is the
    wall clock [epoch s] and ``sleep`` waits [s] (parameters for tests)."""

    client: MapClient
    rate: float = 1.0
    restamp: bool = True
    batch: int = 50
    declare_clock: bool = False
    clock: Callable[[], float] = time.time
    sleep: Callable[[float], None] = time.sleep
    summary: ImportSummary = field(default_factory=ImportSummary)

    def run(self, recording: Recording, progress: Callable[[int, int | None], None]) -> None:
        total = recording.scan_count()
        for batch in self._batches(recording):
            self._send(batch)
            progress(self.summary.sent, total)

    def _batches(self, recording: Recording) -> Iterator[list[Scan]]:
        """Batches of scans, restamped, each sent no earlier than it is due."""
        start = self.clock()
        first: float | None = None
        pending: list[Scan] = []
        for scan in recording:
            if first is None:
                first = scan.stamp
                self.summary.shift_s = self._shift(recording, first, start)
            stamped = self._stamped(scan)
            due = start + (scan.stamp - first) / self.rate
            if self.restamp:  # never ahead of this machine's clock
                due = max(due, stamped.stamp)
            if pending and (len(pending) >= self.batch or due > self.clock()):
                yield pending
                pending = []
            self._wait_until(due)
            pending.append(stamped)
        if pending:
            yield pending

    def _shift(self, recording: Recording, first: float, start: float) -> float:
        """[s] added to every stamp: none without restamping; else the first scan at
        ``start`` (rate 1) or the last one, as far as the recording can tell."""
        if not self.restamp:
            return 0.0
        span = 0.0 if self.rate == 1.0 else (recording.duration() or 0.0)
        return start - first - span

    def _stamped(self, scan: Scan) -> Scan:
        if not self.summary.shift_s:
            stamped = scan
        else:
            stamped = dataclasses.replace(scan, stamp=scan.stamp + self.summary.shift_s)
        if self.summary.first_stamp is None:
            self.summary.first_stamp = stamped.stamp
        self.summary.last_stamp = stamped.stamp
        return stamped

    def _wait_until(self, when: float) -> None:
        wait = when - self.clock()
        if wait > 0 and math.isfinite(wait):
            self.sleep(wait)

    def _send(self, batch: list[Scan]) -> None:
        if self.declare_clock:
            self._call(lambda: self.client.declare_clock(batch[-1].stamp))
        try:
            self._call(lambda: self.client.post_scans(batch))
        except Conflict as exc:
            if len(batch) > 1:  # all or none: find the refused scan(s), send the rest
                for scan in batch:
                    self._send([scan])
                return
            self.summary.sent += 1
            self.summary.refused[f"409 {_reason(exc.detail)}"] += 1
            return
        self.summary.sent += len(batch)
        self.summary.accepted += len(batch)

    def _call(self, request: Callable[[], object]) -> object:
        """``request()``, through throttling and a server that went away for a while."""
        unavailable = 0
        while True:
            try:
                return request()
            except MapServerUnavailable:
                if unavailable == UNAVAILABLE_RETRIES:
                    raise
                self.sleep(2.0**unavailable)
                unavailable += 1
            except MapRequestError as exc:
                if exc.status == 429:
                    self.summary.throttled += 1
                    self.sleep(THROTTLE_WAIT_S)
                elif isinstance(exc, Conflict):
                    raise
                else:
                    raise ImportStopped(str(exc)) from None


def _reason(detail: object) -> str:
    """A refusal's reason for the summary: the server's detail up to its first colon
    (``stamp``, ...), so refusals of one kind count together."""
    text = detail if isinstance(detail, str) else repr(detail)
    return text.split(":")[0][:60]


def run_import(args: argparse.Namespace, http: httpx.Client | None = None) -> int:
    """Import ``args.recording``; exit 0 when every scan was accepted, 1 when some were
    refused or the server stopped the import, 2 on a bad recording or flag, 130 on
    Ctrl-C (after the summary)."""
    prog = "fleetmap import"
    if args.batch < 1:
        print(f"{prog}: error: --batch must be >= 1, got {args.batch}", file=sys.stderr)
        return 2
    try:
        recording = open_recording(args.recording, recording_options_from_args(args))
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(f"{prog}: {recording.describe()}", file=sys.stderr)
    own_http = http is None
    http = http or httpx.Client(base_url=args.server)
    client = MapClient(http, token=args.token, timeout=30.0, retries=5, max_retry_wait_s=10.0)
    importer = Importer(
        client, rate=args.rate, restamp=args.restamp, batch=args.batch,
        declare_clock=args.declare_clock,
    )  # fmt: skip
    progress = ScanProgress("sent")
    code = 0
    try:
        importer.run(recording, progress)
    except KeyboardInterrupt:
        importer.summary.stopped = "interrupted (Ctrl-C)"
        code = 130
    except (ImportStopped, MapClientError) as exc:
        importer.summary.stopped = f"the server stopped the import: {exc}"
        code = 1
    except ValueError as exc:  # RecordingError and the like, found while reading
        importer.summary.stopped = f"error: {exc}"
        code = 2
    except OSError as exc:
        importer.summary.stopped = f"error: cannot read {args.recording}: {exc}"
        code = 2
    finally:
        progress.finish()
        if own_http:
            http.close()
    summary = importer.summary
    if summary.stopped:
        print(f"{prog}: {summary.stopped}", file=sys.stderr)
    print(f"imported {args.recording}: {summary.line()}")
    if code == 0 and summary.refused:
        code = 1
    return code
