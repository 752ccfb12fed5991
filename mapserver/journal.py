"""The map server's durable journal: every accepted scan, in order, plus grid snapshots.

One SQLite database file (stdlib ``sqlite3``) in WAL mode holds:

- ``scans``: one row per accepted scan, ``seq`` (INTEGER PRIMARY KEY AUTOINCREMENT: 1, 2,
  3, ... never reused), ``unit_id``, ``stamp`` [s] and ``body``, the scan's CONTRACT 2.1
  object as compact JSON text (Python's ``json``; a no-return range is written
  ``Infinity``, which the contract accepts as input and ``json.loads`` reads back). The
  journal is the replay log: replaying it in ``seq`` order rebuilds the map bit for bit.
- ``units``: the largest stamp journaled per unit, so a restarted server still rejects a
  stamp that goes backwards (409) without reading every scan.
- ``snapshots``: the grid's arrays as of a ``seq`` (``np.savez_compressed`` bytes), only
  the newest ``keep_snapshots`` kept. Start-up = newest snapshot + the scans after it.

Durability. ``append`` commits its batch in one transaction before it returns, so once it
returns the caller may acknowledge the scans (reply 200). What that survives depends on
``synchronous`` (SQLite, "PRAGMA synchronous", https://www.sqlite.org/pragma.html#pragma_synchronous,
and "Write-Ahead Logging", https://www.sqlite.org/wal.html):

- A crash of this process (exception, ``SIGKILL``, OOM kill) loses nothing that was
  acknowledged, whatever ``synchronous`` is: a WAL commit has written its frames to the
  operating system before ``COMMIT`` returns, and the next open replays them from the
  ``-wal`` file. SQLite: "Transactions are durable across application crashes regardless
  of the synchronous setting or journal mode."
- A crash of the operating system or a power loss: with ``FULL`` (the default) the WAL is
  fsynced at every commit, so every acknowledged scan survives (provided the storage
  honours fsync). With ``NORMAL`` the WAL is fsynced only at checkpoints: the database
  stays consistent but the most recent acknowledged scans may be lost ("A transaction
  committed in WAL mode with synchronous=NORMAL might roll back following a power loss or
  system crash"). With ``OFF`` nothing is fsynced: recent scans may be lost and the
  database file may be corrupted.

Each commit under ``FULL`` costs an fsync, so a writer should group the scans that
arrived meanwhile into one ``append`` call (group commit) rather than commit one by one.

Threads. A ``Journal`` holds one connection (opened with ``check_same_thread=False``)
guarded by a lock, so any thread may call it, one call at a time. A call waits for any
other call on the same instance, including an ``append`` waiting on its fsync; a reader
that must not wait behind the writer opens its own instance (``readonly=True``): WAL lets
any number of readers run beside the one writer, each seeing the last committed state.
SQLite admits one writing transaction at a time across connections; a second writer
waits up to ``busy_timeout`` [s] (e.g. a snapshot saved from another thread's instance).
``scans_after`` reads in pages of ``page_size`` rows, each page under the lock, and yields
outside it, so a consumer may call other methods while iterating.

One writable journal per data directory: two servers appending to one file would each
check unit stamps against their own view. Keeping them apart is the server's job.

The schema is versioned with ``PRAGMA user_version`` (``SCHEMA_VERSION``) and the file
marked as a fleetmap journal with ``PRAGMA application_id``; opening another file or
another schema version raises ``JournalError`` naming the path and both versions.
"""

from __future__ import annotations

import io
import json
import math
import os
import sqlite3
import threading
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

SCHEMA_VERSION = 2
APPLICATION_ID = 0x464D4A31  # "FMJ1": marks the file as a fleetmap journal
JOURNAL_FILENAME = "journal.sqlite3"  # the journal's name inside a server data directory
SYNCHRONOUS_MODES = ("FULL", "NORMAL", "OFF")
Synchronous = Literal["FULL", "NORMAL", "OFF"]

