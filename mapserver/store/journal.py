"""The map server's durable journal: every accepted scan, in order, plus grid snapshots.

One SQLite database file (stdlib ``sqlite3``) in WAL mode holds:

- ``scans``: one row per accepted scan, ``seq`` (INTEGER PRIMARY KEY AUTOINCREMENT: 1, 2,
  3, ... never reused), ``unit_id``, ``stamp`` [s] and ``body``, the scan's docs/http-api.md 2.1
  object as compact JSON text (Python's ``json``; a no-return range is written
  ``Infinity``, which the contract accepts as input and ``json.loads`` reads back). The
  journal is the replay log: replaying it in ``seq`` order rebuilds the map bit for bit.
- ``units``: the largest stamp journaled per unit, so a restarted server still rejects a
  stamp that goes backwards (409) without reading every scan.
- ``snapshots``: the grid's arrays as of a ``seq`` (``np.savez`` bytes), only the newest
  ``keep_snapshots`` kept. Start-up = newest usable snapshot + the scans after it.
- ``quarantine``: records taken out of ``scans`` (a checksum that fails, a body that does
  not parse, a scan the server refuses, an admin's drop), kept with their original bytes,
  their seq and the reason, never replayed.

Integrity. Every scan row carries ``checksum``, a CRC-32 (``zlib.crc32``) over its
unit_id, stamp, body and ranges bytes (``record_checksum``), and every snapshot one over
its seq, stamp, version and arrays (``snapshot_checksum``); both are checked on every
read. CRC-32 detects every error of up to 32 consecutive bits, so any one flipped byte.
A row whose checksum is NULL (none recorded) is read unchecked. ``records_after`` yields
each row as a ``Record`` that says what is wrong with it instead of raising, so a reader
can quarantine one bad record and go on.

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
another schema version raises ``JournalError`` naming the path and both versions. A
version-2 journal (no checksums, no quarantine) is migrated in place by a writable open,
in one transaction (checksums computed for the rows it holds); a read-only open reads it
as it is, unchecked.
"""

from __future__ import annotations

import io
import json
import logging
import math
import os
import sqlite3
import struct
import threading
import time
import zipfile
import zlib
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from mapserver.core.errors import FleetmapError
from mapserver.core.text import quote

logger = logging.getLogger(__name__)

SCHEMA_VERSION = 3
UNCHECKED_VERSION = 2  # the previous schema: no checksums; migrated or read unchecked
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
# Version 3 over version 2: a new file runs both, a migration this one (same schema).
_SCHEMA_V3 = """
ALTER TABLE scans ADD COLUMN checksum INTEGER;
ALTER TABLE snapshots ADD COLUMN checksum INTEGER;
CREATE TABLE quarantine (
    seq INTEGER PRIMARY KEY,
    unit_id BLOB,
    stamp REAL,
    body BLOB,
    ranges BLOB,
    checksum INTEGER,
    reason TEXT NOT NULL,
    quarantined_at REAL NOT NULL
);
"""
_FILL_CHECKSUMS = (
    "UPDATE scans SET checksum = fleetmap_record_checksum("
    "CAST(unit_id AS BLOB), stamp, CAST(body AS BLOB), ranges)",
    "UPDATE snapshots SET checksum = fleetmap_snapshot_checksum(seq, stamp, version, arrays)",
)
# A scan row as bytes: a damaged TEXT value must not fail to decode while it is read.
_RAW_COLUMNS = "seq, CAST(unit_id AS BLOB), stamp, CAST(body AS BLOB), ranges"
_INSERT_SCAN = "INSERT INTO scans (unit_id, stamp, body, ranges, checksum) VALUES (?, ?, ?, ?, ?)"
_IMPORT_SCAN = (
    "INSERT INTO scans (seq, unit_id, stamp, body, ranges, checksum) VALUES (?, ?, ?, ?, ?, ?)"
)
_IMPORT_QUARANTINED = (
    "INSERT OR REPLACE INTO quarantine "
    "(seq, unit_id, stamp, body, ranges, checksum, reason, quarantined_at) "
    "VALUES (?, ?, ?, ?, ?, ?, ?, ?)"
)
_UPSERT_UNIT = (
    "INSERT INTO units (unit_id, stamp) VALUES (?, ?) "
    "ON CONFLICT (unit_id) DO UPDATE SET stamp = max(stamp, excluded.stamp)"
)


