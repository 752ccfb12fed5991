"""The map server's durable journal: every accepted scan, in order, plus grid snapshots.

One SQLite database file (stdlib ``sqlite3``) in WAL mode holds:

- ``scans``: one row per accepted scan, ``seq`` (INTEGER PRIMARY KEY AUTOINCREMENT: 1, 2,
  3, ... never reused), ``unit_id``, ``stamp`` [s], ``body``, the scan's docs/http-api.md
  2.1 object without its ranges as compact JSON text, ``ranges`` (``format`` 1: float32,
  byte-shuffled, zlib; NULL: raw float64 as schema 3 wrote). The journal is the replay
  log: replaying it in ``seq`` order rebuilds the map bit for bit. Index
  ``scans_unit_stamp`` (unit_id, stamp) serves ``find_scan``.
- ``units``: the largest stamp journaled per unit, so a restarted server still rejects a
  stamp that goes backwards (409) without reading every scan.
- ``snapshots``: the grid's arrays as of a ``seq`` (``np.savez`` bytes), only the newest
  ``keep_snapshots`` kept (or, with retention, what ``mapserver.store.retention``
  keeps), each with ``saved_at`` (wall time). Start-up = newest usable snapshot + the
  scans after it.
- ``meta``: ``deleted_through``, the seq through which retention deleted the scans (a
  full replay from seq 0 is possible only while it is 0).
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
as it is, unchecked. A version-3 journal (float64 ranges) is migrated in place to 4 the
same way, its rows kept as they are (``_migrate``); a read-only open reads it as it is.
"""

from __future__ import annotations

import io
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
import orjson
import zstandard

from mapserver import json_text
from mapserver.core.errors import FleetmapError
from mapserver.core.scan import json_ranges
from mapserver.core.text import quote

logger = logging.getLogger(__name__)