_SCHEMA = """
CREATE TABLE scans (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    unit_id TEXT NOT NULL,
    stamp REAL NOT NULL,
    body TEXT NOT NULL,
    ranges BLOB NOT NULL
);
CREATE TABLE units (
    unit_id TEXT PRIMARY KEY,
    stamp REAL NOT NULL
) WITHOUT ROWID;
CREATE TABLE snapshots (
    seq INTEGER PRIMARY KEY,
    stamp REAL NOT NULL,
    version INTEGER NOT NULL,
    arrays BLOB NOT NULL
);
"""
_INSERT_SCAN = "INSERT INTO scans (unit_id, stamp, body, ranges) VALUES (?, ?, ?, ?)"
_UPSERT_UNIT = (
    "INSERT INTO units (unit_id, stamp) VALUES (?, ?) "
    "ON CONFLICT (unit_id) DO UPDATE SET stamp = max(stamp, excluded.stamp)"
)


class JournalError(RuntimeError):
    """The journal file cannot be opened or used; the message names the path and why."""


@dataclass(frozen=True)
class Snapshot:
    """The grid's state as of journal ``seq``: every scan with ``seq' <= seq`` is in it.

    seq: the last journaled scan the arrays include (0: none).
    stamp: [s] the map's "now" at that point (the latest fused stamp).
    version: the map version at that point.
    arrays: named arrays as saved (dtype and shape preserved).
    """

    seq: int
    stamp: float
    version: int
    arrays: dict[str, np.ndarray]