class JournalError(FleetmapError, RuntimeError):
    """The journal file cannot be opened or used; the message names the path and why."""


class RecordError(FleetmapError, ValueError):
    """One journal record is damaged: its checksum fails or its body does not parse."""


class SnapshotError(JournalError):
    """One snapshot is unusable: missing, its checksum fails, or it does not decode."""


@dataclass(frozen=True)
class RawRow:
    """A scan row as stored: ``unit_id`` and ``body`` as their bytes, ``stamp`` [s],
    ``ranges`` (float64 bytes) and ``checksum`` (None: not recorded, read unchecked)."""

    seq: int
    unit_id: bytes
    stamp: float
    body: bytes
    ranges: bytes
    checksum: int | None

    def computed_checksum(self) -> int:
        return record_checksum(self.unit_id, self.stamp, self.body, self.ranges)


@dataclass(frozen=True)
class Record:
    """One journaled scan as read: its ``seq``, ``unit_id`` (damaged bytes replaced),
    ``stamp`` [s], and either ``scan`` (the docs/http-api.md 2.1 object) or ``problem`` (why it
    cannot be read). ``checksum_ok``: True checked, False failed, None unchecked."""

    seq: int
    unit_id: str
    stamp: float
    scan: dict[str, Any] | None
    problem: str | None
    checksum_ok: bool | None

    def body(self) -> dict[str, Any]:
        """The scan object; raises RecordError (the problem) for a damaged record."""
        if self.scan is None:
            raise RecordError(self.problem)
        return self.scan


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
        self.schema_version = SCHEMA_VERSION  # what the file holds (2: read unchecked)
        self._conn = self._connect(busy_timeout)
        self._checksum_column = "checksum" if self.schema_version >= 3 else "NULL"
        self.quarantined = self._count_quarantined()  # rows in quarantine, kept current

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
        conn.create_function("fleetmap_record_checksum", 4, record_checksum, deterministic=True)
        conn.create_function("fleetmap_snapshot_checksum", 4, snapshot_checksum, deterministic=True)
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
            raise JournalError(f"{self.path}: {_unreadable(self.path, exc)}") from exc
        if tables == 0 and app_id == 0 and version == 0:
            if self.readonly:
                raise JournalError(f"{self.path}: the journal is empty (no schema)")
            self._create_schema(conn)
        elif app_id != APPLICATION_ID:
            raise JournalError(
                f"{self.path}: not a fleetmap journal "
                f"(application_id {app_id:#x}, expected {APPLICATION_ID:#x})"
            )
        elif version == UNCHECKED_VERSION and self.readonly:
            self.schema_version = UNCHECKED_VERSION
        elif version == UNCHECKED_VERSION:
            self._migrate(conn)
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
        statements = [*_statements(_SCHEMA), *_statements(_SCHEMA_V3)]
        statements.append(f"PRAGMA application_id = {APPLICATION_ID}")
        _in_transaction(conn, [*statements, f"PRAGMA user_version = {SCHEMA_VERSION}"])

    def _migrate(self, conn: sqlite3.Connection) -> None:
        """Version 2 -> 3 in one transaction: the new columns and table, checksums for the
        rows there are (a row damaged before now is not detectable by its checksum)."""
        statements = [*_statements(_SCHEMA_V3), *_FILL_CHECKSUMS]
        _in_transaction(conn, [*statements, f"PRAGMA user_version = {SCHEMA_VERSION}"])
        rows = conn.execute("SELECT count(*) FROM scans").fetchone()[0]
        logger.info(
            "%s: journal migrated from schema 2 to 3 (%d scans checksummed)", self.path, rows
        )

    def _count_quarantined(self) -> int:
        if self.schema_version < 3:
            return 0
        return int(self._read("SELECT count(*) FROM quarantine")[0][0])

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

    def _write(self, statements: Sequence[tuple[str, Sequence[Any]]]) -> list[sqlite3.Cursor]:
        """Run ``statements`` in one committed transaction; returns each one's cursor
        (``lastrowid``, ``rowcount``)."""
        if self.readonly:
            raise JournalError(f"{self.path}: the journal is open read-only")
        with self._lock:
            db = self._db()
            db.execute("BEGIN IMMEDIATE")
            try:
                cursors = [db.execute(sql, params) for sql, params in statements]
                db.execute("COMMIT")
            except BaseException:
                if db.in_transaction:
                    db.execute("ROLLBACK")
                raise
        return cursors

    def _read(self, sql: str, params: Sequence[Any] = ()) -> list[tuple[Any, ...]]:
        with self._lock:
            try:
                return self._db().execute(sql, params).fetchall()
            except sqlite3.DatabaseError as exc:
                raise JournalError(f"{self.path}: {_unreadable(self.path, exc)}") from exc

    # ------------------------------------------------------------------ scans
    def append(self, scans: Sequence[Mapping[str, Any]]) -> list[int]:
        """Journal accepted scans in order, committed before returning; returns their seqs.

        scans: docs/http-api.md 2.1 scan objects already accepted by ``Scan.from_dict`` (the
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
            checksum = record_checksum(unit_id.encode(), stamp, body.encode(), ranges)
            statements.append((_INSERT_SCAN, (unit_id, stamp, body, ranges, checksum)))
            statements.append((_UPSERT_UNIT, (unit_id, stamp)))
        if not statements:
            return []
        return [cursor.lastrowid for cursor in self._write(statements)[::2]]

    def records_after(
        self, seq: int = 0, until_stamp: float | None = None, page_size: int = 512
    ) -> Iterator[Record]:
        """Yield every journaled scan with a larger seq as a ``Record``, in seq order; a
        damaged record is yielded with its ``problem``, not raised.

        seq: yield scans after this one (0: from the first).
        until_stamp: [s] when given, only scans whose stamp is <= this (scans of
            different units interleave in seq order, so later ones are skipped, not a stop).
        page_size: rows read per query; scans appended while iterating are yielded too.
        Raises JournalError when the file itself cannot be read (a damaged page).
        """
        if page_size < 1:
            raise ValueError(f"page_size must be >= 1, got {page_size!r}")
        where, params = "seq > ?", []
        if until_stamp is not None:
            where, params = "seq > ? AND stamp <= ?", [float(until_stamp)]
        sql = (
            f"SELECT {_RAW_COLUMNS}, {self._checksum_column} FROM scans "
            f"WHERE {where} ORDER BY seq LIMIT ?"
        )
        last = int(seq)
        while True:
            rows = self._read(sql, [last, *params, page_size])
            for row in rows:
                yield decode_row(RawRow(*row))
            if len(rows) < page_size:
                return
            last = rows[-1][0]

    def scans_after(
        self, seq: int = 0, until_stamp: float | None = None, page_size: int = 512
    ) -> Iterator[tuple[int, dict[str, Any]]]:
        """Yield ``(seq, scan)`` like ``records_after``, but raise JournalError on the
        first damaged record (for readers that must have every scan)."""
        for record in self.records_after(seq, until_stamp, page_size):
            if record.scan is None:
                raise JournalError(
                    f"{self.path}: seq {record.seq} (unit {quote(record.unit_id)}): "
                    f"{record.problem}"
                )
            yield record.seq, record.scan

    def find_scan(self, unit_id: str, stamp: float) -> tuple[int, dict[str, Any]] | None:
        """The newest intact journaled ``(seq, scan)`` of ``unit_id`` at ``stamp`` [s], or
        None (a full table scan: for the rare retry the server has not seen itself)."""
        rows = self._read(
            f"SELECT {_RAW_COLUMNS}, {self._checksum_column} FROM scans "
            "WHERE unit_id = ? AND stamp = ? ORDER BY seq DESC LIMIT 1",
            (unit_id, float(stamp)),
        )
        record = decode_row(RawRow(*rows[0])) if rows else None
        if record is None or record.scan is None:
            return None
        return record.seq, record.scan

    # ---------------------------------------------------------------- quarantine
    def quarantine(self, seq: int, reason: str) -> bool:
        """Move scan ``seq`` (its original bytes) to the ``quarantine`` table with
        ``reason``; it is never replayed again. Returns False when there is no such scan.
        The unit's stamp bound (``unit_stamps``) is left as it was."""
        moved = self._write(_quarantine_statements(seq, reason))[1].rowcount > 0
        self.quarantined += int(moved)
        return moved

    def quarantined_rows(self) -> list[tuple[int, str, float | None, str]]:
        """``(seq, unit_id, stamp [s], reason)`` of every quarantined record, by seq."""
        if self.schema_version < 3:
            return []
        rows = self._read("SELECT seq, unit_id, stamp, reason FROM quarantine ORDER BY seq")
        return [(int(seq), _text(unit), stamp, reason) for seq, unit, stamp, reason in rows]

    def drop_unit_after(self, unit_id: str, after: float, reason: str) -> list[tuple[int, float]]:
        """Quarantine every scan of ``unit_id`` with stamp > ``after`` [s], set the unit's
        stamp bound to its largest remaining stamp (no row when none remains) and delete
        every snapshot (they include the dropped scans), in one transaction. Returns the
        dropped ``(seq, stamp)``, by seq; nothing changes when there are none."""
        dropped = [
            (int(seq), float(stamp))
            for seq, stamp in self._read(
                "SELECT seq, stamp FROM scans WHERE unit_id = ? AND stamp > ? ORDER BY seq",
                (unit_id, float(after)),
            )
        ]
        if not dropped:
            return []
        statements = [st for seq, _ in dropped for st in _quarantine_statements(seq, reason)]
        statements += [*_reset_unit_statements(unit_id), ("DELETE FROM snapshots", ())]
        self._write(statements)
        self.quarantined += len(dropped)
        return dropped

    def reset_unit_stamp(self, unit_id: str) -> None:
        """Set ``unit_id``'s stamp bound to its largest journaled stamp (no bound when it
        has no scan left), e.g. after its newest scan was quarantined."""
        self._write(_reset_unit_statements(unit_id))

    def import_rows(self, rows: Sequence[RawRow], reasons: Mapping[int, str]) -> None:
        """Copy rows of another journal with their original seqs, in one transaction:
        those with a ``reasons`` entry into quarantine, the others into ``scans`` (their
        checksum recomputed when they had none) with their unit's stamp bound raised."""
        statements: list[tuple[str, Sequence[Any]]] = []
        now = time.time()
        for row in rows:
            reason = reasons.get(row.seq)
            if reason is not None:
                values = (row.seq, row.unit_id, row.stamp, row.body, row.ranges, row.checksum)
                statements.append((_IMPORT_QUARANTINED, (*values, reason, now)))
                continue
            unit_id = row.unit_id.decode()
            checksum = row.computed_checksum() if row.checksum is None else row.checksum
            values = (row.seq, unit_id, row.stamp, row.body.decode(), row.ranges, checksum)
            statements.append((_IMPORT_SCAN, values))
            statements.append((_UPSERT_UNIT, (unit_id, row.stamp)))
        if statements:
            self._write(statements)
            self.quarantined = self._count_quarantined()

    def raise_unit_stamps(self, stamps: Mapping[str, float]) -> None:
        """Raise units' stamp bounds [s] to at least ``stamps`` (never lowers one)."""
        self._write([(_UPSERT_UNIT, (unit, float(stamp))) for unit, stamp in stamps.items()])

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
        checksum = snapshot_checksum(int(seq), float(stamp), int(version), blob)
        newest = self.last_seq()
        if seq > newest:
            raise ValueError(f"seq must not be beyond the journal's last seq ({newest}), got {seq}")
        self._write(
            [
                (
                    "INSERT OR REPLACE INTO snapshots (seq, stamp, version, arrays, checksum) "
                    "VALUES (?, ?, ?, ?, ?)",
                    (int(seq), float(stamp), int(version), blob, checksum),
                ),
                (
                    "DELETE FROM snapshots WHERE seq NOT IN "
                    "(SELECT seq FROM snapshots ORDER BY seq DESC LIMIT ?)",
                    (self.keep_snapshots,),
                ),
            ]
        )

    def latest_snapshot(self) -> Snapshot | None:
        """The snapshot with the largest seq, or None when there is none; raises
        SnapshotError when that one is unusable (``load_snapshot``)."""
        seqs = self.snapshot_seqs()
        return self.load_snapshot(seqs[-1]) if seqs else None

    def load_snapshot(self, seq: int) -> Snapshot:
        """The snapshot at ``seq``, its checksum verified; SnapshotError names the seq and
        why when it is missing, its checksum fails or its arrays do not decode."""
        rows = self._read(
            f"SELECT seq, stamp, version, arrays, {self._checksum_column} FROM snapshots "
            "WHERE seq = ?",
            (int(seq),),
        )
        if not rows:
            raise SnapshotError(f"{self.path}: no snapshot at seq {seq}")
        seq, stamp, version, blob, stored = rows[0]
        if stored is not None:
            computed = snapshot_checksum(seq, stamp, version, blob)
            if computed != stored:
                raise SnapshotError(
                    f"{self.path}: snapshot at seq {seq}: checksum mismatch "
                    f"(stored {stored:#010x}, computed {computed:#010x})"
                )
        try:
            arrays = decode_arrays(blob)
        except (ValueError, OSError, EOFError, KeyError, TypeError, zipfile.BadZipFile) as exc:
            raise SnapshotError(
                f"{self.path}: snapshot at seq {seq} does not decode: {exc}"
            ) from None
        return Snapshot(int(seq), float(stamp), int(version), arrays)

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


