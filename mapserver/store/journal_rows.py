"""Reading a possibly damaged journal file row by row (``fleetmap journal check`` and
``salvage``).

A journal file cut short (a copy that stopped, a disk that filled, a torn restore) still
claims in its header the pages it had, and SQLite then refuses every query ("database
disk image is malformed"). ``readable_copy`` opens such a file through a temporary copy
whose header counts the whole pages the file still has; the intact b-tree pages then
read again. ``RowReader`` reads the ``scans`` table in seq ranges and, where a range
fails, seq by seq, so one damaged page costs the rows on it and nothing else.
"""

from __future__ import annotations

import contextlib
import shutil
import sqlite3
import struct
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from mapserver.store.journal import RawRow

SQLITE_MAGIC = b"SQLite format 3\x00"
CHUNK = 256  # seqs read per range query
PROBE_LIMIT = 1 << 16  # seqs read past the last row found when the journal's end is unknown


@dataclass(frozen=True)
class Unreadable:
    """A seq whose row could not be read (a damaged or missing page) and the error."""

    seq: int
    error: str


def _opens(path: Path) -> bool:
    """Whether SQLite reads ``path``'s header and schema."""
    try:
        with contextlib.closing(_connect(path)) as conn:
            conn.execute("SELECT count(*) FROM sqlite_master").fetchone()
    except sqlite3.DatabaseError:
        return False
    return True


@contextlib.contextmanager
def readable_copy(path: Path) -> Iterator[Path]:
    """``path`` itself when SQLite reads it, else a temporary copy (with its ``-wal``)
    cut to whole pages and with the header's page count set to the pages it holds."""
    if _opens(path):
        yield path
        return
    with open(path, "rb") as f:
        header = f.read(100)
    if len(header) < 100 or not header.startswith(SQLITE_MAGIC):
        yield path  # not SQLite, or no header left: nothing a copy would mend
        return
    page_size = struct.unpack(">H", header[16:18])[0]
    page_size = 65536 if page_size == 1 else page_size
    with tempfile.TemporaryDirectory(prefix="fleetmap-salvage-") as tmp:
        copy = Path(tmp) / path.name
        shutil.copyfile(path, copy)
        wal = path.with_name(path.name + "-wal")
        if wal.is_file():
            shutil.copyfile(wal, copy.with_name(copy.name + "-wal"))
        with open(copy, "r+b") as f:
            pages = f.seek(0, 2) // page_size
            f.truncate(pages * page_size)
            f.seek(28)
            f.write(struct.pack(">I", pages))
        yield copy


def _connect(path: Path) -> sqlite3.Connection:
    return sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, isolation_level=None)


class RowReader:
    """Read-only, best-effort access to a journal file's rows (``readable_copy`` first).

    Raises sqlite3.DatabaseError when not even the schema reads.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._conn = _connect(path)
        columns = {row[1] for row in self._conn.execute("PRAGMA table_info(scans)")}
        if not columns:
            self._conn.close()
            raise sqlite3.DatabaseError(f"{path}: no scans table")
        self._checksum = "checksum" if "checksum" in columns else "NULL"
        self._format = "format" if "format" in columns else "NULL"

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> RowReader:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _try(self, sql: str, params: tuple = ()) -> list[tuple] | None:
        try:
            return self._conn.execute(sql, params).fetchall()
        except sqlite3.DatabaseError:
            return None

    def last_seq_claimed(self) -> int | None:
        """The largest seq the file says it handed out (its b-tree's or AUTOINCREMENT's
        record, whichever reads and is larger), or None when neither reads."""
        found = [
            rows[0][0]
            for rows in (
                self._try("SELECT max(seq) FROM scans"),
                self._try("SELECT seq FROM sqlite_sequence WHERE name = 'scans'"),
            )
            if rows and rows[0][0] is not None
        ]
        return max(found) if found else None

    def first_seq(self) -> int:
        """Where the rows start: 1, or past the seqs retention deleted (the ``meta``
        table's mark, else the smallest seq that reads) so a cut journal is not probed
        from seq 1."""
        mark = self.deleted_through()
        if mark:
            return mark + 1
        first = self._try("SELECT min(seq) FROM scans")
        return int(first[0][0]) if first and first[0][0] is not None else 1

    def deleted_through(self) -> int:
        """The seq through which retention deleted the scans (0: none, or unknown)."""
        mark = self._try("SELECT value FROM meta WHERE key = 'deleted_through'")
        return int(mark[0][0]) if mark else 0

    def rows(self) -> Iterator[RawRow | Unreadable]:
        """Every scan row that reads, by seq, and an ``Unreadable`` for each seq from
        ``first_seq`` up to the end the file claims whose lookup fails (a gap of deleted
        seqs is silent)."""
        columns = "seq, CAST(unit_id AS BLOB), stamp, CAST(body AS BLOB), ranges"
        select = f"SELECT {columns}, {self._checksum}, {self._format} FROM scans WHERE seq "
        end = self.last_seq_claimed()
        start = self.first_seq()
        last_found = start - 1
        while start <= (end if end is not None else last_found + PROBE_LIMIT):
            stop = start + CHUNK - 1
            chunk = self._try(select + "BETWEEN ? AND ? ORDER BY seq", (start, stop))
            if chunk is None:
                chunk = []
                for seq in range(start, stop + 1):
                    try:
                        chunk += self._conn.execute(select + "= ?", (seq,)).fetchall()
                    except sqlite3.DatabaseError as exc:
                        if end is not None and seq <= end:
                            yield Unreadable(seq, str(exc))
            for row in chunk:
                yield RawRow(*row)
                last_found = row[0]
            start = stop + 1

    def unit_stamps(self) -> dict[str, float]:
        """The ``units`` table's stamp bounds [s], or {} when it does not read."""
        rows = self._try("SELECT unit_id, stamp FROM units") or []
        return {str(unit): float(stamp) for unit, stamp in rows}

    def quarantined(self) -> list[tuple[RawRow, str]]:
        """The quarantined rows with their reasons, or [] when the table does not read."""
        columns = f"seq, unit_id, stamp, body, ranges, checksum, {self._format}, reason"
        rows = self._try(f"SELECT {columns} FROM quarantine ORDER BY seq") or []
        return [(RawRow(*row[:7]), row[7]) for row in rows]


def seq_ranges(seqs: list[int]) -> list[tuple[int, int]]:
    """Sorted seqs as runs of consecutive ones: [1, 2, 3, 7] -> [(1, 3), (7, 7)]."""
    runs: list[tuple[int, int]] = []
    for seq in sorted(seqs):
        if runs and seq == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], seq)
        else:
            runs.append((seq, seq))
    return runs
