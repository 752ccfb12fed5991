"""Posting each tick's scans to the map server through ``MapClient``.

``ScanPoster.post`` sends one tick's scans as one ``POST /v1/scans/batch`` (split into
requests of at most ``max_batch`` scans, the server's ``limits.max_batch``). Stamps are
the sim's, so the server must not have seen later stamps of these units (docs/http-api.md 2.1:
409).

- ``in_flight = 0`` (default): ``post`` waits for the acks and returns them, one per scan
  in order: once it returns, the scans are durable.
- ``in_flight = n > 0``: a worker thread sends the batches in order while the simulation
  runs on, with at most ``n`` ticks' batches queued (``post`` blocks when the queue is
  full, so a slower server slows the simulation down rather than piling up scans).
  The ticks that queued while a request was on its way go out together, in order, in
  requests of up to ``max_batch`` scans: a backlog costs one request's overhead (HTTP,
  the journal's commit) rather than one per tick. A refused request refuses all of
  its scans (the batch rule), so a tick sent with a refused one is not journaled either.
  ``post`` returns the acks received since the last call (earlier ticks' scans);
  ``flush`` waits for every batch and returns the remaining acks. After a failed request
  no further batch is sent, and ``post``, ``flush`` and ``close`` raise its error.

With ``declare_every_s`` set, the poster also declares the simulation's clock to the
server (``PUT /v1/clock``, as ROS's ``/clock``; docs/map-time.md) before a tick's scans
whenever their newest stamp is that much past the last declaration (tick by tick, also
for ticks sent together: the same declarations however the ticks were grouped), so the
server judges the fleet's stamps against the simulation's time. A server that does not take the
declaration (an older one: 404 or 405; a token that is not an admin's: 403) is told no
more, and stamps are then judged by the server's own rule.

Close a poster (``close`` or ``with``) to stop its worker.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Sequence

from mapserver.client import MapClient, MapRequestError, ScanAck
from mapserver.core.scan import Scan

logger = logging.getLogger(__name__)

DEFAULT_MAX_BATCH = 256
"""Scans per request: the map server's default ``limits.max_batch``."""


class ScanPoster:
    """Sends scans through ``client`` in batches of at most ``max_batch``, with up to
    ``in_flight`` ticks' batches on their way, declaring the simulation's clock every
    ``declare_every_s`` [s] of its time (None: never) (module docstring)."""

    def __init__(
        self,
        client: MapClient,
        max_batch: int = DEFAULT_MAX_BATCH,
        in_flight: int = 0,
        declare_every_s: float | None = None,
    ) -> None:
        for name, value, low in (("max_batch", max_batch, 1), ("in_flight", in_flight, 0)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        if declare_every_s is not None and not declare_every_s > 0:
            raise ValueError(
                f"declare_every_s must be > 0 seconds or None, got {declare_every_s!r}"
            )
        self.client = client
        self.max_batch = max_batch
        self.in_flight = in_flight
        self.declare_every_s = declare_every_s
        self.declared: float | None = None  # [s] the clock last declared
        self.posted = 0  # scans acknowledged so far
        self._acks: list[ScanAck] = []
        self._lock = threading.Lock()
        self._error: Exception | None = None
        self._queue: queue.Queue[Sequence[Scan] | None] | None = None
        self._worker: threading.Thread | None = None
        if in_flight:
            self._queue = queue.Queue(maxsize=in_flight)
            self._worker = threading.Thread(target=self._run, name="scan-poster", daemon=True)
            self._worker.start()

    def post(self, scans: Sequence[Scan]) -> list[ScanAck]:
        """Send one tick's ``scans``; returns their acks (waiting) or, with ``in_flight``,
        the acks received since the last call."""
        if self._queue is None:
            acks = self._send([scans])
            self.posted += len(acks)
            return acks
        self._raise_error()
        if scans:
            self._queue.put(list(scans))
        return self._take_acks()

    def flush(self) -> list[ScanAck]:
        """Wait until every queued batch is acknowledged; returns the acks not yet returned."""
        if self._queue is not None:
            self._queue.join()
        self._raise_error()
        return self._take_acks()

    def close(self) -> None:
        """Stop the worker after the queued batches (idempotent); raises a pending error."""
        if self._worker is not None and self._queue is not None:
            self._queue.put(None)
            self._worker.join()
            self._worker = None
        self._raise_error()

    def __enter__(self) -> ScanPoster:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    def _send(self, ticks: Sequence[Sequence[Scan]]) -> list[ScanAck]:
        """Send ``ticks`` in order, their scans together: each tick's clock declaration
        first (``declare_every_s``), then the scans in requests of up to ``max_batch``."""
        for tick in ticks:
            self._declare_clock(tick)
        scans = [scan for tick in ticks for scan in tick]
        acks: list[ScanAck] = []
        for start in range(0, len(scans), self.max_batch):
            acks += self.client.post_scans(scans[start : start + self.max_batch])
        return acks

    def _declare_clock(self, scans: Sequence[Scan]) -> None:
        """Declare the newest stamp of ``scans`` as the simulation's clock when it is
        ``declare_every_s`` past the last declaration; stop on a server that refuses."""
        if self.declare_every_s is None or not scans:
            return
        now = max(scan.stamp for scan in scans)
        if self.declared is not None and now - self.declared < self.declare_every_s:
            return
        try:
            self.client.declare_clock(now)
        except MapRequestError as exc:
            if exc.status not in (403, 404, 405):
                raise
            logger.info("the map server does not take the clock's declaration: %s", exc)
            self.declare_every_s = None
            return
        self.declared = now

    def _run(self) -> None:
        assert self._queue is not None
        while True:
            ticks = self._take_queued()
            try:
                batch = [tick for tick in ticks if tick is not None]
                if self._error is None and batch:
                    acks = self._send(batch)
                    with self._lock:
                        self._acks += acks
                        self.posted += len(acks)
            except Exception as exc:  # raised to the caller by post, flush and close
                self._error = exc
            finally:
                for _ in ticks:
                    self._queue.task_done()
            if ticks[-1] is None:
                return

    def _take_queued(self) -> list[Sequence[Scan] | None]:
        """The next queued tick (waiting for one) and every tick queued behind it, up to
        the stop (None): the ticks that piled up while the last request was on its way
        go out together, in order, in requests of up to ``max_batch`` scans."""
        assert self._queue is not None
        ticks = [self._queue.get()]
        while ticks[-1] is not None:
            try:
                ticks.append(self._queue.get_nowait())
            except queue.Empty:
                break
        return ticks

    def _take_acks(self) -> list[ScanAck]:
        with self._lock:
            acks, self._acks = self._acks, []
        return acks

    def _raise_error(self) -> None:
        if self._error is not None:
            raise self._error