def record_checksum(unit_id: bytes, stamp: float, body: bytes, ranges: bytes) -> int:
    """CRC-32 of a scan row: its field lengths and stamp [s] (float64), then the
    ``unit_id``, ``body`` (JSON text) and ``ranges`` bytes as stored."""
    header = struct.pack("<dQQQ", float(stamp), len(unit_id), len(body), len(ranges))
    return zlib.crc32(ranges, zlib.crc32(body, zlib.crc32(unit_id, zlib.crc32(header))))


def snapshot_checksum(seq: int, stamp: float, version: int, arrays: bytes) -> int:
    """CRC-32 of a snapshot row: its seq, stamp [s], version and arrays bytes."""
    return zlib.crc32(arrays, zlib.crc32(struct.pack("<qdq", int(seq), float(stamp), int(version))))


def decode_row(row: RawRow) -> Record:
    """A stored row as a ``Record``: its checksum checked (when it has one), its body
    parsed; what is wrong goes into ``problem`` rather than raising."""
    unit_id = _text(row.unit_id)
    ok = None if row.checksum is None else row.computed_checksum() == row.checksum
    if ok is False:
        problem = (
            f"checksum mismatch (stored {row.checksum:#010x}, "
            f"computed {row.computed_checksum():#010x})"
        )
        return Record(row.seq, unit_id, row.stamp, None, problem, ok)
    try:
        scan = json.loads(row.body.decode("utf-8"))
        if not isinstance(scan, dict):
            raise ValueError(f"the body is a JSON {type(scan).__name__}, not an object")
        if len(row.ranges) % 8:
            raise ValueError(f"ranges hold {len(row.ranges)} bytes, not whole float64s")
    except ValueError as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        return Record(row.seq, unit_id, row.stamp, None, f"body does not parse: {exc}", ok)
    values = np.frombuffer(row.ranges, dtype="<f8").tolist()
    scan["ranges"] = [None if math.isnan(r) else r for r in values]
    return Record(row.seq, unit_id, row.stamp, scan, None, ok)