SCHEMA_VERSION = 4
UNCHECKED_VERSION = 2  # no checksums: migrated by a writable open, else read unchecked
FLOAT64_VERSION = 3  # float64 ranges, no index: migrated by a writable open, else read as is
FORMAT_F32_ZLIB = 1  # scans.format: ranges as byte-shuffled float32, zlib (NULL: raw float64)
RANGES_ZLIB_LEVEL = 6  # zlib level of the ranges (1 is 2 % larger, 9 no smaller)
APPLICATION_ID = 0x464D4A31  # "FMJ1": marks the file as a fleetmap journal
JOURNAL_FILENAME = "journal.sqlite3"  # the journal's name inside a server data directory
SYNCHRONOUS_MODES = ("FULL", "NORMAL", "OFF")
WAL_SIZE_LIMIT = 64 << 20  # [bytes] the -wal file kept after a checkpoint (journal_size_limit)
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
# Version 4 over version 3: the rows' ranges encoding (NULL: a schema-3 row, raw float64,
# fused unrounded), the wall time a snapshot was saved (retention's clock), what retention
# deleted, and the index of the same-stamp lookup (``find_scan``).
_SCHEMA_V4 = """
ALTER TABLE scans ADD COLUMN format INTEGER;
ALTER TABLE quarantine ADD COLUMN format INTEGER;
ALTER TABLE snapshots ADD COLUMN saved_at REAL;
CREATE TABLE meta (
    key TEXT PRIMARY KEY,
    value INTEGER NOT NULL
) WITHOUT ROWID;
CREATE INDEX scans_unit_stamp ON scans (unit_id, stamp);
"""
DELETED_THROUGH = "deleted_through"  # meta key: every scan with seq <= this was deleted
_FILL_CHECKSUMS = (
    "UPDATE scans SET checksum = fleetmap_record_checksum("
    "CAST(unit_id AS BLOB), stamp, CAST(body AS BLOB), ranges)",
    "UPDATE snapshots SET checksum = fleetmap_snapshot_checksum(seq, stamp, version, arrays)",
)
# A scan row as bytes: a damaged TEXT value must not fail to decode while it is read.
_RAW_COLUMNS = "seq, CAST(unit_id AS BLOB), stamp, CAST(body AS BLOB), ranges"
_INSERT_SCAN = (
    "INSERT INTO scans (unit_id, stamp, body, ranges, checksum, format) VALUES (?, ?, ?, ?, ?, ?)"
)
_IMPORT_SCAN = (
    "INSERT INTO scans (seq, unit_id, stamp, body, ranges, checksum, format) "
    "VALUES (?, ?, ?, ?, ?, ?, ?)"
)
_IMPORT_QUARANTINED = (
    "INSERT OR REPLACE INTO quarantine "
    "(seq, unit_id, stamp, body, ranges, checksum, format, reason, quarantined_at) "
    "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)"
)
_SET_DELETED_THROUGH = (
    f"INSERT INTO meta (key, value) VALUES ('{DELETED_THROUGH}', ?) "
    "ON CONFLICT (key) DO UPDATE SET value = max(value, excluded.value)"
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
    ``ranges`` (bytes in ``format``), ``checksum`` (None: not recorded, read unchecked)
    and ``format`` (None: raw float64, as schemas 2 and 3 wrote; ``FORMAT_F32_ZLIB``)."""

    seq: int
    unit_id: bytes
    stamp: float
    body: bytes
    ranges: bytes
    checksum: int | None
    format: int | None = None

    def computed_checksum(self) -> int:
        return record_checksum(self.unit_id, self.stamp, self.body, self.ranges, self.format)


@dataclass(frozen=True)
class Record:
    """One journaled scan as read: its ``seq``, ``unit_id`` (damaged bytes replaced),
    ``stamp`` [s], and either its ``header`` (the docs/http-api.md 2.1 object without
    ``ranges``) and ``ranges`` [m] (as stored: float32, float64 for schema <= 3; NaN for
    null; it may view the stored bytes: copy it to write) or ``problem`` (why it cannot
    be read). ``checksum_ok``: True checked, False failed, None unchecked."""

    seq: int
    unit_id: str
    stamp: float
    header: dict[str, Any] | None
    ranges: np.ndarray | None
    problem: str | None
    checksum_ok: bool | None
    float64_ranges: bool = False  # stored as float64 (schema <= 3): fused unrounded

    @property
    def scan(self) -> dict[str, Any] | None:
        """The docs/http-api.md 2.1 object (ranges a list, null for NaN), or None for a
        damaged record. Made at each call: readers that build a ``Scan`` take ``fields``."""
        if self.header is None or self.ranges is None:
            return None
        return {**self.header, "ranges": json_ranges(self.ranges)}

    def body(self) -> dict[str, Any]:
        """The scan object; raises RecordError (the problem) for a damaged record."""
        scan = self.scan
        if scan is None:
            raise RecordError(self.problem)
        return scan

    def fields(self) -> dict[str, Any]:
        """The scan object with ``ranges`` as the decoded array, as ``Scan.from_dict``
        takes it (and copies it to float64) without a Python list in between (the same
        scan, in half the time or less); raises RecordError (the problem) for a damaged
        record."""
        if self.header is None or self.ranges is None:
            raise RecordError(self.problem)
        return {**self.header, "ranges": self.ranges}


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


@dataclass(frozen=True)
class SnapshotInfo:
    """A stored snapshot without its arrays: ``seq``, ``saved_at`` [s since the epoch,
    wall time] and ``nbytes`` (its arrays' stored size)."""

    seq: int
    saved_at: float
    nbytes: int


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
        self._format_column = "format" if self.schema_version >= 4 else "NULL"
        self._row_columns = f"{_RAW_COLUMNS}, {self._checksum_column}, {self._format_column}"
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
        elif version in (UNCHECKED_VERSION, FLOAT64_VERSION) and self.readonly:
            self.schema_version = version
        elif version in (UNCHECKED_VERSION, FLOAT64_VERSION):
            self._migrate(conn, version)
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
        # After a checkpoint the -wal file is truncated to this size instead of staying at
        # its high-water mark (a snapshot's blob passes through it): SQLite, "PRAGMA
        # journal_size_limit". Checkpoints themselves run every wal_autocheckpoint pages
        # (SQLite's default, 1000).
        conn.execute(f"PRAGMA journal_size_limit = {WAL_SIZE_LIMIT}")

    @staticmethod
    def _create_schema(conn: sqlite3.Connection) -> None:
        statements = [*_statements(_SCHEMA), *_statements(_SCHEMA_V3), *_statements(_SCHEMA_V4)]
        statements.append(f"PRAGMA application_id = {APPLICATION_ID}")
        _in_transaction(conn, [*statements, f"PRAGMA user_version = {SCHEMA_VERSION}"])

    def _migrate(self, conn: sqlite3.Connection, version: int) -> None:
        """Version 2 or 3 -> 4 in one transaction. From 2: the checksum columns and the
        quarantine table, checksums for the rows there are (a row damaged before now is
        not detectable by its checksum). From 3: the ``format`` column (the rows there keep
        their float64 ranges and NULL format, so they replay to the map they made), the
        snapshots' ``saved_at`` (now: they age from the upgrade), ``meta`` and the index."""
        statements: list[str] = []
        if version == UNCHECKED_VERSION:
            statements += [*_statements(_SCHEMA_V3), *_FILL_CHECKSUMS]
        statements += _statements(_SCHEMA_V4)
        statements.append(f"UPDATE snapshots SET saved_at = {time.time()!r}")
        _in_transaction(conn, [*statements, f"PRAGMA user_version = {SCHEMA_VERSION}"])
        rows = conn.execute("SELECT count(*) FROM scans").fetchone()[0]
        logger.info(
            "%s: journal migrated from schema %d to %d (%d scans kept as they were stored)",
            self.path,
            version,
            SCHEMA_VERSION,
            rows,
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
            and ``ranges`` as float32, null as NaN, byte-shuffled and zlib-compressed
            (``encode_ranges``): ``Scan.from_dict`` rounded them to float32 already, so
            what is stored is exactly what was fused).
        Returns the new seqs, consecutive and increasing, one per scan. All scans are
        written or none: on any error nothing is journaled. What survives a crash once
        this returns is in the module docstring.
        """
        statements: list[tuple[str, Sequence[Any]]] = []
        for i, scan in enumerate(scans):
            unit_id, stamp = _unit_and_stamp(scan, i)
            header = {k: v for k, v in scan.items() if k != "ranges"}
            ranges = encode_ranges(scan.get("ranges", ()))
            body = orjson.dumps(header).decode()  # as json.dumps, compact, in a tenth the time
            fmt = FORMAT_F32_ZLIB
            checksum = record_checksum(unit_id.encode(), stamp, body.encode(), ranges, fmt)
            statements.append((_INSERT_SCAN, (unit_id, stamp, body, ranges, checksum, fmt)))
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
        sql = f"SELECT {self._row_columns} FROM scans WHERE {where} ORDER BY seq LIMIT ?"
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
        None (the index ``scans_unit_stamp``: O(log scans); a schema-3 file opened
        read-only has none and scans the table)."""
        rows = self._read(
            f"SELECT {self._row_columns} FROM scans "
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
        the snapshots that include a dropped scan (seq >= the first dropped seq), in one
        transaction; the older snapshots stay, so start-up rebuilds from the newest of
        them. Returns the dropped ``(seq, stamp)``, by seq; nothing changes when there are
        none. Raises JournalError, changing nothing, when retention deleted the journal's
        first scans and no usable snapshot older than the first dropped scan remains (the
        map could not be rebuilt)."""
        dropped = [
            (int(seq), float(stamp))
            for seq, stamp in self._read(
                "SELECT seq, stamp FROM scans WHERE unit_id = ? AND stamp > ? ORDER BY seq",
                (unit_id, float(after)),
            )
        ]
        if not dropped:
            return []
        first = dropped[0][0]
        base = self.deleted_through()
        if base > 0 and self.usable_snapshot(before=first) is None:
            raise JournalError(
                f"{self.path}: cannot drop unit {unit_id!r}'s scans from seq {first} (stamp "
                f"{dropped[0][1]}): retention deleted scans 1-{base}, so the map can only be "
                f"rebuilt from a snapshot, and no usable snapshot older than seq {first} "
                f"remains (kept: {self.snapshot_seqs() or 'none'}). Drop with a later --after "
                "(after the oldest kept snapshot), or start a new data dir"
            )
        statements = [st for seq, _ in dropped for st in _quarantine_statements(seq, reason)]
        statements += _reset_unit_statements(unit_id)
        statements.append(("DELETE FROM snapshots WHERE seq >= ?", (first,)))
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
                statements.append((_IMPORT_QUARANTINED, (*values, row.format, reason, now)))
                continue
            unit_id = row.unit_id.decode()
            checksum = row.computed_checksum() if row.checksum is None else row.checksum
            values = (
                row.seq,
                unit_id,
                row.stamp,
                row.body.decode(),
                row.ranges,
                checksum,
                row.format,
            )
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

    def deleted_through(self) -> int:
        """Every scan with seq <= this was deleted by retention (0: none was; the whole
        journal replays from an empty map). Snapshots older than it cannot be used."""
        if self.schema_version < 4:
            return 0
        rows = self._read("SELECT value FROM meta WHERE key = ?", (DELETED_THROUGH,))
        return int(rows[0][0]) if rows else 0

    def set_deleted_through(self, seq: int) -> None:
        """Record that the scans up to ``seq`` are gone (never lowers it; salvage)."""
        self._write([(_SET_DELETED_THROUGH, (int(seq),))])

    def delete_scans_through(self, seq: int, batch: int = 1000) -> int:
        """Delete the scans with seq <= ``seq`` (retention), ``batch`` seqs per
        transaction, each also raising ``deleted_through``, so appends wait for one
        short transaction at most and a crash between two leaves a consistent journal.
        Returns the rows deleted."""
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch!r}")
        start = self.deleted_through()
        if seq <= start:
            return 0
        first = self._read("SELECT min(seq) FROM scans WHERE seq > ?", (start,))[0][0]
        low = int(seq) if first is None else max(start, min(int(first) - 1, int(seq)))
        if low > start:  # no scan between: only the mark moves
            self.set_deleted_through(low)
        deleted = 0
        while low < seq:
            high = min(int(seq), low + batch)
            cursors = self._write(
                [
                    ("DELETE FROM scans WHERE seq > ? AND seq <= ?", (low, high)),
                    (_SET_DELETED_THROUGH, (high,)),
                ]
            )
            deleted += max(0, cursors[0].rowcount)
            low = high
        return deleted

    def prune_quarantine(self, through_seq: int, max_rows: int | None) -> int:
        """Delete the quarantined rows with seq <= ``through_seq`` (retention deleted
        their neighbours) and, beyond ``max_rows`` (None: no cap), the oldest; returns
        how many."""
        statements: list[tuple[str, Sequence[Any]]] = [
            ("DELETE FROM quarantine WHERE seq <= ?", (int(through_seq),))
        ]
        if max_rows is not None:
            statements.append(
                (
                    "DELETE FROM quarantine WHERE seq NOT IN "
                    "(SELECT seq FROM quarantine ORDER BY seq DESC LIMIT ?)",
                    (int(max_rows),),
                )
            )
        deleted = sum(max(0, c.rowcount) for c in self._write(statements))
        self.quarantined = self._count_quarantined()
        return deleted

    def prune_units(self) -> int:
        """Delete the stamp bound of every unit with no scan left in the journal (its
        scans all past retention); returns how many. O(units x log scans), by the index."""
        cursor = self._write(
            [
                (
                    "DELETE FROM units WHERE NOT EXISTS "
                    "(SELECT 1 FROM scans WHERE scans.unit_id = units.unit_id)",
                    (),
                )
            ]
        )[0]
        return max(0, cursor.rowcount)

    def page_stats(self) -> tuple[int, int, int]:
        """``(page_count, freelist_count, page_size [bytes])`` of the database file: its
        used bytes are ``(page_count - freelist_count) * page_size``."""
        return (
            int(self._read("PRAGMA page_count")[0][0]),
            int(self._read("PRAGMA freelist_count")[0][0]),
            int(self._read("PRAGMA page_size")[0][0]),
        )

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
        self,
        seq: int,
        stamp: float,
        version: int,
        arrays: Mapping[str, np.ndarray],
        *,
        prune: bool = True,
    ) -> None:
        """Store the grid's arrays as of journal ``seq``, with the wall time now as
        ``saved_at``; with ``prune``, keep only the newest ``keep_snapshots`` (without:
        retention, ``mapserver.store.retention``, chooses which to keep).

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
        statements: list[tuple[str, Sequence[Any]]] = [
            (
                "INSERT OR REPLACE INTO snapshots "
                "(seq, stamp, version, arrays, checksum, saved_at) VALUES (?, ?, ?, ?, ?, ?)",
                (int(seq), float(stamp), int(version), blob, checksum, time.time()),
            )
        ]
        if prune:
            statements.append(
                (
                    "DELETE FROM snapshots WHERE seq NOT IN "
                    "(SELECT seq FROM snapshots ORDER BY seq DESC LIMIT ?)",
                    (self.keep_snapshots,),
                )
            )
        self._write(statements)

    def import_snapshot(self, snapshot: Snapshot, saved_at: float) -> None:
        """Store another journal's snapshot as it was (salvage), checksummed anew."""
        blob = encode_arrays(snapshot.arrays)
        checksum = snapshot_checksum(snapshot.seq, snapshot.stamp, snapshot.version, blob)
        self._write(
            [
                (
                    "INSERT OR REPLACE INTO snapshots "
                    "(seq, stamp, version, arrays, checksum, saved_at) VALUES (?, ?, ?, ?, ?, ?)",
                    (snapshot.seq, snapshot.stamp, snapshot.version, blob, checksum, saved_at),
                )
            ]
        )

    def delete_snapshots(self, seqs: Sequence[int]) -> None:
        """Delete the snapshots at ``seqs`` (one transaction)."""
        if seqs:
            self._write([("DELETE FROM snapshots WHERE seq = ?", (int(s),)) for s in seqs])

    def snapshot_infos(self) -> list[SnapshotInfo]:
        """Every stored snapshot's seq, wall time saved and size, oldest first (a schema
        older than 4 records no ``saved_at``: 0). Reads no arrays."""
        saved_at = "saved_at" if self.schema_version >= 4 else "0"
        rows = self._read(
            f"SELECT seq, coalesce({saved_at}, 0), length(arrays) FROM snapshots ORDER BY seq"
        )
        return [SnapshotInfo(int(seq), float(at), int(size)) for seq, at, size in rows]

    def usable_snapshot(self, before: int | None = None) -> Snapshot | None:
        """The newest snapshot that loads (checksum, arrays), among those a replay can start
        from (seq >= ``deleted_through``) and, when given, with seq < ``before``; None when
        there is none. Unusable ones are logged and skipped."""
        base = self.deleted_through()
        for seq in reversed(self.snapshot_seqs()):
            if seq < base or (before is not None and seq >= before):
                continue
            try:
                return self.load_snapshot(seq)
            except SnapshotError as exc:
                logger.error("%s", exc)
        return None

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


SNAPSHOT_ZSTD_LEVEL = 1
"""zstd level of a snapshot's arrays: level 1 compresses the 26 MB of a 2 M-cell grid in
milliseconds with the GIL released (zlib took about a second a 4 M-cell grid), and the
journal's write of the smaller blob holds up the scans' appends for less (one journal
lock): docs/durability.md."""

ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"  # a zstd frame's first bytes (RFC 8878); an npz starts "PK"


def encode_arrays(arrays: Mapping[str, np.ndarray]) -> bytes:
    """``np.savez`` bytes of named arrays (no pickled objects), zstd-compressed."""
    buffer = io.BytesIO()
    for name, array in arrays.items():
        if np.asarray(array).dtype == object:
            raise ValueError(f"arrays[{name!r}] must be a numeric array, got dtype object")
    np.savez(buffer, allow_pickle=False, **{k: np.asarray(v) for k, v in arrays.items()})
    return zstandard.ZstdCompressor(level=SNAPSHOT_ZSTD_LEVEL).compress(buffer.getbuffer())


def decode_arrays(blob: bytes) -> dict[str, np.ndarray]:
    """The named arrays of ``encode_arrays`` bytes, or of a bare npz (a snapshot saved
    before snapshots were compressed, 2026-12-05)."""
    if bytes(blob[:4]) == ZSTD_MAGIC:
        try:
            blob = zstandard.ZstdDecompressor().decompress(blob)
        except zstandard.ZstdError as exc:
            raise ValueError(f"the zstd frame does not decompress: {exc}") from None
    with np.load(io.BytesIO(blob), allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def record_checksum(
    unit_id: bytes, stamp: float, body: bytes, ranges: bytes, fmt: int | None = None
) -> int:
    """CRC-32 of a scan row: its field lengths and stamp [s] (float64), its ranges
    ``fmt`` when it has one (a schema-3 row, NULL, keeps its old checksum), then the
    ``unit_id``, ``body`` (JSON text) and ``ranges`` bytes as stored."""
    header = struct.pack("<dQQQ", float(stamp), len(unit_id), len(body), len(ranges))
    if fmt is not None:
        header += struct.pack("<q", int(fmt))
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
        return Record(row.seq, unit_id, row.stamp, None, None, problem, ok)
    try:
        scan = json_text.loads(row.body)  # read as the server read the scan's body
        if not isinstance(scan, dict):
            raise ValueError(f"the body is a JSON {type(scan).__name__}, not an object")
        ranges = decode_ranges(row.ranges, row.format)
    except (ValueError, zlib.error) as exc:  # UnicodeDecodeError, JSONDecodeError: ValueErrors
        return Record(row.seq, unit_id, row.stamp, None, None, f"body does not parse: {exc}", ok)
    scan.pop("ranges", None)  # a header that holds ranges (never written so) is overridden
    return Record(row.seq, unit_id, row.stamp, scan, ranges, None, ok, row.format is None)


def encode_ranges(ranges: Any) -> bytes:
    """Ranges [m] as stored (``FORMAT_F32_ZLIB``): float32 little-endian, null as NaN,
    byte-shuffled (all first bytes, then all second bytes, ...: the sign and exponent
    bytes of nearby ranges repeat, so zlib finds them) and zlib-compressed. Values must
    be float32 already (``Scan.from_dict`` rounds them); a value that is not is refused,
    since the map would not replay to what was fused."""
    values = np.asarray(
        [np.nan if r is None else r for r in ranges] if isinstance(ranges, list) else ranges,
        dtype=np.float64,
    )
    with np.errstate(over="ignore"):
        single = values.astype("<f4")
    exact = (single.astype(np.float64) == values) | np.isnan(values)
    if not exact.all():
        i = int(np.argmin(exact))
        raise ValueError(
            f"ranges[{i}] = {values[i]!r} is not a float32 value: validate scans with "
            "Scan.from_dict, which rounds ranges to float32 (what the journal stores)"
        )
    shuffled = single.view(np.uint8).reshape(-1, 4).T.tobytes()
    return zlib.compress(shuffled, RANGES_ZLIB_LEVEL)


def decode_ranges(blob: bytes, fmt: int | None) -> np.ndarray:
    """The ranges [m] of a stored row (float32 or, for ``fmt`` None, float64 values);
    ValueError (or zlib.error) when the bytes are not of that format."""
    if fmt is None:
        if len(blob) % 8:
            raise ValueError(f"ranges hold {len(blob)} bytes, not whole float64s")
        return np.frombuffer(blob, dtype="<f8")
    if fmt != FORMAT_F32_ZLIB:
        raise ValueError(f"unknown ranges format {fmt!r} (this fleetmap reads NULL and 1)")
    shuffled = zlib.decompress(blob)
    if len(shuffled) % 4:
        raise ValueError(f"ranges hold {len(shuffled)} bytes, not whole float32s")
    planes = np.frombuffer(shuffled, dtype=np.uint8).reshape(4, -1)
    return planes.T.copy().view("<f4").reshape(-1)


def _quarantine_statements(seq: int, reason: str) -> list[tuple[str, Sequence[Any]]]:
    """Copy scan ``seq`` to quarantine with ``reason``, then delete it from scans."""
    copy = (
        "INSERT OR REPLACE INTO quarantine "
        "(seq, unit_id, stamp, body, ranges, checksum, format, reason, quarantined_at) "
        f"SELECT {_RAW_COLUMNS}, checksum, format, ?, ? FROM scans WHERE seq = ?"
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