class Journal:
    """A durable, ordered log of accepted scans plus grid snapshots (module docstring).

    path: the database file; created (with its folder) unless ``readonly``.
    synchronous: ``FULL`` (default), ``NORMAL`` or ``OFF``: what survives a power loss.
    readonly: open an existing journal for reading only (replay, a second reader).
    keep_snapshots: how many of the newest snapshots ``save_snapshot`` keeps (>= 1).
    busy_timeout: [s] how long a write waits for another connection's write lock.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        synchronous: Synchronous | str = "FULL",
        *,
        readonly: bool = False,
        keep_snapshots: int = 2,
        busy_timeout: float = 5.0,
    ) -> None:
        mode = str(synchronous).upper()
        if mode not in SYNCHRONOUS_MODES:
            raise ValueError(f"synchronous must be one of FULL, NORMAL, OFF, got {synchronous!r}")
        if isinstance(keep_snapshots, bool) or not isinstance(keep_snapshots, int):
            raise ValueError(f"keep_snapshots must be an integer >= 1, got {keep_snapshots!r}")
        if keep_snapshots < 1:
            raise ValueError(f"keep_snapshots must be an integer >= 1, got {keep_snapshots!r}")
        if not (math.isfinite(busy_timeout) and busy_timeout >= 0):
            raise ValueError(f"busy_timeout must be >= 0 seconds, got {busy_timeout!r}")
        self.path = Path(path)
        self.synchronous = mode
        self.readonly = readonly
        self.keep_snapshots = keep_snapshots
        self._lock = threading.Lock()
        self._conn = self._connect(busy_timeout)

    # ------------------------------------------------------------------ opening
    def _connect(self, busy_timeout: float) -> sqlite3.Connection:
        if self.readonly:
            if not self.path.is_file():
                raise JournalError(f"{self.path}: no journal file there")
            target, uri = f"{self.path.resolve().as_uri()}?mode=ro", True
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            target, uri = str(self.path), False
        try:
            conn = sqlite3.connect(
                target,
                uri=uri,
                timeout=busy_timeout,
                isolation_level=None,  # autocommit: transactions are explicit BEGIN/COMMIT
                check_same_thread=False,  # guarded by self._lock (module docstring)
            )
        except sqlite3.Error as exc:
            raise JournalError(f"{self.path}: cannot open the journal: {exc}") from exc
        try:
            self._prepare(conn)
        except BaseException:
            conn.close()
            raise
        return conn

    def _prepare(self, conn: sqlite3.Connection) -> None:
        """Check (or, for a new writable file, create) the schema; set the pragmas."""
        try:
            app_id = conn.execute("PRAGMA application_id").fetchone()[0]
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            tables = conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        except sqlite3.DatabaseError as exc:
            raise JournalError(f"{self.path}: not a fleetmap journal ({exc})") from exc
        if tables == 0 and app_id == 0 and version == 0:
            if self.readonly:
                raise JournalError(f"{self.path}: the journal is empty (no schema)")
            self._create_schema(conn)
        elif app_id != APPLICATION_ID:
            raise JournalError(
                f"{self.path}: not a fleetmap journal "
                f"(application_id {app_id:#x}, expected {APPLICATION_ID:#x})"
            )
        elif version != SCHEMA_VERSION:
            raise JournalError(
                f"{self.path}: journal schema version {version}, but this fleetmap reads "
                f"version {SCHEMA_VERSION}; use the fleetmap release that wrote it, or start "
                "a new data directory"
            )
        if self.readonly:
            conn.execute("PRAGMA query_only = ON")
            return
        mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
        if str(mode).lower() != "wal":
            raise JournalError(f"{self.path}: cannot switch to WAL mode, got journal_mode {mode}")
        conn.execute(f"PRAGMA synchronous = {self.synchronous}")

    @staticmethod
    def _create_schema(conn: sqlite3.Connection) -> None:
        conn.execute("BEGIN IMMEDIATE")
        try:
            for statement in _SCHEMA.split(";"):
                if statement.strip():
                    conn.execute(statement)
            conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            conn.execute("COMMIT")
        except BaseException:
            if conn.in_transaction:
                conn.execute("ROLLBACK")
            raise

    def close(self) -> None:
        """Close the connection (idempotent); the last close checkpoints the WAL."""
        with self._lock:
            if self._conn is not None:
                self._conn.close()
                self._conn = None

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _db(self) -> sqlite3.Connection:
        if self._conn is None:
            raise JournalError(f"{self.path}: the journal is closed")
        return self._conn

    def _write(self, statements: Sequence[tuple[str, Sequence[Any]]]) -> list[Any]:
        """Run ``statements`` in one committed transaction; returns each one's lastrowid."""
        if self.readonly:
            raise JournalError(f"{self.path}: the journal is open read-only")
        with self._lock:
            db = self._db()
            db.execute("BEGIN IMMEDIATE")
            try:
                rowids = [db.execute(sql, params).lastrowid for sql, params in statements]
                db.execute("COMMIT")
            except BaseException:
                if db.in_transaction:
                    db.execute("ROLLBACK")
                raise
        return rowids

    def _read(self, sql: str, params: Sequence[Any] = ()) -> list[tuple[Any, ...]]:
        with self._lock:
            return self._db().execute(sql, params).fetchall()

    # ------------------------------------------------------------------ scans
    def append(self, scans: Sequence[Mapping[str, Any]]) -> list[int]:
        """Journal accepted scans in order, committed before returning; returns their seqs.

        scans: CONTRACT 2.1 scan objects already accepted by ``Scan.from_dict`` (the
            journal reads ``unit_id`` and ``stamp`` [s]; it stores the other fields as JSON
            and ``ranges`` as float64 bytes, null as NaN: encoding 1080 floats as text
            cost more than fusing them).
        Returns the new seqs, consecutive and increasing, one per scan. All scans are
        written or none: on any error nothing is journaled. What survives a crash once
        this returns is in the module docstring.
        """
        statements: list[tuple[str, Sequence[Any]]] = []
        for i, scan in enumerate(scans):
            unit_id, stamp = _unit_and_stamp(scan, i)
            header = {k: v for k, v in scan.items() if k != "ranges"}
            ranges = np.asarray(scan.get("ranges", ()), dtype="<f8").tobytes()
            body = json.dumps(header, separators=(",", ":"))
            statements.append((_INSERT_SCAN, (unit_id, stamp, body, ranges)))
            statements.append((_UPSERT_UNIT, (unit_id, stamp)))
        if not statements:
            return []
        return self._write(statements)[::2]

    def scans_after(
        self, seq: int = 0, until_stamp: float | None = None, page_size: int = 512
    ) -> Iterator[tuple[int, dict[str, Any]]]:
        """Yield ``(seq, scan)`` for every journaled scan with a larger seq, in seq order.

        seq: yield scans after this one (0: from the first).
        until_stamp: [s] when given, only scans whose stamp is <= this (scans of
            different units interleave in seq order, so later ones are skipped, not a stop).
        page_size: rows read per query; scans appended while iterating are yielded too.
        """
        if page_size < 1:
            raise ValueError(f"page_size must be >= 1, got {page_size!r}")
        where, params = "seq > ?", []
        if until_stamp is not None:
            where, params = "seq > ? AND stamp <= ?", [float(until_stamp)]
        sql = f"SELECT seq, body, ranges FROM scans WHERE {where} ORDER BY seq LIMIT ?"
        last = int(seq)
        while True:
            rows = self._read(sql, [last, *params, page_size])
            for row_seq, body, ranges in rows:
                yield row_seq, _decode_scan(body, ranges)
            if len(rows) < page_size:
                return
            last = rows[-1][0]

    def find_scan(self, unit_id: str, stamp: float) -> tuple[int, dict[str, Any]] | None:
        """The newest journaled ``(seq, scan)`` of ``unit_id`` at ``stamp`` [s], or None
        (a full table scan: for the rare retry the server has not seen itself)."""
        rows = self._read(
            "SELECT seq, body, ranges FROM scans WHERE unit_id = ? AND stamp = ? "
            "ORDER BY seq DESC LIMIT 1",
            (unit_id, float(stamp)),
        )
        if not rows:
            return None
        seq, body, ranges = rows[0]
        return int(seq), _decode_scan(body, ranges)

    def last_seq(self) -> int:
        """The seq of the newest journaled scan (0 when there is none)."""
        return int(self._read("SELECT coalesce(max(seq), 0) FROM scans")[0][0])

    def count(self) -> int:
        """Number of journaled scans (a full count: O(scans); prefer ``last_seq`` on hot paths)."""
        return int(self._read("SELECT count(*) FROM scans")[0][0])

    def unit_stamps(self) -> dict[str, float]:
        """The largest journaled stamp [s] of every unit, the bound for its next scan."""
        return {
            unit: float(stamp) for unit, stamp in self._read("SELECT unit_id, stamp FROM units")
        }

    def size_bytes(self) -> int:
        """Bytes on disk of the database file plus its ``-wal`` file."""
        total = 0
        for suffix in ("", "-wal"):
            try:
                total += os.path.getsize(f"{self.path}{suffix}")
            except FileNotFoundError:
                pass
        return total

    # ------------------------------------------------------------------ snapshots
    def save_snapshot(
        self, seq: int, stamp: float, version: int, arrays: Mapping[str, np.ndarray]
    ) -> None:
        """Store the grid's arrays as of journal ``seq``; keep only the newest snapshots.

        seq: the last journaled scan the arrays include (0 <= seq <= last_seq()).
        stamp: [s] the map's "now" then. version: the map version then.
        arrays: named arrays (names as accepted by ``np.savez``), stored compressed.
        A second snapshot at the same seq replaces the first. Compression runs before the
        lock is taken, so a large grid does not hold up other calls on this instance.
        """
        if isinstance(seq, bool) or not isinstance(seq, int | np.integer) or seq < 0:
            raise ValueError(f"seq must be an integer >= 0, got {seq!r}")
        if not arrays:
            raise ValueError("arrays must hold at least one array, got none")
        blob = encode_arrays(arrays)
        newest = self.last_seq()
        if seq > newest:
            raise ValueError(f"seq must not be beyond the journal's last seq ({newest}), got {seq}")
        self._write(
            [
                (
                    "INSERT OR REPLACE INTO snapshots (seq, stamp, version, arrays) "
                    "VALUES (?, ?, ?, ?)",
                    (int(seq), float(stamp), int(version), blob),
                ),
                (
                    "DELETE FROM snapshots WHERE seq NOT IN "
                    "(SELECT seq FROM snapshots ORDER BY seq DESC LIMIT ?)",
                    (self.keep_snapshots,),
                ),
            ]
        )

    def latest_snapshot(self) -> Snapshot | None:
        """The snapshot with the largest seq, or None when there is none."""
        rows = self._read(
            "SELECT seq, stamp, version, arrays FROM snapshots ORDER BY seq DESC LIMIT 1"
        )
        if not rows:
            return None
        seq, stamp, version, blob = rows[0]
        return Snapshot(int(seq), float(stamp), int(version), decode_arrays(blob))

    def snapshot_seqs(self) -> list[int]:
        """Seqs of the stored snapshots, oldest first."""
        return [int(row[0]) for row in self._read("SELECT seq FROM snapshots ORDER BY seq")]


