"""The map in a process of its own: ``MapProcess(settings)`` runs a ``MapService`` (gate,
journal, fusion, costmap) in a child process and offers the HTTP front the same calls.

Why: in one process the event loop (HTTP, parsing, answers), the journal and fusion share
one GIL, and a server uses about 1.1-1.2 cores however hard it is pushed
(docs/scaling.md). With ``server.map_process: true`` the front process keeps the event
loop, the guards, the ingest budgets, the unit board and the planner; the child keeps
everything the map is, unchanged: the one writer of the data dir, the journal order, and
every durability promise (an ack is sent only after the child journaled and fused its
scan).

The wire is one ``multiprocessing`` pipe, pickled messages both ways:

- front -> child: a list of ``(call_id, name, args)``, ``name`` one of ``CALLS`` (the
  calls of one turn of the front's event loop in one write);
- child -> front: a list of ``(call_id, ok, value)``, several answers per write (the
  fusion thread answers a whole group at once; a sender thread drains them in one write).

A submission (``submit``) is queued at once in the child's ``MapService``; reads run on a
small pool of the child's threads, so a slow read never holds up the scans behind it.

Lifetimes: ``close()`` asks the child to stop after what is queued (its ``MapService``
journals and fuses it) and waits for it. When the front dies (even killed), the child
reads the end of the pipe and closes its ``MapService`` the same way. When the child dies,
every waiting call and every later one fails with ``MapProcessError`` (a 503 for scans)
and ``fleetmap serve`` stops (SIGTERM to itself), so a supervisor restarts the pair.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import multiprocessing
import pickle
import queue
import signal
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from mapserver.core.geometry import GridGeometry
from mapserver.service.ingest_stages import Histogram
from mapserver.service.map_clock import ClockView
from mapserver.service.map_service import GridRead, MapService, take_waiting
from mapserver.service.scan_gate import IngestError
from mapserver.service.settings import Settings

logger = logging.getLogger(__name__)

CALLS = frozenset(
    {
        "submit",
        "meta",
        "costmap_read",
        "occupancy_read",
        "age_read",
        "updates_since",
        "cell_columns",
        "segments",
        "journal_bytes",
        "snapshot",
        "counters",
        "stages",
        "group_sizes",
        "clock_view",
        "declare_clock",
    }
)
"""What the front may ask of the child's ``MapService`` (see ``_run_call``)."""

SWITCH_INTERVAL_S = 0.0005
"""[s] the child's GIL switch interval: its ingest, fusion and snapshot threads hand the
GIL over promptly (Python's default, 5 ms, would add that much to an ack's wait)."""

READ_THREADS = 4  # the child's threads for reads (queries, plans' costmaps, metrics)


class MapProcessError(IngestError):
    """The map process is gone (it crashed, or the server is shutting down): 503."""

    def __init__(self, detail: str) -> None:
        super().__init__(503, detail)

    def __reduce__(self) -> tuple[Any, ...]:
        return (MapProcessError, (self.detail,))


def open_map_service(
    settings: Settings, on_lost: Callable[[], None] | None = None
) -> MapService | MapProcess:
    """The map of ``settings``: in this process, or in a child when
    ``server.map_process`` is set (``on_lost``: see ``MapProcess``)."""
    if settings.server.map_process:
        return MapProcess(settings, on_lost)
    return MapService(settings)