def _quarantine_statements(seq: int, reason: str) -> list[tuple[str, Sequence[Any]]]:
    """Copy scan ``seq`` to quarantine with ``reason``, then delete it from scans."""
    copy = (
        "INSERT OR REPLACE INTO quarantine "
        "(seq, unit_id, stamp, body, ranges, checksum, reason, quarantined_at) "
        f"SELECT {_RAW_COLUMNS}, checksum, ?, ? FROM scans WHERE seq = ?"
    )
    return [
        (copy, (str(reason), time.time(), int(seq))),
        ("DELETE FROM scans WHERE seq = ?", (int(seq),)),
    ]


def _text(value: bytes | str | None) -> str:
    """A stored TEXT value, damaged UTF-8 replaced (for messages)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    return "" if value is None else str(value)


def _unreadable(path: Path, exc: sqlite3.DatabaseError) -> str:
    """Why a file cannot be read as a journal: damaged SQLite, or not SQLite at all."""
    try:
        with open(path, "rb") as f:
            sqlite = f.read(16) == b"SQLite format 3\x00"
    except OSError:
        sqlite = False
    if not sqlite:
        return f"not a fleetmap journal ({exc})"
    return (
        f"the journal file is damaged ({exc}): `fleetmap journal check DATA_DIR` says what, "
        "`fleetmap journal salvage DATA_DIR` copies the intact records to a new journal"
    )


def _statements(script: str) -> list[str]:
    return [statement for statement in script.split(";") if statement.strip()]


def _in_transaction(conn: sqlite3.Connection, statements: Sequence[str]) -> None:
    """Run ``statements`` in one immediate transaction, rolled back on any error."""
    conn.execute("BEGIN IMMEDIATE")
    try:
        for statement in statements:
            conn.execute(statement)
        conn.execute("COMMIT")
    except BaseException:
        if conn.in_transaction:
            conn.execute("ROLLBACK")
        raise


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


def _reset_unit_statements(unit_id: str) -> list[tuple[str, Sequence[Any]]]:
    """Statements that set a unit's stamp bound to its largest remaining stamp."""
    return [
        ("DELETE FROM units WHERE unit_id = ?", (unit_id,)),
        (
            "INSERT INTO units (unit_id, stamp) SELECT unit_id, max(stamp) FROM scans "
            "WHERE unit_id = ? GROUP BY unit_id",
            (unit_id,),
        ),
    ]


def _unit_and_stamp(scan: Mapping[str, Any], index: int) -> tuple[str, float]:
    """The ``unit_id`` and finite ``stamp`` [s] of scan number ``index`` of a batch."""
    if not isinstance(scan, Mapping):
        raise ValueError(f"scans[{index}] must be a scan object, got {type(scan).__name__}")
    unit_id, stamp = scan.get("unit_id"), scan.get("stamp")
    if not isinstance(unit_id, str) or not unit_id:
        raise ValueError(f"scans[{index}].unit_id must be a non-empty string, got {quote(unit_id)}")
    if isinstance(stamp, bool) or not isinstance(stamp, int | float) or not math.isfinite(stamp):
        raise ValueError(f"scans[{index}].stamp must be a finite number, got {stamp!r}")
    return unit_id, float(stamp)