def encode_arrays(arrays: Mapping[str, np.ndarray]) -> bytes:
    """``np.savez`` bytes of named arrays (no pickled objects). Uncompressed: zlib on a
    4 M-cell grid costs about a second of CPU that the fleet's scans need more."""
    buffer = io.BytesIO()
    for name, array in arrays.items():
        if np.asarray(array).dtype == object:
            raise ValueError(f"arrays[{name!r}] must be a numeric array, got dtype object")
    np.savez(buffer, allow_pickle=False, **{k: np.asarray(v) for k, v in arrays.items()})
    return buffer.getvalue()


def decode_arrays(blob: bytes) -> dict[str, np.ndarray]:
    """The named arrays of ``encode_arrays`` bytes."""
    with np.load(io.BytesIO(blob), allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def journal_path(data_dir: str | os.PathLike[str]) -> Path:
    """The journal file of a server data directory."""
    return Path(data_dir) / JOURNAL_FILENAME


def open_journal_for_replay(path: str | os.PathLike[str]) -> Journal:
    """Open a journal read-only: ``path`` is a journal file or a server data directory."""
    target = Path(path)
    if target.is_dir():
        target = journal_path(target)
    if not target.is_file():
        raise JournalError(f"{path}: neither a journal file nor a data directory holding one")
    return Journal(target, readonly=True)


def _decode_scan(body: str, ranges: bytes) -> dict[str, Any]:
    """A journaled scan object from its stored header JSON and float64 ranges bytes."""
    scan = json.loads(body)
    values = np.frombuffer(ranges, dtype="<f8").tolist()
    scan["ranges"] = [None if math.isnan(r) else r for r in values]
    return scan


def _unit_and_stamp(scan: Mapping[str, Any], index: int) -> tuple[str, float]:
    """The ``unit_id`` and finite ``stamp`` [s] of scan number ``index`` of a batch."""
    if not isinstance(scan, Mapping):
        raise ValueError(f"scans[{index}] must be a scan object, got {type(scan).__name__}")
    unit_id, stamp = scan.get("unit_id"), scan.get("stamp")
    if not isinstance(unit_id, str) or not unit_id:
        raise ValueError(f"scans[{index}].unit_id must be a non-empty string, got {unit_id!r}")
    if isinstance(stamp, bool) or not isinstance(stamp, int | float) or not math.isfinite(stamp):
        raise ValueError(f"scans[{index}].stamp must be a finite number, got {stamp!r}")
    return unit_id, float(stamp)