class MapProcess:
    """A ``MapService`` run in a child process, with the calls the HTTP front makes of one.
    Raises what ``MapService(settings)`` raises (``DataDirError``, ``JournalError``) when
    the child cannot open the map. ``on_lost`` is called (on a thread of this class) when
    the child ends without being asked to; ``fleetmap serve`` then stops serving."""

    def __init__(self, settings: Settings, on_lost: Callable[[], None] | None = None) -> None:
        self.settings = settings
        self._on_lost = on_lost
        self.geometry: GridGeometry = settings.geometry()
        context = multiprocessing.get_context("spawn")  # no threads or locks inherited
        self._conn, child_end = context.Pipe(duplex=True)
        self._process = context.Process(
            target=run_child, args=(child_end, settings), name="fleetmap-map", daemon=True
        )
        self._process.start()
        child_end.close()
        try:
            kind, payload = self._conn.recv()
        except EOFError:
            self._process.join()
            raise MapProcessError(
                f"the map process exited with code {self._process.exitcode} while opening "
                f"the map of {settings.data_dir}"
            ) from None
        if kind == "error":
            self._process.join()
            raise payload
        self.planning_bounds = payload["planning_bounds"]
        self.clock = _RemoteClock(self)
        self.stages = _RemoteStages(self)
        self.journal = _RemoteJournal(self)
        self._pending: dict[int, Future] = {}
        self._ids = itertools.count()
        self._send_lock = threading.Lock()
        self._outbox: list[tuple[int, str, tuple]] = []  # calls not sent yet
        self._flush_scheduled = False
        self._closing = False
        self._gone: str | None = None  # why calls fail, once the child is gone
        self._receiver = threading.Thread(
            target=self._receive, name="map-process-replies", daemon=True
        )
        self._receiver.start()

    @property
    def pid(self) -> int | None:
        """The child's process id."""
        return self._process.pid

    # ------------------------------------------------------------------ the wire
    def call(self, name: str, *args: Any, batched: bool = False) -> Future:
        """Ask the child for ``name(*args)``; the future gives its value or raises.
        ``batched`` calls made on an event loop's thread go out together at the loop's
        next turn (one write for all the scans one turn read); other calls go at once
        (a caller may block on the answer)."""
        future: Future = Future()
        loop = _running_loop() if batched else None
        with self._send_lock:
            if self._gone is not None:
                future.set_exception(MapProcessError(self._gone))
                return future
            call_id = next(self._ids)
            self._pending[call_id] = future
            self._outbox.append((call_id, name, args))
            if loop is None:
                self._flush_locked()
                return future
            if self._flush_scheduled:
                return future
            self._flush_scheduled = True
        loop.call_soon(self._flush)
        return future

    def _flush(self) -> None:
        with self._send_lock:
            self._flush_scheduled = False
            self._flush_locked()

    def _flush_locked(self) -> None:
        """Send the calls waiting in the outbox in one write (the send lock held)."""
        calls, self._outbox = self._outbox, []
        if not calls:
            return
        try:
            self._conn.send(calls)
        except (OSError, ValueError) as exc:  # the child is gone: the receiver says why
            for call_id, _, _ in calls:
                future = self._pending.pop(call_id, None)
                if future is not None:
                    future.set_exception(MapProcessError(f"the map process is gone: {exc}"))

    def _ask(self, name: str, *args: Any) -> Any:
        return self.call(name, *args).result()

    def _receive(self) -> None:
        """Thread ``map-process-replies``: settle each answer's future; at the end of the
        pipe, fail what still waits and, unless closing, stop the server."""
        while True:
            try:
                answers = self._conn.recv()
            except (EOFError, OSError):
                break
            for call_id, ok, value in answers:
                future = self._pending.pop(call_id, None)
                if future is None:
                    continue
                if ok:
                    future.set_result(value)
                else:
                    future.set_exception(value)
        with self._send_lock:
            self._gone = (
                "the map server is shutting down"
                if self._closing
                else "the map process ended unexpectedly (a server fault, logged)"
            )
            pending, self._pending = self._pending, {}
        for future in pending.values():
            future.set_exception(MapProcessError(self._gone))
        if not self._closing:
            self._process.join(timeout=5.0)
            logger.error("the map process (pid %s) ended with code %s",
                         self._process.pid, self._process.exitcode)  # fmt: skip
            if self._on_lost is not None:
                self._on_lost()

    # -------------------------------------------------------------- the service
    def submit(self, scans: list) -> Future:
        return self.call("submit", scans, batched=True)

    def ingest(self, scans: list) -> list:
        return self.submit(scans).result()

    def meta(self) -> dict[str, Any]:
        return self._ask("meta")

    def costmap_read(self, at: float | None = None) -> GridRead:
        return self._ask("costmap_read", at)

    def occupancy_read(self, at: float | None = None) -> GridRead:
        return self._ask("occupancy_read", at)

    def age_read(self, at: float | None = None) -> GridRead:
        return self._ask("age_read", at)

    def updates_since(self, version: int) -> tuple:
        return self._ask("updates_since", version)

    def cell_columns(self, points: Any, at: float | None = None) -> dict[str, list]:
        return self._ask("cell_columns", points, at)

    def segments(self, segments: list[list[float]]) -> list:
        return self._ask("segments", segments)

    def journal_bytes(self) -> int:
        return self._ask("journal_bytes")

    def snapshot(self) -> int:
        return self._ask("snapshot")

    @property
    def version(self) -> int:
        return self._ask("counters")["version"]

    @property
    def fusion_seconds(self) -> float:
        return self._ask("counters")["fusion_seconds"]

    @property
    def snapshot_failures(self) -> int:
        return self._ask("counters")["snapshot_failures"]

    def close(self) -> None:
        """Stop the child after what it has queued (journaled and fused) and wait for it."""
        with self._send_lock:
            if self._closing:
                return
            self._closing = True
            if self._gone is None:
                try:
                    self._flush_locked()
                    self._conn.send([(None, "close", ())])
                except (OSError, ValueError):
                    pass
        self._process.join()
        self._receiver.join()
        self._conn.close()


class _RemoteClock:
    """The child's ``MapClock``, as ``routes_clock`` uses it."""

    def __init__(self, process: MapProcess) -> None:
        self._process = process

    def view(self) -> ClockView:
        return self._process._ask("clock_view")

    def declare(self, now: float) -> None:
        self._process._ask("declare_clock", now)


class _RemoteStages:
    """The child's ``IngestStages``, as ``metrics`` reads them."""

    def __init__(self, process: MapProcess) -> None:
        self._process = process

    def stages(self) -> dict[str, Histogram]:
        return self._process._ask("stages")

    def group_sizes(self) -> Histogram:
        return self._process._ask("group_sizes")


class _RemoteJournal:
    """The child's journal's counters, as ``metrics`` reads them."""

    def __init__(self, process: MapProcess) -> None:
        self._process = process

    @property
    def quarantined(self) -> int:
        return self._process._ask("counters")["quarantined"]


def _running_loop() -> asyncio.AbstractEventLoop | None:
    try:
        return asyncio.get_running_loop()
    except RuntimeError:
        return None


# ---------------------------------------------------------------------- the child
def _run_call(service: MapService, name: str, args: tuple) -> Any:
    """What the name of a read in ``CALLS`` does on the child's service."""
    if name == "counters":
        return {
            "version": service.version,
            "fusion_seconds": service.fusion_seconds,
            "snapshot_failures": service.snapshot_failures,
            "quarantined": service.journal.quarantined,
        }
    if name == "stages":
        return service.stages.stages()
    if name == "group_sizes":
        return service.stages.group_sizes()
    if name == "clock_view":
        return service.clock.view()
    if name == "declare_clock":
        return service.clock.declare(*args)
    return getattr(service, name)(*args)


class _Answers:
    """The child's answers to the front: queued by any thread, written by one sender
    thread, as many as are waiting in one write."""

    def __init__(self, conn: Any) -> None:
        self._conn = conn
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._sender = threading.Thread(target=self._send, name="map-answers", daemon=True)
        self._sender.start()

    def put(self, call_id: int, ok: bool, value: Any) -> None:
        self._queue.put((call_id, ok, value))

    def settle(self, call_id: int, future: Future) -> None:
        """A done future's value or exception, as the answer to ``call_id``."""
        exc = future.exception()
        self.put(call_id, exc is None, future.result() if exc is None else _portable(exc))

    def run(self, call_id: int, service: MapService, name: str, args: tuple) -> None:
        """Answer ``call_id`` with the read ``name(*args)`` (``_run_call``)."""
        try:
            value = _run_call(service, name, args)
        except Exception as exc:
            self.put(call_id, False, _portable(exc))
        else:
            self.put(call_id, True, value)

    def close(self) -> None:
        """Send what is queued, then stop the sender."""
        self._queue.put(None)
        self._sender.join()

    def _send(self) -> None:
        while True:
            batch, stop = take_waiting(self._queue, lambda _: 1)
            if batch:
                try:
                    self._conn.send(batch)
                except (OSError, ValueError):  # the front is gone
                    return
            if stop:
                return


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError saying what it was."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


def _dispatch(
    calls: list[tuple[int, str, tuple]],
    service: MapService,
    answers: _Answers,
    reads: ThreadPoolExecutor,
) -> bool:
    """Start each of ``calls`` (one write of the front); False when one says ``close``.
    A submission is queued at once (in order); a read goes to the read threads."""
    for call_id, name, args in calls:
        if name == "close":
            return False
        if name not in CALLS:
            answers.put(call_id, False, ValueError(f"map process: no call {name!r}"))
        elif name == "submit":
            service.submit(*args).add_done_callback(
                lambda future, call_id=call_id: answers.settle(call_id, future)
            )
        else:
            reads.submit(answers.run, call_id, service, name, args)
    return True


def run_child(conn: Any, settings: Settings) -> None:
    """The child's main: open the map, answer the front until it says ``close`` or its
    end of the pipe closes, then close the map (what is queued is journaled and fused)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the group: the front decides
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        service = MapService(settings)
    except Exception as exc:
        conn.send(("error", _portable(exc)))
        conn.close()
        return
    conn.send(("ready", {"planning_bounds": service.planning_bounds}))
    answers = _Answers(conn)
    reads = ThreadPoolExecutor(READ_THREADS, thread_name_prefix="map-read")
    try:
        while True:
            try:
                calls = conn.recv()
            except (EOFError, OSError):
                break
            if not _dispatch(calls, service, answers, reads):
                break
    finally:
        reads.shutdown(wait=True)
        service.close()
        answers.close()
        conn.close()
